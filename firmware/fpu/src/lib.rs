//! The single-precision FPU's square root for the flight core.
//!
//! Stable `core` has no `f32::sqrt` (it is `std`'s), so `no_std` code
//! calls `libm::sqrtf`, which on Arm is libm's integer algorithm in
//! software, where the Cortex-M4F has an instruction, `VSQRT.F32` (14
//! cycles on silicon, ST PM0214 §3.10); here it takes four moves beside
//! it (below). Both are IEEE 754 square roots, correctly
//! rounded, so the two give the same bits for every input: the host (libm,
//! or SSE's `sqrtss` under it) and the chip compute the same flight. The
//! QEMU harness `equivalence` holds the chip's against libm's, bit for
//! bit, over inputs of every exponent and sign (QEMU's `VSQRT` is
//! softfloat's correctly rounded square root; on silicon the same holds by
//! the architecture, not checked here).
//!
//! Its own crate because the flight core forbids `unsafe` and `asm!` needs
//! it: this is that instruction, with nothing else beside it.

#![no_std]
#![deny(missing_docs)]

/// `√x`, correctly rounded (IEEE 754): `NaN` for `x < 0` or `NaN`, `-0.0`
/// for `-0.0`. `VSQRT.F32` on a hard-float Arm target, `libm::sqrtf`
/// elsewhere; the same bits on both.
#[inline(always)]
pub fn sqrt(x: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        let r: u32;
        // Stable rustc does not see this target's FPU as a target feature,
        // so `asm!` may not name an FPU register as an operand: the value
        // goes in and out in core registers, through `s0`, which is kept.
        // SAFETY: the sequence reads and writes core registers it names,
        // and `s0` which it restores; it touches no memory, no stack and no
        // flags but the FPSCR's cumulative exception bits, which nothing
        // reads.
        unsafe {
            core::arch::asm!(
                "vmov {keep}, s0",
                "vmov s0, {x}",
                "vsqrt.f32 s0, s0",
                "vmov {r}, s0",
                "vmov s0, {keep}",
                x = in(reg) x.to_bits(),
                r = lateout(reg) r,
                keep = out(reg) _,
                options(pure, nomem, nostack, preserves_flags)
            );
        }
        f32::from_bits(r)
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    {
        libm::sqrtf(x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The special cases IEEE 754 fixes, and exact squares.
    #[test]
    fn ieee_special_cases_and_exact_squares() {
        assert!(sqrt(-1.0).is_nan() && sqrt(f32::NAN).is_nan());
        assert_eq!(sqrt(f32::INFINITY), f32::INFINITY);
        assert_eq!(sqrt(0.0).to_bits(), 0.0f32.to_bits());
        assert_eq!(sqrt(-0.0).to_bits(), (-0.0f32).to_bits());
        for i in 1..=4096u32 {
            let r = i as f32;
            assert_eq!(sqrt(r * r), r);
        }
    }

    /// Correctly rounded: against f64's square root, rounded once to f32.
    #[test]
    fn correctly_rounded_against_f64() {
        let mut bits = 0x0000_0001u32;
        while bits < 0x7f80_0000 {
            let x = f32::from_bits(bits);
            assert_eq!(sqrt(x), (x as f64).sqrt() as f32, "{x:e}");
            bits = bits.wrapping_add(0x0001_3579);
        }
    }
}
