//! The GP hyperparameters of one motion pattern's two-output velocity field `(vx, vy)`. The
//! densities and the posterior are computed by `pattern::Pattern` (the sampler's patterns, and a
//! standalone GP by `Pattern::single`): one implementation of the exact GP.
//!
//! Output η has covariance `σ_η² R + σ_{n,η}² I`. When both outputs have the same signal and
//! noise variances they share one matrix, which is then factored once and solved with two
//! right-hand sides.

use crate::error::{Error, Result};
use crate::frame::LengthScales;

/// `ln(2π)`.
pub const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Hyperparameters of one pattern's GP.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpParams {
    pub length_scales: LengthScales,
    /// `(σ_x², σ_y²)`: signal variance of each output.
    pub signal_var: [f64; 2],
    /// `(σ_{n,x}², σ_{n,y}²)`: observation noise variance of each output (velocities along
    /// and across a road differ by orders of magnitude, so one shared value fits neither).
    pub noise_var: [f64; 2],
    /// `(μ_x, μ_y)`: constant prior mean of each output.
    pub mean: [f64; 2],
}

impl GpParams {
    /// Validated constructor: length scales and variances must be positive and finite.
    pub fn new(
        length_scales: (f64, f64),
        signal_var: (f64, f64),
        noise_var: (f64, f64),
        mean: (f64, f64),
    ) -> Result<Self> {
        let ls = LengthScales::new(length_scales.0, length_scales.1)?;
        for (name, s) in [
            ("signal_var[0]", signal_var.0),
            ("signal_var[1]", signal_var.1),
            ("noise_var[0]", noise_var.0),
            ("noise_var[1]", noise_var.1),
        ] {
            if !(s.is_finite() && s > 0.0) {
                return Err(Error::InvalidInput(format!(
                    "{name} must be a positive finite variance, got {s}"
                )));
            }
        }
        for (name, m) in [("mean[0]", mean.0), ("mean[1]", mean.1)] {
            if !m.is_finite() {
                return Err(Error::InvalidInput(format!(
                    "{name} must be finite, got {m}"
                )));
            }
        }
        Ok(Self {
            length_scales: ls,
            signal_var: [signal_var.0, signal_var.1],
            noise_var: [noise_var.0, noise_var.1],
            mean: [mean.0, mean.1],
        })
    }

    /// The same parameters with other length scales.
    pub fn with_length_scales(&self, ls: LengthScales) -> Self {
        Self {
            length_scales: ls,
            ..*self
        }
    }

    /// Groups of outputs that share one covariance matrix.
    pub fn groups(&self) -> &'static [&'static [usize]] {
        if self.signal_var[0] == self.signal_var[1] && self.noise_var[0] == self.noise_var[1] {
            &[&[0, 1]]
        } else {
            &[&[0], &[1]]
        }
    }

    /// `(σ², σ_n²)` of the group of outputs `outs` (one of [`GpParams::groups`]).
    pub fn group_vars(&self, outs: &[usize]) -> (f64, f64) {
        (self.signal_var[outs[0]], self.noise_var[outs[0]])
    }
}

/// Column-major `n x outs.len()` buffer of `v[i][d] - μ_d` for each output `d` in `outs`.
pub fn centered(v: &[[f64; 2]], outs: &[usize], mean: [f64; 2]) -> Vec<f64> {
    let mut out = Vec::with_capacity(v.len() * outs.len());
    for &d in outs {
        out.extend(v.iter().map(|r| r[d] - mean[d]));
    }
    out
}

#[cfg(test)]
#[path = "tests/gp.rs"]
mod tests;
