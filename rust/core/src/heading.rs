//! The periodic kernel over a vehicle's previous heading (docs/heading.md; algorithms.md §3.12).
//!
//! A field over position and heading has the product kernel `σ² k_SE(p, p') k_h(h, h')` with
//! `k_h(h, h') = exp(−2 sin²((h − h') / 2) / w_h²) = exp(z (cos(h − h') − 1))`, `z = w_h⁻²`: two
//! vehicles at one place share a velocity in proportion to how alike their headings are, so
//! opposite lanes and turning movements no longer average. Its Fourier series
//! `k_h = Σ_j q_j² cos(j (h − h'))`, `q_0² = I_0(z) e^{−z}`, `q_j² = 2 I_j(z) e^{−z}` (Solin &
//! Särkkä 2014) makes the reduced-rank basis `φ_jk(x, y) × {1, cos h, sin h, cos 2h, …}` with
//! prior weights `s_jk q_c²`: the patterns' statistics stay sums.
//!
//! A vehicle without a previous step (its first frame) has no heading (`NaN`). It observes the
//! field averaged over heading, `f̄(p) = (2π)⁻¹ ∫ f(p, h) dh`: a linear functional of the same
//! GP, so its density is still exact and proper. Its covariance with any point is `q_0²` times the
//! position part, and in the basis only the constant heading function is non-zero.
//!
//! `w_h = ∞` is the paper's position-only field (`k_h ≡ 1`, `q_0 = 1`).

use crate::special::bessel_ive;

/// Whether a heading length scale makes the field depend on heading.
#[inline]
pub fn is_headed(wh: f64) -> bool {
    wh.is_finite()
}

/// `z = 1 / w_h²` (zero for the position-only field).
#[inline]
fn concentration(wh: f64) -> f64 {
    if is_headed(wh) { 1.0 / (wh * wh) } else { 0.0 }
}

/// The kernel's Fourier weights `q_j²`, `j = 0..=harmonics`, at heading length scale `wh`.
pub fn spectrum(wh: f64, harmonics: usize) -> Vec<f64> {
    let mut q = bessel_ive(harmonics, concentration(wh));
    q.iter_mut().skip(1).for_each(|x| *x *= 2.0);
    q
}

/// `q_0² = I_0(z) e^{−z}`: the heading kernel averaged over one heading (or both), at
/// concentration `z = 1 / w_h²`.
pub fn bessel_q0(z: f64) -> f64 {
    bessel_ive(0, z)[0]
}

/// `k_h(a, b)`: the exact periodic kernel, `q_0²` when either heading is unknown (`NaN`).
pub struct HeadingKernel {
    z: f64,
    q0: f64,
}

impl HeadingKernel {
    pub fn new(wh: f64) -> Self {
        let z = concentration(wh);
        Self {
            z,
            q0: bessel_q0(z),
        }
    }

    #[inline]
    pub fn eval(&self, a: f64, b: f64) -> f64 {
        let d = a - b;
        if d.is_nan() {
            self.q0
        } else {
            (self.z * (d.cos() - 1.0)).exp()
        }
    }
}

/// The heading functions of the basis at `h`, in feature order: `1, cos h, sin h, cos 2h, sin 2h,
/// …` (`2 harmonics + 1` values); an unknown heading gives the average over heading, `1, 0, 0, …`.
pub fn features(h: f64, out: &mut [f64]) {
    out.fill(0.0);
    out[0] = 1.0;
    if h.is_nan() {
        return;
    }
    for (j, pair) in out[1..].chunks_exact_mut(2).enumerate() {
        let (s, c) = ((j + 1) as f64 * h).sin_cos();
        pair[0] = c;
        pair[1] = s;
    }
}

/// The heading harmonic of basis column `c` (`0` for the constant, `j` for `cos jh` and `sin jh`).
#[inline]
pub fn harmonic_of(c: usize) -> usize {
    c.div_ceil(2)
}

/// Fewest harmonics whose truncated series keeps all but `1%` of the kernel's variance at the
/// shortest heading length scale `wh_lo` the fit expects (the dropped weights are `Σ_{j>J} q_j²`;
/// `Σ_j q_j² = 1`). The truncated kernel is itself a valid, smoother periodic kernel, so the cut
/// sets resolution in heading, not correctness.
pub fn harmonics_for(wh_lo: f64) -> usize {
    if !is_headed(wh_lo) {
        return 0;
    }
    let q = spectrum(wh_lo, 64);
    let mut kept = 0.0;
    for (j, x) in q.iter().enumerate() {
        kept += x;
        if kept >= 0.99 {
            return j;
        }
    }
    64
}

#[cfg(test)]
#[path = "tests/heading.rs"]
mod tests;
