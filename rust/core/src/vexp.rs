//! A branch-free `exp` for non-positive arguments that the compiler vectorises.
//!
//! `f64::exp` calls libm one element at a time (~5.5 ns); kernel assembly is dominated by it.
//! This Cody–Waite reduction plus a degree-12 Taylor polynomial is accurate to a few ulp on
//! [-708, 0] and runs at about 1 ns per element once the loop is vectorised. Kernel arguments
//! are always `-(squared scaled distance) <= 0`, so only that range is needed. It is inlined
//! into the kernel-assembly loop (kernel.rs), which is compiled for AVX2+FMA where available.

const LOG2E: f64 = std::f64::consts::LOG2_E;
const LN2_HI: f64 = 6.931_471_803_691_238e-1;
const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
/// 1.5 * 2^52: adding it rounds to the nearest integer and leaves that integer in the low bits.
const SHIFTER: f64 = 6_755_399_441_055_744.0;
const MIN_ARG: f64 = -708.0;

/// `exp(x)` for `x <= 0`; inline into loops compiled with AVX2+FMA so that they vectorise.
#[inline(always)]
pub(crate) fn exp_nonpos(x: f64) -> f64 {
    let xc = if x < MIN_ARG { MIN_ARG } else { x };
    let t = xc.mul_add(LOG2E, SHIFTER);
    let k = t - SHIFTER;
    let r = k.mul_add(-LN2_LO, k.mul_add(-LN2_HI, xc));
    // Horner for sum_{i<=12} r^i / i!
    let mut p: f64 = 1.0 / 479_001_600.0;
    p = p.mul_add(r, 1.0 / 39_916_800.0);
    p = p.mul_add(r, 1.0 / 3_628_800.0);
    p = p.mul_add(r, 1.0 / 362_880.0);
    p = p.mul_add(r, 1.0 / 40_320.0);
    p = p.mul_add(r, 1.0 / 5_040.0);
    p = p.mul_add(r, 1.0 / 720.0);
    p = p.mul_add(r, 1.0 / 120.0);
    p = p.mul_add(r, 1.0 / 24.0);
    p = p.mul_add(r, 1.0 / 6.0);
    p = p.mul_add(r, 0.5);
    p = p.mul_add(r, 1.0);
    p = p.mul_add(r, 1.0);
    // t's low bits hold k in two's complement; shift (k + 1023) into the exponent field.
    let scale = f64::from_bits(t.to_bits().wrapping_add(1023) << 52);
    if x < MIN_ARG { 0.0 } else { p * scale }
}

#[cfg(test)]
#[path = "tests/vexp.rs"]
mod tests;
