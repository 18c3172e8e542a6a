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
//! objective. The KKT point is one of the candidates and is already inside
//! the box, and every clamped candidate is feasible, so in exact arithmetic
//! the kept candidate is the minimiser: the answer is exact after a fixed
//! amount of work that does not depend on the data (no iteration, no
//! tolerance, no active-set guess). In the solver's float type it is the
//! minimiser up to rounding, which [`super::QpSolution::gap`] certifies.
//!
//! Steps per block (`solve_block`): load the block, `invert` each principal
//! submatrix once, then for each active set build its `candidate`, take its
//! `objective` and keep the least.

use crate::math::clamp;
use nalgebra::{RealField, SMatrix, SVector};

/// Largest block solved by enumeration (3⁴ = 81 active sets).
pub const MAX_BLOCK: usize = 4;

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
    /// finite with `lb ≤ ub` by the caller), inside the box.
    pub fn solve<T: RealField + Copy>(
        &self,
        h: &SMatrix<T, N, N>,
        g: &SVector<T, N>,
        lb: &SVector<T, N>,
        ub: &SVector<T, N>,
    ) -> SVector<T, N> {
        let mut z = SVector::<T, N>::zeros();
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
            let zb = match idx.len() {
                1 => solve_block::<T, 1>(&hb, &gb),
                2 => solve_block::<T, 2>(&hb, &gb),
                3 => solve_block::<T, 3>(&hb, &gb),
                _ => solve_block::<T, MAX_BLOCK>(&hb, &gb),
            };
            for (a, &i) in idx.iter().enumerate() {
                z[i as usize] = zb[a];
            }
        }
        z
    }
}

/// One block of `K` variables solved by enumeration: `hm` its Hessian,
/// `data` its linear term, lower and upper bounds (the first `K` entries of
/// each are read); its answer in the first `K` entries.
///
/// The data is copied into `K`-sized arrays so that every loop below has a
/// constant trip count and unrolls into straight-line code.
// Out of line: four sizes of it would otherwise be inlined into each caller.
#[inline(never)]
fn solve_block<T: RealField + Copy, const K: usize>(
    hm: &[[T; MAX_BLOCK]; MAX_BLOCK],
    data: &[[T; MAX_BLOCK]; 3],
) -> [T; MAX_BLOCK] {
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
    let mut best_f = objective(&h, &g, &best);
    for free in 0..=full {
        let inv = invert(&h, free);
        let fixed = full & !free;
        // Every subset `up` of the fixed variables sits at its upper
        // bound, the rest of them at their lower (standard subset walk).
        let mut up = 0u8;
        loop {
            let c = candidate(&h, &g, &lo, &hi, &inv, free, up);
            let f = objective(&h, &g, &c);
            if f < best_f {
                best_f = f;
                best = c;
            }
            up = up.wrapping_sub(fixed) & fixed;
            if up == 0 {
                break;
            }
        }
    }
    let mut out = [T::zero(); MAX_BLOCK];
    out[..K].copy_from_slice(&best);
    out
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

/// The block's objective `½cᵀHc + gᵀc`.
#[inline(always)]
fn objective<T: RealField + Copy, const K: usize>(h: &[[T; K]; K], g: &[T; K], c: &[T; K]) -> T {
    let half = T::one() / (T::one() + T::one());
    let mut f = T::zero();
    for i in 0..K {
        let mut hc = T::zero();
        for j in 0..K {
            hc += h[i][j] * c[j];
        }
        f += c[i] * (g[i] + half * hc);
    }
    f
}
