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
mod tests {
    use super::*;
    use crate::linalg::Chol;
    use faer::Par;

    #[test]
    fn agrees_with_faer() {
        let m = 17;
        let mut a = vec![0.0; m * m];
        for j in 0..m {
            for i in 0..m {
                let d = i as f64 - j as f64;
                a[j * m + i] = (-(d * d) / 8.0).exp() + if i == j { 0.3 } else { 0.0 };
            }
        }
        let reference = Chol::factor(m, "t", Par::Seq, || a.clone()).unwrap();
        let mut l = a.clone();
        cholesky(&mut l, m).unwrap();
        for j in 0..m {
            for i in j..m {
                assert!((l[j * m + i] - reference.l[j * m + i]).abs() < 1e-13);
            }
        }
        let b: Vec<f64> = (0..2 * m).map(|i| (i as f64).sin()).collect();
        let (mut bb, mut rb) = (b.clone(), b.clone());
        solve_lower(&l, m, &mut bb);
        reference.solve_lower(&mut rb, Par::Seq);
        assert!(bb.iter().zip(&rb).all(|(x, y)| (x - y).abs() < 1e-12));
        assert!((log_det(&l, m) - reference.log_det()).abs() < 1e-12);
        assert!(cholesky(&mut vec![-1.0], 1).is_err());
    }
}
