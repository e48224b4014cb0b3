//! The Hilbert-space reduced-rank GP (Solin & Särkkä 2020; Riutort-Mayol et al. 2023).
//!
//! On a box `[c − L, c + L]` per axis, the Laplacian's Dirichlet eigenfunctions
//! `φ_j(u) = sin(π j (u − c + L) / (2L)) / √L` with `√λ_j = π j / (2L)` give the separable basis
//! `φ_jk(x, y) = φ_j(x) φ_k(y)`, and the squared-exponential kernel becomes
//! `k̃(p, q) = σ² Σ_jk s_jk φ_jk(p) φ_jk(q)` with `s_jk = S_x(√λ_j) S_y(√λ_k)` the kernel's
//! (unit-variance) spectral density, `S(ω) = √(2π) w exp(−w² ω² / 2)` per axis. `k̃` is itself a
//! valid kernel, so "the HSGP model" is a GP model in its own right: every density here is exact
//! for it, and the sampler targets its posterior.
//!
//! A pattern's data enter only through sums over its frames that do not depend on the length
//! scales: `G = Σ ΦᵀΦ` (M x M), `Φᵀ1`, `Φᵀv`, `Σv`, `Σv²`. With `D = σ diag(√s)` and
//! `B = σ_n² I + D G D = R Rᵀ`, the marginal likelihood of one output is
//! `−½ (yᵀy − ‖R⁻¹ D b‖²) / σ_n² − ½ ((n − M) log σ_n² + log|B|) − (n/2) log 2π`, so a move is a
//! rank-l update of `R` and a length-scale evaluation one M x M Cholesky, whatever the pattern
//! size. Points outside the box have no basis support: the model's field there is its mean.

use std::f64::consts::PI;
use std::sync::{Arc, OnceLock};

use faer::diag::Diag;
use faer::linalg::cholesky::llt::update::rank_r_update_clobber;
use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::{Accum, MatMut, MatRef, Par};

use crate::error::{Error, Result};
use crate::frame::FrameRef;
use crate::frame::{LengthScales, Point};
use crate::gp::{GpParams, LN_2PI};
use crate::linalg::Chol;
use crate::small;

/// Most basis functions a fit may use (M x M matrices of 8 bytes: 128 MiB each at the cap).
pub const MAX_BASIS: usize = 4096;
/// Frames whose features enter the Gram matrix in one product when a pattern is built.
const STATS_BLOCK: usize = 64;

/// The basis: a box per axis and the number of eigenfunctions along each.
#[derive(Clone, Debug, PartialEq)]
pub struct Basis {
    center: [f64; 2],
    half: [f64; 2],
    m: [usize; 2],
}

impl Basis {
    pub fn new(center: [f64; 2], half: [f64; 2], m: [usize; 2]) -> Result<Self> {
        if !(center.iter().all(|c| c.is_finite()) && half.iter().all(|h| h.is_finite() && *h > 0.0))
        {
            return Err(Error::InvalidInput(format!(
                "the basis box needs a finite centre and positive half-widths, got {center:?}, {half:?}"
            )));
        }
        if m[0] == 0 || m[1] == 0 || m[0].saturating_mul(m[1]) > MAX_BASIS {
            return Err(Error::InvalidInput(format!(
                "n_basis must be two positive counts with a product of at most {MAX_BASIS}, got {m:?}"
            )));
        }
        Ok(Self { center, half, m })
    }

    /// The documented sizing rule for training positions `xy`. Per axis, with `S` the data's
    /// half-range, `w_lo` a low and `w_mid` a typical length scale: the box half-width is
    /// `L = max(1.2 S, S + 2 w_mid)` (the boundary distorts `k̃` within about two length scales
    /// of it) and `m = ceil(2 L / w_lo)`, which puts the highest frequency at `π / w_lo`, where
    /// the spectral density has fallen to `e^{−π²/2} ≈ 0.7%` of its peak for `w = w_lo` and to
    /// far less for the typical `w`. `m` given by the caller overrides the count.
    pub fn for_data(
        xy: &[Point],
        w_lo: [f64; 2],
        w_mid: [f64; 2],
        m: Option<[usize; 2]>,
    ) -> Result<Self> {
        if xy.is_empty() {
            return Err(Error::Shape("no positions to size the basis from".into()));
        }
        let mut center = [0.0; 2];
        let mut half = [0.0; 2];
        let mut count = [0; 2];
        for d in 0..2 {
            let lo = xy.iter().map(|p| p[d]).fold(f64::INFINITY, f64::min);
            let hi = xy.iter().map(|p| p[d]).fold(f64::NEG_INFINITY, f64::max);
            if !(w_lo[d] > 0.0 && w_mid[d] > 0.0 && w_lo[d].is_finite() && w_mid[d].is_finite()) {
                return Err(Error::InvalidInput(format!(
                    "length scales for sizing the basis must be positive, got {w_lo:?}, {w_mid:?}"
                )));
            }
            let s = (0.5 * (hi - lo)).max(w_lo[d]);
            center[d] = 0.5 * (lo + hi);
            half[d] = (1.2 * s).max(s + 2.0 * w_mid[d]);
            count[d] = ((2.0 * half[d] / w_lo[d]).ceil() as usize).max(4);
        }
        let count = match m {
            Some(m) => m,
            None => {
                // Past the cap, shrink both counts in proportion.
                let total = count[0] * count[1];
                if total > MAX_BASIS {
                    let f = (MAX_BASIS as f64 / total as f64).sqrt();
                    [0, 1].map(|d| ((count[d] as f64 * f).floor() as usize).max(1))
                } else {
                    count
                }
            }
        };
        Self::new(center, half, count)
    }

    /// [`Basis::for_data`] with the low and typical length scales of the fit: the 5% quantile
    /// and the median of the Gamma(shape, scale) prior, or the fixed length scales.
    pub fn for_prior(
        xy: &[Point],
        prior: (f64, f64),
        fixed: Option<LengthScales>,
        m: Option<[usize; 2]>,
    ) -> Result<Self> {
        let (lo, mid) = match fixed {
            Some(ls) => ([ls.wx, ls.wy], [ls.wx, ls.wy]),
            None => {
                let (a, b) = prior;
                if !(a > 0.0 && b > 0.0 && a.is_finite() && b.is_finite()) {
                    return Err(Error::InvalidInput(format!(
                        "length_scale_prior must be (shape, scale) with both positive, got {prior:?}"
                    )));
                }
                let lo = crate::special::gamma_quantile(0.05, a, b);
                let mid = crate::special::gamma_quantile(0.5, a, b);
                ([lo; 2], [mid; 2])
            }
        };
        Self::for_data(xy, lo, mid, m)
    }

    pub fn len(&self) -> usize {
        self.m[0] * self.m[1]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn center(&self) -> [f64; 2] {
        self.center
    }

    pub fn half_widths(&self) -> [f64; 2] {
        self.half
    }

    pub fn counts(&self) -> [usize; 2] {
        self.m
    }

    fn sqrt_eig(&self, d: usize, j: usize) -> f64 {
        PI * (j + 1) as f64 / (2.0 * self.half[d])
    }

    /// `φ_j(u)` along axis `d` for every `j`, zero outside the box.
    fn eval_axis(&self, d: usize, u: f64, out: &mut [f64]) {
        let t = u - self.center[d] + self.half[d];
        if !(0.0..=2.0 * self.half[d]).contains(&t) {
            out.fill(0.0);
            return;
        }
        let norm = 1.0 / self.half[d].sqrt();
        let theta = PI * t / (2.0 * self.half[d]);
        for (j, o) in out.iter_mut().enumerate() {
            *o = norm * ((j + 1) as f64 * theta).sin();
        }
    }

    /// Whether `p` lies in the box (where the basis has support).
    pub fn contains(&self, p: Point) -> bool {
        (0..2).all(|d| (p[d] - self.center[d]).abs() <= self.half[d])
    }

    /// `Φᵀ` of the points: column-major `M x n`, one column of basis values per point
    /// (index `j + m_x k` for `φ_j(x) φ_k(y)`).
    pub fn features(&self, xy: &[Point]) -> Vec<f64> {
        let (mx, my) = (self.m[0], self.m[1]);
        let mm = mx * my;
        let mut out = vec![0.0; mm * xy.len()];
        let mut fx = vec![0.0; mx];
        let mut fy = vec![0.0; my];
        for (col, p) in out.chunks_mut(mm).zip(xy) {
            self.eval_axis(0, p[0], &mut fx);
            self.eval_axis(1, p[1], &mut fy);
            for (k, &y) in fy.iter().enumerate() {
                for (c, &x) in col[k * mx..(k + 1) * mx].iter_mut().zip(&fx) {
                    *c = x * y;
                }
            }
        }
        out
    }

    /// Per-axis unit spectral densities `S_d(√λ_j)` at length scales `ls`.
    fn axis_spectra(&self, ls: LengthScales) -> [Vec<f64>; 2] {
        let w = [ls.wx, ls.wy];
        [0, 1].map(|d| {
            (0..self.m[d])
                .map(|j| {
                    let o = self.sqrt_eig(d, j);
                    (2.0 * PI).sqrt() * w[d] * (-0.5 * w[d] * w[d] * o * o).exp()
                })
                .collect()
        })
    }

    /// `√s_jk` for every basis function, in feature order.
    pub fn sqrt_spectral(&self, ls: LengthScales) -> Vec<f64> {
        let [sx, sy] = self.axis_spectra(ls);
        sy.iter()
            .flat_map(|&y| sx.iter().map(move |&x| (x * y).sqrt()))
            .collect()
    }

    /// The eigenfunctions along each axis at the points (points x m_d, column-major): what
    /// [`Basis::correlation_between`] needs, independent of the length scales.
    pub fn axis_features(&self, pts: &[Point]) -> AxisFeatures {
        let n = pts.len();
        let f = [0, 1].map(|d| {
            let m = self.m[d];
            let mut f = vec![0.0; n * m];
            let mut col = vec![0.0; m];
            for (i, p) in pts.iter().enumerate() {
                self.eval_axis(d, p[d], &mut col);
                for (j, c) in col.iter().enumerate() {
                    f[j * n + i] = *c;
                }
            }
            f
        });
        AxisFeatures { n, f }
    }

    /// `scale · k̃(a, b) / σ²`, i.e. `scale Σ s φ(a) φ(b)`, column-major `|a| x |b|`. Separable:
    /// the product of two one-axis sums, `|a| |b| (m_x + m_y)` work.
    pub fn correlation_between(
        &self,
        a: &AxisFeatures,
        b: &AxisFeatures,
        ls: LengthScales,
        scale: f64,
    ) -> Vec<f64> {
        let spectra = self.axis_spectra(ls);
        let mut out = vec![scale; a.n * b.n];
        if out.is_empty() {
            return out;
        }
        let mut k = vec![0.0; a.n * b.n];
        for d in 0..2 {
            let m = self.m[d];
            // a's eigenfunctions weighted by the spectrum, times b's.
            let mut fa = a.f[d].clone();
            for (j, s) in spectra[d].iter().enumerate() {
                for x in &mut fa[j * a.n..(j + 1) * a.n] {
                    *x *= s;
                }
            }
            matmul(
                MatMut::from_column_major_slice_mut(&mut k, a.n, b.n),
                Accum::Replace,
                MatRef::from_column_major_slice(&fa, a.n, m),
                MatRef::from_column_major_slice(&b.f[d], b.n, m).transpose(),
                1.0,
                Par::Seq,
            );
            for (o, x) in out.iter_mut().zip(&k) {
                *o *= x;
            }
        }
        out
    }

    /// [`Basis::correlation_between`] of two point sets.
    pub fn correlation(&self, a: &[Point], b: &[Point], ls: LengthScales, scale: f64) -> Vec<f64> {
        let fa = self.axis_features(a);
        if std::ptr::eq(a, b) {
            return self.correlation_between(&fa, &fa, ls, scale);
        }
        self.correlation_between(&fa, &self.axis_features(b), ls, scale)
    }
}

/// Eigenfunction values of a set of points along each axis.
#[derive(Clone, Debug)]
pub struct AxisFeatures {
    n: usize,
    f: [Vec<f64>; 2],
}

/// Per output group: `R = chol(σ_n² I + D G D)` and `z = R⁻¹ D b` (M x outputs).
#[derive(Clone, Debug)]
struct Group {
    outs: &'static [usize],
    signal_var: f64,
    noise_var: f64,
    chol: Vec<f64>,
    z: Vec<f64>,
}

impl Group {
    fn r(&self, m: usize) -> MatRef<'_, f64> {
        MatRef::from_column_major_slice(&self.chol, m, m)
    }

    fn log_det(&self, m: usize) -> f64 {
        2.0 * (0..m).map(|i| self.chol[i * m + i].ln()).sum::<f64>()
    }
}

/// A motion pattern under the reduced-rank GP: its frames, the additive statistics and the
/// factors of each output group.
#[derive(Clone, Debug)]
pub struct HsgpPattern {
    basis: Arc<Basis>,
    pub params: GpParams,
    frames: Vec<usize>,
    sizes: Vec<usize>,
    xy: Vec<Point>,
    v: Vec<[f64; 2]>,
    /// `G = Σ ΦᵀΦ`, M x M (both triangles).
    gram: Vec<f64>,
    /// `Φᵀ1` (M) and `Φᵀ v_d` (M x 2).
    phi_sum: Vec<f64>,
    phi_v: Vec<f64>,
    v_sum: [f64; 2],
    v_sq: [f64; 2],
    /// `√s` at the current length scales.
    sqrt_s: Vec<f64>,
    groups: Vec<Group>,
    /// Per group, the posterior mean weights `D R⁻ᵀ z` (M x outputs), on first use.
    weights: OnceLock<Vec<Vec<f64>>>,
}

impl HsgpPattern {
    pub fn new(
        basis: Arc<Basis>,
        params: GpParams,
        members: &[(usize, FrameRef<'_>)],
    ) -> Result<Self> {
        let m = basis.len();
        let mut p = Self {
            sqrt_s: basis.sqrt_spectral(params.length_scales),
            basis,
            params,
            frames: Vec::new(),
            sizes: Vec::new(),
            xy: Vec::new(),
            v: Vec::new(),
            gram: vec![0.0; m * m],
            phi_sum: vec![0.0; m],
            phi_v: vec![0.0; 2 * m],
            v_sum: [0.0; 2],
            v_sq: [0.0; 2],
            groups: Vec::new(),
            weights: OnceLock::new(),
        };
        // The Gram matrix in blocks of frames (one level-3 product each), the rest per frame.
        for block in members.chunks(STATS_BLOCK) {
            let pts: Vec<Point> = block.iter().flat_map(|m| m.1.xy.iter().copied()).collect();
            let phi_t = p.basis.features(&pts);
            let pt = MatRef::from_column_major_slice(&phi_t, m, pts.len());
            matmul(
                MatMut::from_column_major_slice_mut(&mut p.gram, m, m),
                Accum::Add,
                pt,
                pt.transpose(),
                1.0,
                Par::Seq,
            );
            let mut col = 0;
            for &(id, f) in block {
                let l = f.xy.len();
                p.add_vectors(&phi_t[col * m..(col + l) * m], f, 1.0);
                col += l;
                p.record(id, f);
            }
        }
        p.refactor()?;
        Ok(p)
    }

    fn m(&self) -> usize {
        self.basis.len()
    }

    pub fn basis(&self) -> &Arc<Basis> {
        &self.basis
    }

    pub fn n_frames(&self) -> usize {
        self.frames.len()
    }

    pub fn frames(&self) -> &[usize] {
        &self.frames
    }

    pub fn sizes(&self) -> &[usize] {
        &self.sizes
    }

    pub fn points(&self) -> (&[Point], &[[f64; 2]]) {
        (&self.xy, &self.v)
    }

    /// Bytes held by the M x M matrices (the statistics and one factor per group).
    pub fn bytes(&self) -> usize {
        let m = self.m();
        8 * m * m * (1 + self.params.groups().len()) + 40 * self.xy.len()
    }

    /// Add (`sign = 1`) or subtract (`sign = −1`) one frame's contribution to the statistics.
    /// Adding also records the frame; subtracting leaves the bookkeeping to the caller.
    fn add_stats(&mut self, id: usize, f: FrameRef<'_>, phi_t: &[f64], sign: f64) {
        let (m, l) = (self.m(), f.xy.len());
        let pt = MatRef::from_column_major_slice(phi_t, m, l);
        matmul(
            MatMut::from_column_major_slice_mut(&mut self.gram, m, m),
            Accum::Add,
            pt,
            pt.transpose(),
            sign,
            Par::Seq,
        );
        self.add_vectors(phi_t, f, sign);
        if sign > 0.0 {
            self.record(id, f);
        }
    }

    fn record(&mut self, id: usize, f: FrameRef<'_>) {
        self.frames.push(id);
        self.sizes.push(f.xy.len());
        self.xy.extend_from_slice(f.xy);
        self.v.extend_from_slice(f.v);
    }

    /// The vector and scalar statistics of one frame, given its `Φᵀ` (M x l).
    fn add_vectors(&mut self, phi_t: &[f64], f: FrameRef<'_>, sign: f64) {
        let m = self.m();
        for (j, col) in phi_t.chunks(m).enumerate() {
            for (d, vd) in f.v[j].iter().enumerate() {
                self.v_sum[d] += sign * vd;
                self.v_sq[d] += sign * vd * vd;
                for (t, c) in self.phi_v[d * m..(d + 1) * m].iter_mut().zip(col) {
                    *t += sign * vd * c;
                }
            }
            for (t, c) in self.phi_sum.iter_mut().zip(col) {
                *t += sign * c;
            }
        }
    }

    /// `b_d = Φᵀ (v_d − μ_d)`.
    fn b(&self, d: usize) -> Vec<f64> {
        let m = self.m();
        let mu = self.params.mean[d];
        self.phi_v[d * m..(d + 1) * m]
            .iter()
            .zip(&self.phi_sum)
            .map(|(a, s)| a - mu * s)
            .collect()
    }

    /// `Σ (v_d − μ_d)²`.
    fn yy(&self, d: usize) -> f64 {
        let mu = self.params.mean[d];
        let n = self.xy.len() as f64;
        self.v_sq[d] - 2.0 * mu * self.v_sum[d] + n * mu * mu
    }

    /// `D = σ √s` for a group's signal variance.
    fn d(&self, signal_var: f64) -> Vec<f64> {
        let s = signal_var.sqrt();
        self.sqrt_s.iter().map(|x| s * x).collect()
    }

    /// `z = R⁻¹ D b` for every output of group `g`.
    fn whiten(&self, g: &Group) -> Vec<f64> {
        let m = self.m();
        let d = self.d(g.signal_var);
        let mut z = Vec::with_capacity(m * g.outs.len());
        for &o in g.outs {
            z.extend(self.b(o).iter().zip(&d).map(|(b, d)| b * d));
        }
        solve_lower_triangular_in_place(
            g.r(m),
            MatMut::from_column_major_slice_mut(&mut z, m, g.outs.len()),
            Par::Seq,
        );
        z
    }

    fn refactor(&mut self) -> Result<()> {
        self.refactor_reusing(&[])
    }

    /// [`Self::refactor`], keeping each group of `reuse` whose output group and variances are
    /// unchanged (the caller guarantees the same statistics, length scales and mean).
    fn refactor_reusing(&mut self, reuse: &[Group]) -> Result<()> {
        let m = self.m();
        self.weights = OnceLock::new();
        self.groups.clear();
        for outs in self.params.groups() {
            let (s2, noise) = self.params.group_vars(outs);
            if let Some(g) = reuse
                .iter()
                .find(|g| g.outs == *outs && g.signal_var == s2 && g.noise_var == noise)
            {
                self.groups.push(g.clone());
                continue;
            }
            let d = self.d(s2);
            let chol = Chol::factor(m, "reduced-rank", Par::Seq, || {
                let mut b = vec![0.0; m * m];
                for j in 0..m {
                    for i in 0..m {
                        b[j * m + i] = d[i] * self.gram[j * m + i] * d[j];
                    }
                    b[j * m + j] += noise;
                }
                b
            })?;
            let mut g = Group {
                outs,
                signal_var: s2,
                noise_var: noise,
                chol: chol.l,
                z: Vec::new(),
            };
            g.z = self.whiten(&g);
            self.groups.push(g);
        }
        Ok(())
    }

    /// `log p(D_k)` under the reduced-rank GP.
    pub fn log_marginal(&self) -> f64 {
        let (m, n) = (self.m(), self.xy.len());
        let mut total = -(n as f64) * LN_2PI;
        for g in &self.groups {
            let s2n = g.noise_var;
            let k = g.outs.len() as f64;
            let zz: f64 = g.z.iter().map(|x| x * x).sum();
            let yy: f64 = g.outs.iter().map(|&d| self.yy(d)).sum();
            let log_det = (n as f64 - m as f64) * s2n.ln() + g.log_det(m);
            total -= 0.5 * (yy - zz) / s2n + 0.5 * k * log_det;
        }
        total
    }

    /// `D Φᵀ` for a group's signal variance (M x n, column-major like `phi_t`).
    fn scaled_features(&self, signal_var: f64, phi_t: &[f64]) -> Vec<f64> {
        let d = self.d(signal_var);
        phi_t
            .chunks(self.m())
            .flat_map(|col| col.iter().zip(&d).map(|(p, d)| p * d))
            .collect()
    }

    /// `U = R⁻¹ D Φᵀ` for the points (M x n) of one group.
    fn whitened_features(&self, g: &Group, phi_t: &[f64], n: usize) -> Vec<f64> {
        let m = self.m();
        let mut u = self.scaled_features(g.signal_var, phi_t);
        solve_lower_triangular_in_place(
            g.r(m),
            MatMut::from_column_major_slice_mut(&mut u, m, n),
            Par::Seq,
        );
        u
    }

    /// `(UᵀU, r)` for one frame's block `u` (M x l) in a group: `r_d = v_d − μ_d − Uᵀ z_d`.
    fn frame_terms(&self, g: &Group, u: MatRef<'_, f64>, f: &FrameRef<'_>) -> (Vec<f64>, Vec<f64>) {
        let (m, l) = (self.m(), f.xy.len());
        let mut utu = vec![0.0; l * l];
        matmul(
            MatMut::from_column_major_slice_mut(&mut utu, l, l),
            Accum::Replace,
            u.transpose(),
            u,
            1.0,
            Par::Seq,
        );
        let k = g.outs.len();
        let mut r = crate::gp::centered(f.v, g.outs, self.params.mean);
        matmul(
            MatMut::from_column_major_slice_mut(&mut r, l, k),
            Accum::Add,
            u.transpose(),
            MatRef::from_column_major_slice(&g.z, m, k),
            -1.0,
            Par::Seq,
        );
        (utu, r)
    }

    /// `log p(V_f | D_k)` for each frame: `N(r ; 0, σ_n² (I + UᵀU))`, one triangular solve for
    /// all the frames.
    pub fn score(&self, frames: &[FrameRef<'_>]) -> Result<Vec<f64>> {
        let m = self.m();
        let pts: Vec<Point> = frames.iter().flat_map(|f| f.xy.iter().copied()).collect();
        let phi_t = self.basis.features(&pts);
        let mut out: Vec<f64> = frames
            .iter()
            .map(|f| -(f.xy.len() as f64) * LN_2PI)
            .collect();
        for g in &self.groups {
            let s2n = g.noise_var;
            let u = self.whitened_features(g, &phi_t, pts.len());
            let ur = MatRef::from_column_major_slice(&u, m, pts.len());
            let mut col = 0;
            for (f, o) in frames.iter().zip(out.iter_mut()) {
                let l = f.xy.len();
                let (mut s, r) = self.frame_terms(g, ur.subcols(col, l), f);
                col += l;
                for x in s.iter_mut() {
                    *x *= s2n;
                }
                for i in 0..l {
                    s[i * l + i] += s2n;
                }
                let (log_det, quad) = small::gaussian_terms(s, l, r)?;
                *o -= 0.5 * quad + 0.5 * g.outs.len() as f64 * log_det;
            }
        }
        Ok(out)
    }

    /// `log p(V_f | D_k \ f)` for a member frame without touching the factor. For the linear
    /// model the leave-one-block-out residual is `(I − H_ff)⁻¹ r` with the hat block
    /// `H_ff = UᵀU` and `r` the in-sample residual, and its covariance `σ_n² (I − H_ff)⁻¹`:
    /// the density is `N(r ; 0, σ_n² C⁻¹)` in `r`-space with `C = I − UᵀU`, i.e.
    /// `−½ rᵀC⁻¹r / σ_n² − ½ (l log σ_n² − log|C|) − (l/2) log 2π` per output.
    pub fn loo_score(&self, id: usize) -> Result<Option<f64>> {
        let Some(pos) = self.frames.iter().position(|&f| f == id) else {
            return Ok(None);
        };
        if self.frames.len() == 1 {
            return Ok(None);
        }
        let start: usize = self.sizes[..pos].iter().sum();
        let l = self.sizes[pos];
        let f = FrameRef {
            xy: &self.xy[start..start + l],
            v: &self.v[start..start + l],
        };
        let m = self.m();
        let phi_t = self.basis.features(f.xy);
        let mut total = -(l as f64) * LN_2PI;
        for g in &self.groups {
            let s2n = g.noise_var;
            let u = self.whitened_features(g, &phi_t, l);
            let (utu, r) = self.frame_terms(g, MatRef::from_column_major_slice(&u, m, l), &f);
            let mut c: Vec<f64> = utu.iter().map(|x| -x).collect();
            for i in 0..l {
                c[i * l + i] += 1.0;
            }
            let k = g.outs.len() as f64;
            match small::gaussian_terms(c, l, r) {
                Ok((log_det_c, quad)) => {
                    total -= 0.5 * quad / s2n + 0.5 * k * (l as f64 * s2n.ln() - log_det_c);
                }
                Err(_) => {
                    // Cancellation made I − H_ff indefinite: take the frame out of a copy.
                    let mut rest = self.clone();
                    rest.remove(id)?;
                    return Ok(Some(rest.score(&[f])?[0]));
                }
            }
        }
        Ok(Some(total))
    }

    /// Rank-l update (`sign = 1`) or downdate (`sign = −1`) of every group's factor by the
    /// frame's `D Φᵀ`; false if a downdate lost positive definiteness.
    fn update_factors(&mut self, phi_t: &[f64], l: usize, sign: f64) -> bool {
        let m = self.m();
        let mut ok = true;
        for gi in 0..self.groups.len() {
            let mut w = self.scaled_features(self.groups[gi].signal_var, phi_t);
            let mut alpha = Diag::<f64>::full(l, sign);
            let g = &mut self.groups[gi];
            ok &= rank_r_update_clobber(
                MatMut::from_column_major_slice_mut(&mut g.chol, m, m),
                MatMut::from_column_major_slice_mut(&mut w, m, l),
                alpha.as_mut(),
            )
            .is_ok();
        }
        ok
    }

    fn rewhiten(&mut self) {
        self.weights = OnceLock::new();
        let zs: Vec<Vec<f64>> = self.groups.iter().map(|g| self.whiten(g)).collect();
        for (g, z) in self.groups.iter_mut().zip(zs) {
            g.z = z;
        }
    }

    /// Add frame `id` (not already here): `O(l M²)`.
    pub fn insert(&mut self, id: usize, f: FrameRef<'_>) -> Result<()> {
        let phi_t = self.basis.features(f.xy);
        self.add_stats(id, f, &phi_t, 1.0);
        if self.update_factors(&phi_t, f.xy.len(), 1.0) {
            self.rewhiten();
            Ok(())
        } else {
            self.refactor()
        }
    }

    /// Remove frame `id`; false if it is not here. A downdate that loses positive definiteness
    /// (round-off only) falls back to refactoring from the statistics.
    pub fn remove(&mut self, id: usize) -> Result<bool> {
        let Some(pos) = self.frames.iter().position(|&f| f == id) else {
            return Ok(false);
        };
        let start: usize = self.sizes[..pos].iter().sum();
        let l = self.sizes[pos];
        let xy: Vec<Point> = self.xy.drain(start..start + l).collect();
        let v: Vec<[f64; 2]> = self.v.drain(start..start + l).collect();
        let phi_t = self.basis.features(&xy);
        self.add_stats(id, FrameRef { xy: &xy, v: &v }, &phi_t, -1.0);
        self.frames.remove(pos);
        self.sizes.remove(pos);
        if self.update_factors(&phi_t, l, -1.0) {
            self.rewhiten();
            Ok(true)
        } else {
            self.refactor()?;
            Ok(true)
        }
    }

    /// The same frames under other hyperparameters (one M x M factorisation per group whose
    /// variances changed: the noise step changes one output's noise at a time, and the other
    /// group keeps its factor, the same numbers a refactor would give).
    pub fn with_params(&self, params: GpParams) -> Result<Self> {
        let mut p = Self {
            sqrt_s: self.basis.sqrt_spectral(params.length_scales),
            params,
            groups: Vec::new(),
            weights: OnceLock::new(),
            ..self.clone_data()
        };
        let same =
            params.length_scales == self.params.length_scales && params.mean == self.params.mean;
        p.refactor_reusing(if same { &self.groups } else { &[] })?;
        Ok(p)
    }

    fn clone_data(&self) -> Self {
        Self {
            basis: Arc::clone(&self.basis),
            params: self.params,
            frames: self.frames.clone(),
            sizes: self.sizes.clone(),
            xy: self.xy.clone(),
            v: self.v.clone(),
            gram: self.gram.clone(),
            phi_sum: self.phi_sum.clone(),
            phi_v: self.phi_v.clone(),
            v_sum: self.v_sum,
            v_sq: self.v_sq,
            sqrt_s: self.sqrt_s.clone(),
            groups: Vec::new(),
            weights: OnceLock::new(),
        }
    }

    /// Per group, the posterior mean weights `a = D R⁻ᵀ z` (field mean `μ + Φ a`).
    fn weights(&self) -> &Vec<Vec<f64>> {
        let m = self.m();
        self.weights.get_or_init(|| {
            self.groups
                .iter()
                .map(|g| {
                    let mut a = g.z.clone();
                    solve_upper_triangular_in_place(
                        g.r(m).transpose(),
                        MatMut::from_column_major_slice_mut(&mut a, m, g.outs.len()),
                        Par::Seq,
                    );
                    let d = self.d(g.signal_var);
                    for col in a.chunks_mut(m) {
                        for (x, d) in col.iter_mut().zip(&d) {
                            *x *= d;
                        }
                    }
                    a
                })
                .collect()
        })
    }

    /// Posterior mean velocity at `q`.
    pub fn predict_mean(&self, q: &[Point]) -> Vec<[f64; 2]> {
        let m = self.m();
        let mut out = vec![self.params.mean; q.len()];
        for (block, out) in q.chunks(1024).zip(out.chunks_mut(1024)) {
            let phi_t = self.basis.features(block);
            for (g, a) in self.groups.iter().zip(self.weights()) {
                for (c, &d) in g.outs.iter().enumerate() {
                    let ad = &a[c * m..(c + 1) * m];
                    for (o, col) in out.iter_mut().zip(phi_t.chunks(m)) {
                        o[d] += col.iter().zip(ad).map(|(x, y)| x * y).sum::<f64>();
                    }
                }
            }
        }
        out
    }

    /// Posterior mean and latent variance at `q`; outside the box the variance is the prior's
    /// `σ²` (the basis has no support there, so the model knows nothing).
    pub fn posterior(&self, q: &[Point]) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
        let m = self.m();
        let mut var = Vec::with_capacity(q.len());
        for block in q.chunks(1024) {
            let phi_t = self.basis.features(block);
            let mut out = vec![[0.0; 2]; block.len()];
            for g in &self.groups {
                let s2n = g.noise_var;
                let u = self.whitened_features(g, &phi_t, block.len());
                for (j, o) in out.iter_mut().enumerate() {
                    let explained: f64 = u[j * m..(j + 1) * m].iter().map(|x| x * x).sum();
                    for &d in g.outs {
                        o[d] = if self.basis.contains(block[j]) {
                            s2n * explained
                        } else {
                            g.signal_var
                        };
                    }
                }
            }
            var.extend(out);
        }
        (self.predict_mean(q), var)
    }

    /// Joint posterior of the latent field at `q`: the mean per point and, per output, the
    /// `n x n` covariance `σ_n² UᵀU` (plus the prior `σ²` on the diagonal outside the box).
    pub fn predict_joint(&self, q: &[Point]) -> (Vec<[f64; 2]>, [Vec<f64>; 2]) {
        let (m, n) = (self.m(), q.len());
        let phi_t = self.basis.features(q);
        let mut cov = [Vec::new(), Vec::new()];
        for g in &self.groups {
            let s2n = g.noise_var;
            let u = self.whitened_features(g, &phi_t, n);
            let ur = MatRef::from_column_major_slice(&u, m, n);
            let mut c = vec![0.0; n * n];
            matmul(
                MatMut::from_column_major_slice_mut(&mut c, n, n),
                Accum::Replace,
                ur.transpose(),
                ur,
                s2n,
                Par::Seq,
            );
            for (i, p) in q.iter().enumerate() {
                if !self.basis.contains(*p) {
                    c[i * n + i] += g.signal_var;
                }
            }
            for &d in g.outs {
                cov[d] = c.clone();
            }
        }
        (self.predict_mean(q), cov)
    }
}

#[cfg(test)]
#[path = "tests/hsgp.rs"]
mod tests;
