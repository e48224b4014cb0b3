//! Hand-written kernels for the frame-sized (l x l, l ≲ 40) matrices of the inner loop, where a
//! library call's dispatch and scratch allocation cost more than the arithmetic.
//! All matrices are column-major.

use crate::error::{Error, Result};

/// Jitter tried after a failed factorisation, relative to the mean diagonal.
const JITTER_STEPS: [f64; 4] = [1e-10, 1e-8, 1e-6, 1e-4];

fn chol_in_place(a: &mut [f64], m: usize) -> bool {
    for j in 0..m {
        let mut d = a[j * m + j];
        for p in 0..j {
            d -= a[p * m + j] * a[p * m + j];
        }
        if !(d > 0.0) {
            return false;
        }
        let d = d.sqrt();
        a[j * m + j] = d;
        for i in j + 1..m {
            let mut s = a[j * m + i];
            for p in 0..j {
                s -= a[p * m + i] * a[p * m + j];
            }
            a[j * m + i] = s / d;
        }
    }
    true
}

/// Lower Cholesky factor of the symmetric positive definite `a` (lower triangle read), in place,
/// with growing diagonal jitter if needed.
pub fn cholesky(a: &mut [f64], m: usize) -> Result<()> {
    let original = a.to_vec();
    if chol_in_place(a, m) {
        return Ok(());
    }
    let mean_diag = (0..m).map(|i| original[i * m + i]).sum::<f64>() / m as f64;
    let mut jitter = 0.0;
    for step in JITTER_STEPS {
        a.copy_from_slice(&original);
        jitter = step * mean_diag.abs().max(f64::MIN_POSITIVE);
        for i in 0..m {
            a[i * m + i] += jitter;
        }
        if chol_in_place(a, m) {
            return Ok(());
        }
    }
    Err(Error::NotPositiveDefinite {
        what: "frame",
        n: m,
        jitter,
    })
}

/// `b <- L⁻¹ b` for the `m x k` right-hand side `b`.
pub fn solve_lower(l: &[f64], m: usize, b: &mut [f64]) {
    for col in b.chunks_mut(m) {
        for j in 0..m {
            let x = col[j] / l[j * m + j];
            col[j] = x;
            for i in j + 1..m {
                col[i] -= l[j * m + i] * x;
            }
        }
    }
}

/// `log |L Lᵀ|`.
pub fn log_det(l: &[f64], m: usize) -> f64 {
    2.0 * (0..m).map(|i| l[i * m + i].ln()).sum::<f64>()
}

/// `(log |A|, Σ ‖L⁻¹ b_c‖²)` with `A = L Lᵀ` factored from `a`: the two terms of a Gaussian log
/// density for every column of `b`.
pub fn gaussian_terms(mut a: Vec<f64>, m: usize, mut b: Vec<f64>) -> Result<(f64, f64)> {
    cholesky(&mut a, m)?;
    solve_lower(&a, m, &mut b);
    Ok((log_det(&a, m), b.iter().map(|x| x * x).sum()))
}

#[cfg(test)]
#[path = "tests/small.rs"]
mod tests;
