//! The exact GP layer: log marginal likelihood, joint log predictive density and posterior of the
//! two-output velocity field `(vx, vy)` of one motion pattern.
//!
//! Output η has covariance `σ_η² R + σ_{n,η}² I`. When both outputs have the same signal and
//! noise variances they share one matrix, which is then factored once and solved with two
//! right-hand sides.

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use crate::error::{Error, Result, check_finite};
use crate::frame::{LengthScales, Point};
use crate::kernel;
use crate::linalg::Chol;

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

fn check_points(name: &str, xy: &[Point]) -> Result<()> {
    if xy.is_empty() {
        return Err(Error::Shape(format!(
            "{name} is empty: at least one point is needed"
        )));
    }
    check_finite(name, xy.as_flattened())
}

fn check_pair(xy_name: &str, xy: &[Point], v_name: &str, v: &[[f64; 2]]) -> Result<()> {
    check_points(xy_name, xy)?;
    check_finite(v_name, v.as_flattened())?;
    if xy.len() != v.len() {
        return Err(Error::Shape(format!(
            "{xy_name} has {} points but {v_name} has {} velocities; they must match row for row",
            xy.len(),
            v.len()
        )));
    }
    Ok(())
}

/// Factor `σ² R(xy, xy) + σ_n² I` for the group of outputs `outs`.
pub fn factor(xy: &[Point], p: &GpParams, outs: &[usize], par: Par) -> Result<Chol> {
    let parallel = !matches!(par, Par::Seq);
    let (s2, n2) = p.group_vars(outs);
    Chol::factor(xy.len(), "training", par, || {
        kernel::gram(xy, p.length_scales, s2, n2, parallel)
    })
}

fn sum_sq(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum()
}

/// `log N(v ; μ, σ² R + σ_n² I)` summed over both outputs.
pub fn log_marginal_likelihood(
    xy: &[Point],
    v: &[[f64; 2]],
    p: &GpParams,
    par: Par,
) -> Result<f64> {
    check_pair("xy", xy, "v", v)?;
    let n = xy.len() as f64;
    let mut total = -n * LN_2PI; // (n/2) ln 2π for each of the two outputs
    for outs in p.groups() {
        let chol = factor(xy, p, outs, par)?;
        let mut z = centered(v, outs, p.mean);
        chol.solve_lower(&mut z, par);
        total -= 0.5 * sum_sq(&z) + 0.5 * outs.len() as f64 * chol.log_det();
    }
    Ok(total)
}

/// Joint log density of the test velocities given the training data, summed over both outputs:
/// `log N(v* ; μ + K*ᵀ K⁻¹ (v - μ), K** + σ_n² I - K*ᵀ K⁻¹ K*)`, which equals
/// `log p(train ∪ test) - log p(train)`.
pub fn log_predictive(
    train_xy: &[Point],
    train_v: &[[f64; 2]],
    test_xy: &[Point],
    test_v: &[[f64; 2]],
    p: &GpParams,
    par: Par,
) -> Result<f64> {
    check_pair("train_xy", train_xy, "train_v", train_v)?;
    check_pair("test_xy", test_xy, "test_v", test_v)?;
    let (n, m) = (train_xy.len(), test_xy.len());
    let parallel = !matches!(par, Par::Seq);
    let mut total = -(m as f64) * LN_2PI;
    for outs in p.groups() {
        let g = outs.len();
        let (s2, n2) = p.group_vars(outs);
        let chol = factor(train_xy, p, outs, par)?;
        // V = L⁻¹ K(X, X*)
        let mut vmat = kernel::cross(train_xy, test_xy, p.length_scales, s2, parallel);
        chol.solve_lower(&mut vmat, par);
        let v = MatRef::from_column_major_slice(&vmat, n, m);
        // S = K** + σ_n² I − VᵀV
        let mut s = kernel::gram(test_xy, p.length_scales, s2, n2, parallel);
        matmul(
            MatMut::from_column_major_slice_mut(&mut s, m, m),
            Accum::Add,
            v.transpose(),
            v,
            -1.0,
            par,
        );
        // r = v* − μ − Vᵀ L⁻¹ (v − μ)
        let mut z = centered(train_v, outs, p.mean);
        chol.solve_lower(&mut z, par);
        let mut r = centered(test_v, outs, p.mean);
        matmul(
            MatMut::from_column_major_slice_mut(&mut r, m, g),
            Accum::Add,
            v.transpose(),
            MatRef::from_column_major_slice(&z, n, g),
            -1.0,
            par,
        );
        let cs = Chol::factor(m, "predictive", par, || s.clone())?;
        cs.solve_lower(&mut r, par);
        total -= 0.5 * sum_sq(&r) + 0.5 * g as f64 * cs.log_det();
    }
    Ok(total)
}

/// Posterior mean and variance of the latent (noise-free) field at `query_xy`, per output.
pub fn posterior(
    train_xy: &[Point],
    train_v: &[[f64; 2]],
    query_xy: &[Point],
    p: &GpParams,
    par: Par,
) -> Result<(Vec<[f64; 2]>, Vec<[f64; 2]>)> {
    check_pair("train_xy", train_xy, "train_v", train_v)?;
    check_points("query_xy", query_xy)?;
    let n = train_xy.len();
    let parallel = !matches!(par, Par::Seq);
    let mut mean = vec![[0.0; 2]; query_xy.len()];
    let mut var = vec![[0.0; 2]; query_xy.len()];
    for outs in p.groups() {
        let g = outs.len();
        let s2 = p.signal_var[outs[0]];
        let chol = factor(train_xy, p, outs, par)?;
        let mut z = centered(train_v, outs, p.mean);
        chol.solve_lower(&mut z, par);
        let zr = MatRef::from_column_major_slice(&z, n, g);
        // Blocks of queries bound the memory of W = L⁻¹ K(X, Q) to n x 1024.
        for (qb, block) in query_xy.chunks(1024).enumerate() {
            let mb = block.len();
            let mut w = kernel::cross(train_xy, block, p.length_scales, s2, parallel);
            chol.solve_lower(&mut w, par);
            let wr = MatRef::from_column_major_slice(&w, n, mb);
            let mut mu = vec![0.0; mb * g];
            matmul(
                MatMut::from_column_major_slice_mut(&mut mu, mb, g),
                Accum::Replace,
                wr.transpose(),
                zr,
                1.0,
                par,
            );
            for j in 0..mb {
                let q = qb * 1024 + j;
                let explained = sum_sq(&w[j * n..(j + 1) * n]);
                for (c, &d) in outs.iter().enumerate() {
                    mean[q][d] = p.mean[d] + mu[c * mb + j];
                    var[q][d] = (s2 - explained).max(0.0);
                }
            }
        }
    }
    Ok((mean, var))
}

#[cfg(test)]
#[path = "tests/gp.rs"]
mod tests;
