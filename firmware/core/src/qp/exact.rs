//! Exact solve of a box QP whose Hessian splits into small independent
//! blocks, by enumerating every active set of every block.
//!
//! When `H` has no non-zero entry between two groups of variables, the QP
//! is one small QP per group (the box is a product of intervals). The MPC's
//! Hessian is such a case: the hover model does not couple its four input
//! channels (thrust, roll, pitch and yaw torque), so its `4·M` moves form
//! four blocks of `M`.
//!
//! A block of `k` variables has `3^k` active sets (each variable free, at
//! its lower or at its upper bound). For each, the free variables solve
//! `H_FF z_F = −(g_F + H_FB z_B)` (`H_FF` is a principal submatrix of a
//! positive definite matrix, so it is invertible); the candidate is clamped
//! into the box, and the block keeps the candidate with the lowest
//! objective (compared by the change from the best so far, `change`, not
//! by two objectives each rounded on its own). The KKT point is one of the candidates and is already inside
//! the box, and every clamped candidate is feasible, so in exact arithmetic
//! the kept candidate is the minimiser: the answer is exact after a fixed
//! amount of work that does not depend on the data (no iteration, no
//! tolerance, no active-set guess). In the solver's float type it is the
//! minimiser up to rounding, which [`super::QpSolution::gap`] certifies
//! (with the blocks' duality gap, `dual_gap`, when it is the tighter).
//!
//! Steps per block (`solve_block`): load the block, `invert` each principal
//! submatrix once, then for each active set build its `candidate`, take its
//! `change` from the best so far and keep it if it is lower; then the
//! `dual_gap` of the kept one.

use crate::math::clamp;
use nalgebra::{RealField, SMatrix, SVector};

/// Largest block solved by enumeration (3³ = 27 active sets). The MPC's
/// blocks are its moves per channel, three in the fast preset; a block of
/// four (81 active sets) would cost three times the solve and about
/// 3.5 KiB of flash for a size of its own, so it is left to the
/// iterative solver.
pub const MAX_BLOCK: usize = 3;

/// The independent blocks of a Hessian, found once at design time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Blocks<const N: usize> {
    /// The variables ordered block by block.
    order: [u8; N],
    /// Size of each block, in `order`'s order (`count` of them are used).
    sizes: [u8; N],
    /// Number of blocks.
    count: u8,
}

impl<const N: usize> Blocks<N> {
    /// The blocks of `h`: the connected components of its non-zero pattern
    /// (an entry exactly zero couples nothing). `None` when a block is
    /// larger than [`MAX_BLOCK`] (or `N` does not fit the index type): such
    /// a Hessian is left to the iterative solver.
    pub fn of<T: RealField + Copy>(h: &SMatrix<T, N, N>) -> Option<Self> {
        if N > u8::MAX as usize {
            return None;
        }
        // Component label per variable: the smallest index reachable.
        let mut label = [0usize; N];
        for (i, l) in label.iter_mut().enumerate() {
            *l = i;
        }
        // Relabel to a fixed point (N passes at most: labels only decrease).
        for _ in 0..N {
            let mut changed = false;
            for i in 0..N {
                for j in 0..N {
                    if h[(i, j)] != T::zero() && label[j] < label[i] {
                        label[i] = label[j];
                        changed = true;
                    }
                }
            }
            if !changed {
                break;
            }
        }
        let mut me = Self {
            order: [0; N],
            sizes: [0; N],
            count: 0,
        };
        let mut n = 0usize;
        for root in 0..N {
            if label[root] != root {
                continue;
            }
            let start = n;
            for (i, &l) in label.iter().enumerate() {
                if l == root {
                    me.order[n] = i as u8;
                    n += 1;
                }
            }
            let size = n - start;
            if size > MAX_BLOCK {
                return None;
            }
            me.sizes[me.count as usize] = size as u8;
            me.count += 1;
        }
        Some(me)
    }

    /// Each block's variables (indices into the QP's), block by block.
    pub fn each(&self) -> impl Iterator<Item = &[u8]> {
        let mut at = 0usize;
        self.sizes[..self.count()].iter().map(move |&size| {
            let idx = &self.order[at..at + size as usize];
            at += size as usize;
            idx
        })
    }

    /// Number of blocks.
    pub fn count(&self) -> usize {
        self.count as usize
    }

    /// Active sets tried per solve: `Σ 3^kᵢ` over the blocks (the fixed work
    /// of every solve).
    pub fn active_sets(&self) -> u32 {
        self.sizes[..self.count()].iter().map(|&k| 3u32.pow(k as u32)).sum()
    }

    /// The exact minimiser of `½zᵀHz + gᵀz` over `lb ≤ z ≤ ub` (data checked
    /// finite with `lb ≤ ub` by the caller), inside the box, and its
    /// duality gap (the sum of the blocks' `dual_gap`s; `None` when a
    /// block's Hessian did not invert).
    pub fn solve<T: RealField + Copy>(
        &self,
        h: &SMatrix<T, N, N>,
        g: &SVector<T, N>,
        lb: &SVector<T, N>,
        ub: &SVector<T, N>,
    ) -> (SVector<T, N>, Option<T>) {
        let mut z = SVector::<T, N>::zeros();
        let mut gap = Some(T::zero());
        let mut at = 0usize;
        for &size in &self.sizes[..self.count()] {
            let idx = &self.order[at..at + size as usize];
            at += size as usize;
            // The block's data, padded to MAX_BLOCK (only its first
            // `idx.len()` entries are read).
            let mut hb = [[T::zero(); MAX_BLOCK]; MAX_BLOCK];
            let mut gb = [[T::zero(); MAX_BLOCK]; 3];
            for (a, &i) in idx.iter().enumerate() {
                let i = i as usize;
                gb[0][a] = g[i];
                gb[1][a] = lb[i];
                gb[2][a] = ub[i];
                for (c, &j) in idx.iter().enumerate() {
                    hb[a][c] = h[(i, j as usize)];
                }
            }
            let (zb, block_gap) = match idx.len() {
                1 => solve_block::<T, 1>(&hb, &gb),
                2 => solve_block::<T, 2>(&hb, &gb),
                _ => solve_block::<T, MAX_BLOCK>(&hb, &gb),
            };
            for (a, &i) in idx.iter().enumerate() {
                z[i as usize] = zb[a];
            }
            gap = match (gap, block_gap) {
                (Some(a), Some(b)) => Some(a + b),
                _ => None,
            };
        }
        (z, gap)
    }
}

/// One block of `K` variables solved by enumeration: `hm` its Hessian,
/// `data` its linear term, lower and upper bounds (the first `K` entries of
/// each are read); its answer in the first `K` entries, and its
/// [`dual_gap`] (from the inverse of the whole block, which the
/// enumeration computes anyway).
///
/// The data is copied into `K`-sized arrays so that every loop below has a
/// constant trip count and unrolls into straight-line code.
// Out of line: four sizes of it would otherwise be inlined into each caller.
#[inline(never)]
fn solve_block<T: RealField + Copy, const K: usize>(
    hm: &[[T; MAX_BLOCK]; MAX_BLOCK],
    data: &[[T; MAX_BLOCK]; 3],
) -> ([T; MAX_BLOCK], Option<T>) {
    let mut h = [[T::zero(); K]; K];
    let (mut g, mut lo, mut hi) = ([T::zero(); K], [T::zero(); K], [T::zero(); K]);
    for a in 0..K {
        g[a] = data[0][a];
        lo[a] = data[1][a];
        hi[a] = data[2][a];
        h[a][..K].copy_from_slice(&hm[a][..K]);
    }
    let full = ((1u32 << K) - 1) as u8;
    let mut best = [T::zero(); K];
    for a in 0..K {
        best[a] = clamp(T::zero(), lo[a], hi[a]);
    }
    let mut best_grad = gradient(&h, &g, &best);
    let mut inv_full = [[T::zero(); K]; K];
    for free in 0..=full {
        let inv = invert(&h, free);
        if free == full {
            inv_full = inv;
        }
        let fixed = full & !free;
        // Every subset `up` of the fixed variables sits at its upper
        // bound, the rest of them at their lower (standard subset walk).
        let mut up = 0u8;
        loop {
            let c = candidate(&h, &g, &lo, &hi, &inv, free, up);
            let (df, hd) = change(&h, &best_grad, &best, &c);
            if df < T::zero() {
                best = c;
                for i in 0..K {
                    best_grad[i] += hd[i];
                }
            }
            up = up.wrapping_sub(fixed) & fixed;
            if up == 0 {
                break;
            }
        }
    }
    let mut out = [T::zero(); MAX_BLOCK];
    out[..K].copy_from_slice(&best);
    (out, dual_gap(&best_grad, &lo, &hi, &inv_full, &best))
}

/// The duality gap of the block's answer `z` (`grad` its gradient, `inv`
/// the inverse of the whole block): a bound on how far its objective is above the block's
/// minimum. The multipliers are the gradient `∇ = Hz + g` of each
/// variable at a bound it pushes against (`z = lo` with `∇ ≥ 0`, `z = hi`
/// with `∇ ≤ 0`), zero for the rest; what they leave of the gradient,
/// `r`, gives `f(z) − f* ≤ ½ rᵀH⁻¹r` (weak duality; the multipliers'
/// complementary terms are zero, `z` being exactly on its bound). Unlike
/// the strong-convexity bound `½‖r‖²/μ`, it does not take the block's
/// weakest direction for every residual: a free variable that the
/// near-singular direction barely moves is bounded by its own curvature.
/// `None` when the block did not invert (a non-positive pivot left a
/// variable out of `inv`).
#[inline(always)]
fn dual_gap<T: RealField + Copy, const K: usize>(
    grad: &[T; K],
    lo: &[T; K],
    hi: &[T; K],
    inv: &[[T; K]; K],
    z: &[T; K],
) -> Option<T> {
    let mut r = [T::zero(); K];
    for i in 0..K {
        if inv[i][i] <= T::zero() {
            return None;
        }
        let d = grad[i];
        let pushes = (z[i] == lo[i] && d >= T::zero()) || (z[i] == hi[i] && d <= T::zero());
        r[i] = if pushes { T::zero() } else { d };
    }
    let mut q = T::zero();
    for i in 0..K {
        let mut s = T::zero();
        for j in 0..K {
            s += inv[i][j] * r[j];
        }
        q += r[i] * s;
    }
    let half = q / (T::one() + T::one());
    Some(if half > T::zero() { half } else { T::zero() })
}

/// The inverse of `H_FF` (F = the set bits of `free`) in the block's own
/// indices, zero outside F. Gauss–Jordan without pivoting: `H_FF` is
/// symmetric positive definite, so every pivot is positive in exact
/// arithmetic; a non-positive one (rounding on a near-singular block)
/// leaves that variable out, and the candidate then clamps its zero.
#[inline(always)]
fn invert<T: RealField + Copy, const K: usize>(h: &[[T; K]; K], free: u8) -> [[T; K]; K] {
    let on = |i: usize| free & (1 << i) != 0;
    let mut a = [[T::zero(); K]; K];
    let mut inv = [[T::zero(); K]; K];
    for i in 0..K {
        if on(i) {
            for j in 0..K {
                if on(j) {
                    a[i][j] = h[i][j];
                }
            }
            inv[i][i] = T::one();
        }
    }
    for p in 0..K {
        if !on(p) {
            continue;
        }
        let piv = a[p][p];
        if piv.partial_cmp(&T::zero()) != Some(core::cmp::Ordering::Greater) {
            inv[p] = [T::zero(); K];
            continue;
        }
        let r = T::one() / piv;
        for j in 0..K {
            a[p][j] *= r;
            inv[p][j] *= r;
        }
        for i in 0..K {
            if i != p && on(i) {
                let f = a[i][p];
                for j in 0..K {
                    a[i][j] -= f * a[p][j];
                    inv[i][j] -= f * inv[p][j];
                }
            }
        }
    }
    inv
}

/// The candidate of one active set: fixed variables at their bound
/// (`up`: upper), free ones solving `H_FF z_F = −(g_F + H_FB z_B)`, then
/// clamped into the box. With the free entries zero first, `g + H c` is
/// `g_F + H_FB z_B` on F; `inv` is zero outside F.
#[inline(always)]
fn candidate<T: RealField + Copy, const K: usize>(
    h: &[[T; K]; K],
    g: &[T; K],
    lo: &[T; K],
    hi: &[T; K],
    inv: &[[T; K]; K],
    free: u8,
    up: u8,
) -> [T; K] {
    let mut c = [T::zero(); K];
    for i in 0..K {
        if free & (1 << i) == 0 {
            c[i] = if up & (1 << i) != 0 { hi[i] } else { lo[i] };
        }
    }
    let mut rhs = *g;
    for i in 0..K {
        for j in 0..K {
            rhs[i] += h[i][j] * c[j];
        }
    }
    for i in 0..K {
        if free & (1 << i) != 0 {
            let mut s = T::zero();
            for j in 0..K {
                s -= inv[i][j] * rhs[j];
            }
            c[i] = clamp(s, lo[i], hi[i]);
        }
    }
    c
}

/// The block's gradient `Hc + g` at `c`.
#[inline(always)]
fn gradient<T: RealField + Copy, const K: usize>(h: &[[T; K]; K], g: &[T; K], c: &[T; K]) -> [T; K] {
    let mut d = *g;
    for i in 0..K {
        for j in 0..K {
            d[i] += h[i][j] * c[j];
        }
    }
    d
}

/// The block's objective at `c` less that at `b` (`grad` its gradient at
/// `b`): `f(c) − f(b) = dᵀ(∇f(b) + ½Hd)` with `d = c − b`. Taken as a
/// difference, not as two objectives: each objective sums terms far
/// larger than itself (`gᵢcᵢ` against `½cᵢ(Hc)ᵢ`), and with a weakly
/// curved block two candidates' objectives then differ by less than
/// their own rounding, so the comparison picked a candidate far from the
/// minimiser; the difference's rounding shrinks with `d`. Also returns
/// `Hd`, the gradient's change (`∇f(c) = ∇f(b) + Hd`).
#[inline(always)]
fn change<T: RealField + Copy, const K: usize>(h: &[[T; K]; K], grad: &[T; K], b: &[T; K], c: &[T; K]) -> (T, [T; K]) {
    let half = T::one() / (T::one() + T::one());
    let mut d = [T::zero(); K];
    for i in 0..K {
        d[i] = c[i] - b[i];
    }
    let mut f = T::zero();
    let mut hd = [T::zero(); K];
    for i in 0..K {
        for j in 0..K {
            hd[i] += h[i][j] * d[j];
        }
        f += d[i] * (grad[i] + half * hd[i]);
    }
    (f, hd)
}
