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

use std::sync::{Arc, OnceLock};

use faer::diag::Diag;
use faer::linalg::cholesky::llt::update::rank_r_update_clobber;
use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve::solve_lower_triangular_in_place;
use faer::{Accum, MatMut, MatRef, Par};

pub use crate::basis::{AxisFeatures, Basis, MAX_BASIS};
use crate::correlation::Correlation;
use crate::error::Result;
use crate::frame::{FrameRef, Inputs, Point, concat_headings, extend_headings};
use crate::gp::{GpParams, LN_2PI};
use crate::hsgp_sums::{Group, Sums, VecSums, log_marginal, scaled_sqrt_spectrum};
use crate::low_data::{self, PointGrid};
use crate::small;

/// Points whose features [`HsgpPattern::score`] holds at once (M doubles each).
const SCORE_POINTS: usize = 4096;

/// A motion pattern under the reduced-rank GP: its frames, the additive statistics and the
/// factors of each output group.
#[derive(Clone, Debug)]
pub struct HsgpPattern {
    basis: Arc<Basis>,
    pub params: GpParams,
    frames: Vec<usize>,
    sizes: Vec<usize>,
    xy: Vec<Point>,
    /// Each point's previous heading (`NaN`: unknown), or empty when no frame has headings.
    h: Vec<f64>,
    v: Vec<[f64; 2]>,
    /// `G = Σ ΦᵀΦ`, M x M (both triangles).
    gram: Vec<f64>,
    /// `Φᵀ1`, `Φᵀ v_d` and the scalar sums.
    vecs: VecSums,
    /// `√s` at the current length scales.
    sqrt_s: Vec<f64>,
    groups: Vec<Group>,
    /// Per group, the posterior mean weights `D R⁻ᵀ z` (M x outputs), on first use.
    weights: OnceLock<Vec<Vec<f64>>>,
    /// The points by grid cell, for the low-data flags' bound; on first use after the points
    /// change.
    grid: OnceLock<PointGrid>,
}

impl HsgpPattern {
    pub fn new(
        basis: Arc<Basis>,
        params: GpParams,
        members: &[(usize, FrameRef<'_>)],
    ) -> Result<Self> {
        let mut p = Self {
            sqrt_s: basis.sqrt_spectral(params.length_scales),
            basis,
            params,
            frames: Vec::new(),
            sizes: Vec::new(),
            xy: Vec::new(),
            h: Vec::new(),
            v: Vec::new(),
            gram: Vec::new(),
            vecs: VecSums::zeros(0),
            groups: Vec::new(),
            weights: OnceLock::new(),
            grid: OnceLock::new(),
        };
        if p.basis.harmonics() == 0 {
            for &(id, f) in members {
                p.record(id, f);
            }
            // The sums in O(M) per point (hsgp_sums: the Gram matrix from its moments).
            let sums = Sums::of_points(&p.basis, &p.xy, &p.v, members.len());
            p.gram = sums.gram(&p.basis);
            p.vecs = sums.vecs;
        } else {
            // Heading functions are not separable into per-axis moments: sum the features.
            let m = p.m();
            p.gram = vec![0.0; m * m];
            p.vecs = VecSums::zeros(m);
            for &(id, f) in members {
                let phi_t = p.basis.features_of(f.inputs());
                p.add_stats(id, f, &phi_t, 1.0);
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

    /// The training inputs: positions and headings.
    pub fn inputs(&self) -> Inputs<'_> {
        Inputs {
            xy: &self.xy,
            h: &self.h,
        }
    }

    /// Bytes held by the M x M matrices (the statistics and one factor per group).
    pub fn bytes(&self) -> usize {
        let m = self.m();
        8 * m * m * (1 + self.params.groups().len())
            + 40 * self.xy.len()
            + self.grid.get().map_or(0, PointGrid::bytes)
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
        extend_headings(&mut self.h, self.xy.len(), f.h, f.xy.len());
        self.xy.extend_from_slice(f.xy);
        self.v.extend_from_slice(f.v);
    }

    /// The vector and scalar statistics of one frame, given its `Φᵀ` (M x l).
    fn add_vectors(&mut self, phi_t: &[f64], f: FrameRef<'_>, sign: f64) {
        let m = self.m();
        let vs = &mut self.vecs;
        for (j, col) in phi_t.chunks(m).enumerate() {
            for (d, vd) in f.v[j].iter().enumerate() {
                vs.v_sum[d] += sign * vd;
                vs.v_sq[d] += sign * vd * vd;
                for (t, c) in vs.phi_v[d * m..(d + 1) * m].iter_mut().zip(col) {
                    *t += sign * vd * c;
                }
            }
            for (t, c) in vs.phi_sum.iter_mut().zip(col) {
                *t += sign * c;
            }
        }
        if sign > 0.0 {
            vs.n_points += f.xy.len();
        } else {
            vs.n_points -= f.xy.len();
        }
    }

    /// `D = σ √s` for a group's signal variance.
    fn d(&self, signal_var: f64) -> Vec<f64> {
        scaled_sqrt_spectrum(&self.sqrt_s, signal_var)
    }

    /// `z = R⁻¹ D b` for every output of group `g`.
    fn whiten(&self, g: &Group) -> Vec<f64> {
        g.whiten(&self.d(g.signal_var), &self.vecs, self.params.mean)
    }

    fn refactor(&mut self) -> Result<()> {
        self.refactor_reusing(&[])
    }

    /// [`Self::refactor`], keeping each group of `reuse` whose output group and variances are
    /// unchanged (the caller guarantees the same statistics, length scales and mean).
    fn refactor_reusing(&mut self, reuse: &[Group]) -> Result<()> {
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
            let g = Group::new(
                outs,
                (s2, noise),
                &self.gram,
                &d,
                &self.vecs,
                self.params.mean,
            )?;
            self.groups.push(g);
        }
        Ok(())
    }

    /// `log p(D_k)` under the reduced-rank GP.
    pub fn log_marginal(&self) -> f64 {
        log_marginal(&self.groups, &self.vecs, self.params.mean, self.m())
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
        // In blocks of frames of about SCORE_POINTS points: the features of every point at once
        // would be 8 M bytes a point (27 GB for a million frames of a dozen vehicles).
        let mut out = Vec::with_capacity(frames.len());
        let mut start = 0;
        while start < frames.len() {
            let mut end = start + 1;
            let mut points = frames[start].xy.len();
            while end < frames.len() && points + frames[end].xy.len() <= SCORE_POINTS {
                points += frames[end].xy.len();
                end += 1;
            }
            out.extend(self.score_block(&frames[start..end])?);
            start = end;
        }
        Ok(out)
    }

    fn score_block(&self, frames: &[FrameRef<'_>]) -> Result<Vec<f64>> {
        let m = self.m();
        let pts: Vec<Point> = frames.iter().flat_map(|f| f.xy.iter().copied()).collect();
        let pts_h = concat_headings(frames.iter().copied());
        let phi_t = self.basis.features_of(Inputs {
            xy: &pts,
            h: &pts_h,
        });
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
            h: if self.h.is_empty() {
                &[]
            } else {
                &self.h[start..start + l]
            },
        };
        let m = self.m();
        let phi_t = self.basis.features_of(f.inputs());
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
        self.grid = OnceLock::new();
        let phi_t = self.basis.features_of(f.inputs());
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
        self.grid = OnceLock::new();
        let xy: Vec<Point> = self.xy.drain(start..start + l).collect();
        let v: Vec<[f64; 2]> = self.v.drain(start..start + l).collect();
        let h: Vec<f64> = if self.h.is_empty() {
            Vec::new()
        } else {
            self.h.drain(start..start + l).collect()
        };
        let f = FrameRef {
            xy: &xy,
            v: &v,
            h: &h,
        };
        let phi_t = self.basis.features_of(f.inputs());
        self.add_stats(id, f, &phi_t, -1.0);
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
            grid: OnceLock::new(),
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
            h: self.h.clone(),
            v: self.v.clone(),
            gram: self.gram.clone(),
            vecs: self.vecs.clone(),
            sqrt_s: self.sqrt_s.clone(),
            groups: Vec::new(),
            weights: OnceLock::new(),
            grid: OnceLock::new(),
        }
    }

    /// Per group, the posterior mean weights `a = D R⁻ᵀ z` (field mean `μ + Φ a`).
    fn weights(&self) -> &Vec<Vec<f64>> {
        self.weights.get_or_init(|| {
            self.groups
                .iter()
                .map(|g| g.weights(&self.d(g.signal_var), None))
                .collect()
        })
    }

    /// Posterior mean velocity at `q`.
    pub fn predict_mean(&self, q: &[Point]) -> Vec<[f64; 2]> {
        self.predict_mean_at(Inputs::positions(q))
    }

    /// [`HsgpPattern::predict_mean`] at positions and previous headings.
    pub fn predict_mean_at(&self, q: Inputs<'_>) -> Vec<[f64; 2]> {
        let m = self.m();
        let mut out = vec![self.params.mean; q.len()];
        for (block, out) in q.chunks(1024).zip(out.chunks_mut(1024)) {
            let phi_t = self.basis.features_of(block);
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
        self.posterior_at(Inputs::positions(q))
    }

    /// [`HsgpPattern::posterior`] at positions and previous headings.
    pub fn posterior_at(&self, q: Inputs<'_>) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
        let m = self.m();
        let mut var = Vec::with_capacity(q.len());
        for block in q.chunks(1024) {
            let phi_t = self.basis.features_of(block);
            let mut out = vec![[0.0; 2]; block.len()];
            for g in &self.groups {
                let s2n = g.noise_var;
                let u = self.whitened_features(g, &phi_t, block.len());
                for (j, o) in out.iter_mut().enumerate() {
                    let explained: f64 = u[j * m..(j + 1) * m].iter().map(|x| x * x).sum();
                    for &d in g.outs {
                        o[d] = if self.basis.contains(block.xy[j]) {
                            s2n * explained
                        } else {
                            g.signal_var
                        };
                    }
                }
            }
            var.extend(out);
        }
        (self.predict_mean_at(q), var)
    }

    /// The low-data flags at `q`, threshold `f` of the prior variance ([`crate::low_data`]): the
    /// nearest training points' bound, the full solve where it cannot decide.
    pub fn low_data_at(&self, q: Inputs<'_>, f: f64) -> Vec<bool> {
        let grid = self.grid.get_or_init(|| PointGrid::new(&self.xy));
        let corr = Correlation::Reduced(Arc::clone(&self.basis));
        let model = low_data::Model {
            train: self.inputs(),
            params: &self.params,
            corr: &corr,
            groups: (self.groups.iter())
                .map(|g| (g.outs, g.signal_var, g.noise_var))
                .collect(),
        };
        low_data::flags(&model, grid, q, f, |r| self.posterior_at(r).1)
    }

    /// Joint posterior of the latent field at `q`: the mean per point and, per output, the
    /// `n x n` covariance `σ_n² UᵀU` (plus the prior `σ²` on the diagonal outside the box).
    pub fn predict_joint(&self, q: &[Point]) -> (Vec<[f64; 2]>, [Vec<f64>; 2]) {
        self.predict_joint_at(Inputs::positions(q))
    }

    /// [`HsgpPattern::predict_joint`] at positions and previous headings.
    pub fn predict_joint_at(&self, q: Inputs<'_>) -> (Vec<[f64; 2]>, [Vec<f64>; 2]) {
        let (m, n) = (self.m(), q.len());
        let phi_t = self.basis.features_of(q);
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
            for (i, p) in q.xy.iter().enumerate() {
                if !self.basis.contains(*p) {
                    c[i * n + i] += g.signal_var;
                }
            }
            for &d in g.outs {
                cov[d] = c.clone();
            }
        }
        (self.predict_mean_at(q), cov)
    }
}

#[cfg(test)]
#[path = "tests/hsgp.rs"]
mod tests;
