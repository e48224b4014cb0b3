//! Dense Cholesky factors over column-major buffers, with jitter escalation, and the
//! triangular solves built on them. Thin wrappers over faer's low-level kernels so that the
//! parallelism (`Par`) is always explicit.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{
    LltRegularization, cholesky_in_place, cholesky_in_place_scratch,
};
use faer::linalg::triangular_solve::solve_lower_triangular_in_place;
use faer::{MatMut, MatRef, Par};

use crate::error::{Error, Result};

/// Jitter tried after a failed factorisation, relative to the mean diagonal.
const JITTER_STEPS: [f64; 4] = [1e-10, 1e-8, 1e-6, 1e-4];

/// Choose faer's parallelism for a matrix of order `n` when not already inside a parallel loop.
pub fn par_for(n: usize) -> Par {
    if n >= 768 && rayon::current_num_threads() > 1 {
        Par::rayon(0)
    } else {
        Par::Seq
    }
}

/// Factor the column-major `n x n` matrix in `a` in place (lower triangle).
pub fn cholesky(a: &mut [f64], n: usize, par: Par) -> std::result::Result<(), usize> {
    let req = cholesky_in_place_scratch::<f64>(n, par, Default::default());
    let mut buf = MemBuffer::new(req);
    let stack = MemStack::new(&mut buf);
    let mat = MatMut::from_column_major_slice_mut(a, n, n);
    cholesky_in_place(
        mat,
        LltRegularization::default(),
        par,
        stack,
        Default::default(),
    )
    .map(|_| ())
    .map_err(|faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index }| index)
}

/// A lower Cholesky factor `L` with `L L^T = A + jitter * I`, stored column-major.
/// Entries above the diagonal are unspecified.
#[derive(Clone, Debug)]
pub struct Chol {
    pub n: usize,
    pub l: Vec<f64>,
    /// Diagonal jitter that was needed (0 when the matrix factored as given).
    pub jitter: f64,
}

impl Chol {
    /// Factor the matrix that `build` writes into an `n x n` column-major buffer, adding
    /// growing diagonal jitter if it is not numerically positive definite.
    pub fn factor(
        n: usize,
        what: &'static str,
        par: Par,
        build: impl Fn() -> Vec<f64>,
    ) -> Result<Self> {
        let mut l = build();
        debug_assert_eq!(l.len(), n * n);
        if cholesky(&mut l, n, par).is_ok() {
            return Ok(Self { n, l, jitter: 0.0 });
        }
        let mut jitter = 0.0;
        for step in JITTER_STEPS {
            l = build();
            let mean_diag = (0..n).map(|i| l[i * n + i]).sum::<f64>() / n as f64;
            jitter = step * mean_diag.abs().max(f64::MIN_POSITIVE);
            for i in 0..n {
                l[i * n + i] += jitter;
            }
            if cholesky(&mut l, n, par).is_ok() {
                return Ok(Self { n, l, jitter });
            }
        }
        Err(Error::NotPositiveDefinite { what, n, jitter })
    }

    pub fn mat(&self) -> MatRef<'_, f64> {
        MatRef::from_column_major_slice(&self.l, self.n, self.n)
    }

    /// `log |A| = 2 sum log L_ii`.
    pub fn log_det(&self) -> f64 {
        2.0 * (0..self.n)
            .map(|i| self.l[i * self.n + i].ln())
            .sum::<f64>()
    }

    /// Overwrite the column-major `n x k` buffer `rhs` with `L^{-1} rhs`.
    pub fn solve_lower(&self, rhs: &mut [f64], par: Par) {
        let k = rhs.len() / self.n.max(1);
        if self.n == 0 || k == 0 {
            return;
        }
        let b = MatMut::from_column_major_slice_mut(rhs, self.n, k);
        solve_lower_triangular_in_place(self.mat(), b, par);
    }
}

#[cfg(test)]
#[path = "tests/linalg.rs"]
mod tests;
