//! A growable lower Cholesky factor: frames are appended as new trailing rows (the append
//! trial's `[Vᵀ, chol S]`) and deleted by a stable rank-l *update* of the trailing block.
//!
//! Storage is column-major with a leading dimension `cap` that grows by a quarter when full
//! ([`capacity`]), so an append writes in place and a delete moves memory inside the buffer.
//! (Doubling wasted up to three quarters of an `n²` buffer: 4.3 GB for a pattern of 8,400 points
//! that needs 1.1 GB, which kept the exact engine out of a 12 GB budget.)

use faer::diag::Diag;
use faer::linalg::cholesky::llt::update::rank_r_update_clobber;
use faer::linalg::triangular_solve::solve_lower_triangular_in_place;
use faer::{MatMut, MatRef, Par};

/// The leading dimension of a buffer for `need` rows: a quarter to spare, a multiple of 16, at
/// least 16. A factor's `cap` never exceeds `capacity` of its order, so `8 capacity(n)²` bytes
/// bound a factor of `n` points.
pub fn capacity(need: usize) -> usize {
    (need + need / 4).max(16).next_multiple_of(16)
}

/// Lower factor `L` (n x n) inside a `cap x cap` column-major buffer.
#[derive(Clone, Debug, Default)]
pub struct GrowFactor {
    n: usize,
    cap: usize,
    buf: Vec<f64>,
}

impl GrowFactor {
    /// Take a dense factor of order `n` stored with leading dimension `n`.
    pub fn from_dense(l: &[f64], n: usize) -> Self {
        let cap = capacity(n);
        let mut buf = vec![0.0; cap * cap];
        for j in 0..n {
            buf[j * cap + j..j * cap + n].copy_from_slice(&l[j * n + j..j * n + n]);
        }
        Self { n, cap, buf }
    }

    /// Take ownership of a dense factor of order `n` with leading dimension `n` (entries above
    /// the diagonal unspecified): no copy and no spare room, for a factor that will not grow.
    pub fn from_owned(l: Vec<f64>, n: usize) -> Self {
        debug_assert_eq!(l.len(), n * n);
        Self { n, cap: n, buf: l }
    }

    pub fn n(&self) -> usize {
        self.n
    }

    /// The buffer's leading dimension (its memory is `cap² · 8` bytes).
    pub fn cap(&self) -> usize {
        self.cap
    }

    pub fn mat(&self) -> MatRef<'_, f64> {
        MatRef::from_column_major_slice_with_stride(&self.buf, self.n, self.n, self.cap)
    }

    fn grow_to(&mut self, need: usize) {
        if need <= self.cap {
            return;
        }
        let cap = capacity(need);
        let mut buf = vec![0.0; cap * cap];
        for j in 0..self.n {
            buf[j * cap + j..j * cap + self.n]
                .copy_from_slice(&self.buf[j * self.cap + j..j * self.cap + self.n]);
        }
        self.cap = cap;
        self.buf = buf;
    }

    /// `log |L Lᵀ|`.
    pub fn log_det(&self) -> f64 {
        2.0 * (0..self.n)
            .map(|i| self.buf[i * self.cap + i].ln())
            .sum::<f64>()
    }

    /// Overwrite the column-major `n x k` buffer `rhs` with `L⁻¹ rhs`.
    pub fn solve_lower(&self, rhs: &mut [f64], par: Par) {
        if self.n == 0 || rhs.is_empty() {
            return;
        }
        let k = rhs.len() / self.n;
        solve_lower_triangular_in_place(
            self.mat(),
            MatMut::from_column_major_slice_mut(rhs, self.n, k),
            par,
        );
    }

    /// Append `m` rows: `vt` is `V = L⁻¹ K(X, X_new)` (n x m, column-major) and `r` the lower
    /// factor of the Schur complement (m x m, column-major, entries above the diagonal ignored).
    pub fn append(&mut self, v: &[f64], r: &[f64], m: usize) {
        let n = self.n;
        self.grow_to(n + m);
        let cap = self.cap;
        for j in 0..n {
            for c in 0..m {
                self.buf[j * cap + n + c] = v[c * n + j];
            }
        }
        for c in 0..m {
            for i in c..m {
                self.buf[(n + c) * cap + n + i] = r[c * m + i];
            }
        }
        self.n = n + m;
    }

    /// Delete rows and columns `p..p+l`. The trailing block is repaired by a rank-l update,
    /// which is numerically stable (no hyperbolic rotations). Returns false if the update lost
    /// positive definiteness (never for exact arithmetic); the caller then refactors.
    pub fn delete(&mut self, p: usize, l: usize) -> bool {
        let (n, cap) = (self.n, self.cap);
        let m = n - p - l; // trailing rows
        // W = L[T, B]: the deleted columns' trailing part.
        let mut w = vec![0.0; m * l];
        for c in 0..l {
            let col = (p + c) * cap;
            w[c * m..(c + 1) * m].copy_from_slice(&self.buf[col + p + l..col + n]);
        }
        // Rows T move up by l in the leading columns.
        for j in 0..p {
            let col = j * cap;
            self.buf.copy_within(col + p + l..col + n, col + p);
        }
        // Trailing columns move left by l and their rows up by l.
        for j in p + l..n {
            let (src, dst) = (j * cap, (j - l) * cap);
            self.buf.copy_within(src + j..src + n, dst + j - l);
        }
        self.n = n - l;
        if m == 0 {
            return true;
        }
        let x = MatMut::from_column_major_slice_with_stride_mut(
            &mut self.buf[p * cap + p..],
            m,
            m,
            cap,
        );
        let wm = MatMut::from_column_major_slice_mut(&mut w, m, l);
        let mut alpha = Diag::<f64>::ones(l);
        rank_r_update_clobber(x, wm, alpha.as_mut()).is_ok()
    }
}

#[cfg(test)]
#[path = "tests/factor.rs"]
mod tests;
