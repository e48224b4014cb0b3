//! A growable lower Cholesky factor: frames are appended as new trailing rows (the append
//! trial's `[Vᵀ, chol S]`) and deleted by a stable rank-l *update* of the trailing block.
//!
//! Storage is column-major with a leading dimension `cap` that doubles when full, so an append
//! writes in place and a delete moves memory inside the buffer.

use faer::diag::Diag;
use faer::linalg::cholesky::llt::update::rank_r_update_clobber;
use faer::linalg::triangular_solve::solve_lower_triangular_in_place;
use faer::{MatMut, MatRef, Par};

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
        let cap = n.next_power_of_two().max(16);
        let mut buf = vec![0.0; cap * cap];
        for j in 0..n {
            buf[j * cap + j..j * cap + n].copy_from_slice(&l[j * n + j..j * n + n]);
        }
        Self { n, cap, buf }
    }

    pub fn n(&self) -> usize {
        self.n
    }

    pub fn mat(&self) -> MatRef<'_, f64> {
        MatRef::from_column_major_slice_with_stride(&self.buf, self.n, self.n, self.cap)
    }

    fn grow_to(&mut self, need: usize) {
        if need <= self.cap {
            return;
        }
        let cap = need.next_power_of_two();
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
mod tests {
    use super::*;
    use crate::linalg::Chol;

    fn spd(n: usize) -> Vec<f64> {
        let mut a = vec![0.0; n * n];
        for j in 0..n {
            for i in 0..n {
                let d = i as f64 - j as f64;
                a[j * n + i] = 2.0 * (-(d * d) / 18.0).exp() + if i == j { 0.5 } else { 0.0 };
            }
        }
        a
    }

    fn dense_l(f: &GrowFactor) -> Vec<f64> {
        let n = f.n();
        let mut out = vec![0.0; n * n];
        for j in 0..n {
            for i in j..n {
                out[j * n + i] = f.mat()[(i, j)];
            }
        }
        out
    }

    fn sub(a: &[f64], n: usize, keep: &[usize]) -> Vec<f64> {
        let k = keep.len();
        let mut s = vec![0.0; k * k];
        for (jj, &j) in keep.iter().enumerate() {
            for (ii, &i) in keep.iter().enumerate() {
                s[jj * k + ii] = a[j * n + i];
            }
        }
        s
    }

    #[test]
    fn delete_matches_a_fresh_factor() {
        let n = 40;
        let a = spd(n);
        let c = Chol::factor(n, "t", Par::Seq, || a.clone()).unwrap();
        for (p, l) in [(0, 5), (10, 7), (33, 7), (20, 1)] {
            let mut f = GrowFactor::from_dense(&c.l, n);
            assert!(f.delete(p, l));
            let keep: Vec<usize> = (0..n).filter(|i| *i < p || *i >= p + l).collect();
            let s = sub(&a, n, &keep);
            let fresh = Chol::factor(keep.len(), "t", Par::Seq, || s.clone()).unwrap();
            let got = dense_l(&f);
            for j in 0..keep.len() {
                for i in j..keep.len() {
                    let (g, e) = (got[j * keep.len() + i], fresh.l[j * keep.len() + i]);
                    assert!((g - e).abs() < 1e-12, "p={p} l={l} ({i},{j}): {g} vs {e}");
                }
            }
        }
    }

    #[test]
    fn append_grows_past_capacity() {
        let n = 30;
        let a = spd(n);
        let head = sub(&a, n, &(0..10).collect::<Vec<_>>());
        let c = Chol::factor(10, "t", Par::Seq, || head.clone()).unwrap();
        let mut f = GrowFactor::from_dense(&c.l, 10);
        // Append rows 10..30 in blocks of 5 via the Schur complement, then compare.
        for start in (10..30).step_by(5) {
            let k = f.n();
            let mut v = vec![0.0; k * 5];
            for c in 0..5 {
                for i in 0..k {
                    v[c * k + i] = a[(start + c) * n + i];
                }
            }
            f.solve_lower(&mut v, Par::Seq);
            let mut s = sub(&a, n, &(start..start + 5).collect::<Vec<_>>());
            for c in 0..5 {
                for r in 0..5 {
                    s[c * 5 + r] -= (0..k).map(|i| v[r * k + i] * v[c * k + i]).sum::<f64>();
                }
            }
            let r = Chol::factor(5, "t", Par::Seq, || s.clone()).unwrap();
            f.append(&v, &r.l, 5);
        }
        let full = Chol::factor(n, "t", Par::Seq, || a.clone()).unwrap();
        let got = dense_l(&f);
        for j in 0..n {
            for i in j..n {
                assert!((got[j * n + i] - full.l[j * n + i]).abs() < 1e-12);
            }
        }
        assert!((f.log_det() - full.log_det()).abs() < 1e-10);
    }
}
