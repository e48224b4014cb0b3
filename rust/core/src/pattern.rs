//! One motion pattern: its frames' points in factor order, its length scales, and per output
//! group a growable Cholesky factor of `σ² R + σ_n² I` with the whitened residuals `z = L⁻¹(v − μ)`.
//!
//! Scoring a frame against a pattern is the append trial (docs/engine.md): with
//! `V = L⁻¹ K(X_k, X_i)` and `S = K_ii + σ_n² I − VᵀV`, the GP predictive density of the frame is
//! `N(r ; 0, S)` with `r = v_i − μ − Vᵀ z`. The same `V` and `chol S` are the new factor rows.
//!
//! This is the one implementation of the exact GP: the sampler's patterns, and a standalone GP
//! over given points ([`Pattern::single`], what `dpgp.gp` and the single-GP baseline call).

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use std::sync::OnceLock;

use crate::basis::{AxisFeatures, Basis};
use crate::correlation::Correlation;
use crate::error::{Error, Result, check_finite};
use crate::factor::{GrowFactor, capacity};
pub use crate::frame::FrameRef;
use crate::frame::{Inputs, LengthScales, Point, concat_headings, extend_headings};
use crate::gp::{GpParams, LN_2PI, centered};
use crate::linalg::Chol;
use crate::low_data::{self, PointGrid};
use crate::small;

#[derive(Clone, Debug)]
struct Group {
    outs: &'static [usize],
    signal_var: f64,
    noise_var: f64,
    factor: GrowFactor,
    /// `L⁻¹ (v_d − μ_d)` for each output `d` of the group, column-major `n x outs.len()`.
    z: Vec<f64>,
}

/// A motion pattern and its cached factorisation.
#[derive(Clone, Debug)]
pub struct Pattern {
    pub params: GpParams,
    /// The kernel's correlation: the squared exponential, or the reduced-rank one for small
    /// patterns of a reduced-rank fit.
    corr: Correlation,
    /// Training frames in factor order, with the row where each starts.
    pub frames: Vec<usize>,
    sizes: Vec<usize>,
    xy: Vec<Point>,
    /// Each point's previous heading (`NaN`: unknown), or empty when no frame has headings.
    h: Vec<f64>,
    v: Vec<[f64; 2]>,
    groups: Vec<Group>,
    /// Per group, `K⁻¹ (v − μ)` (n x outputs), computed on first use after each change.
    weights: OnceLock<Vec<Vec<f64>>>,
    /// With a reduced-rank correlation, the points' per-axis basis values (they do not depend
    /// on the hyperparameters), computed on first use after each change of the points: a cross
    /// correlation with new points then evaluates no basis functions at the pattern's own.
    axis: OnceLock<AxisFeatures>,
    /// With a reduced-rank correlation, per group the posterior mean's weights on the basis
    /// functions ([`Pattern::basis_weights`]), computed on first use after each change.
    basis_weights: OnceLock<Vec<Vec<f64>>>,
    /// The points by grid cell, for the low-data flags' bound; on first use after the points
    /// change.
    grid: OnceLock<PointGrid>,
    /// `Some(par)` for a standalone GP ([`Pattern::single`]): factored without spare room and
    /// solved with `par`. `None` for the sampler's patterns, which run inside parallel loops.
    solo: Option<Par>,
}

/// Frames larger than this are factored by faer rather than the frame-sized kernels (only in
/// a standalone GP, so the sampler's arithmetic is unchanged).
const SMALL_MAX: usize = 64;

impl Pattern {
    /// Build and factor a pattern from scratch.
    pub fn new(params: GpParams, members: &[(usize, FrameRef<'_>)]) -> Result<Self> {
        Self::with_correlation(Correlation::SquaredExp, params, members)
    }

    /// Build and factor a pattern whose GP uses the correlation `corr`.
    pub fn with_correlation(
        corr: Correlation,
        params: GpParams,
        members: &[(usize, FrameRef<'_>)],
    ) -> Result<Self> {
        let h = concat_headings(members.iter().map(|m| m.1));
        let mut p = Self {
            params,
            corr,
            frames: members.iter().map(|m| m.0).collect(),
            sizes: members.iter().map(|m| m.1.xy.len()).collect(),
            xy: members
                .iter()
                .flat_map(|m| m.1.xy.iter().copied())
                .collect(),
            h,
            v: members.iter().flat_map(|m| m.1.v.iter().copied()).collect(),
            groups: Vec::new(),
            weights: Default::default(),
            axis: Default::default(),
            basis_weights: Default::default(),
            grid: Default::default(),
            solo: None,
        };
        p.refactor()?;
        Ok(p)
    }

    /// One GP over the points `xy` with velocities `v` (a pattern of one frame, id 0), factored
    /// and solved with the parallelism `par`. Inputs are checked: non-empty, finite, row for row.
    pub fn single(params: GpParams, xy: &[Point], v: &[[f64; 2]], par: Par) -> Result<Self> {
        Self::single_at(params, FrameRef::new(xy, v), par)
    }

    /// [`Pattern::single`] over positions and previous headings (`f.h`: `NaN` where unknown).
    pub fn single_at(params: GpParams, f: FrameRef<'_>, par: Par) -> Result<Self> {
        let (xy, v) = (f.xy, f.v);
        check_pair("train_xy", xy, "train_v", v)?;
        check_headings("train_h", f.h, xy.len())?;
        let mut p = Self {
            params,
            corr: Correlation::SquaredExp,
            frames: vec![0],
            sizes: vec![xy.len()],
            xy: xy.to_vec(),
            h: f.h.to_vec(),
            v: v.to_vec(),
            groups: Vec::new(),
            weights: Default::default(),
            axis: Default::default(),
            basis_weights: Default::default(),
            grid: Default::default(),
            solo: Some(par),
        };
        p.refactor()?;
        Ok(p)
    }

    fn par(&self) -> Par {
        self.solo.unwrap_or(Par::Seq)
    }

    fn parallel(&self) -> bool {
        !matches!(self.par(), Par::Seq)
    }

    /// The same frames under other hyperparameters (a fresh factorisation).
    pub fn with_params(&self, params: GpParams) -> Result<Self> {
        let mut p = Self {
            params,
            groups: Vec::new(),
            ..self.clone_data()
        };
        // A group whose kernel and mean are unchanged keeps its factor (the noise step changes
        // one output's noise at a time): the same numbers a refactor would give, for a copy.
        let same =
            params.length_scales == self.params.length_scales && params.mean == self.params.mean;
        p.refactor_reusing(if same { &self.groups } else { &[] })?;
        Ok(p)
    }

    /// The correlation this pattern's GP uses.
    pub fn correlation(&self) -> &Correlation {
        &self.corr
    }

    /// Bytes held by the factors and the data (with a reduced-rank correlation, and the
    /// points' basis values it caches).
    pub fn bytes(&self) -> usize {
        let cap: usize = self.groups.iter().map(|g| g.factor.cap().pow(2)).sum();
        8 * cap + self.point_bytes() * self.xy.len()
    }

    fn point_bytes(&self) -> usize {
        match &self.corr {
            Correlation::SquaredExp => 56,
            Correlation::Reduced(basis) => 56 + 8 * basis.counts().iter().sum::<usize>(),
        }
    }

    /// Bytes after appending a frame of `l` points (the factors grow by [`capacity`]).
    pub fn bytes_after_insert(&self, l: usize) -> usize {
        let n = self.xy.len() + l;
        let cap: usize = self
            .groups
            .iter()
            .map(|g| {
                let cap = g.factor.cap();
                if n > cap { capacity(n) } else { cap }.pow(2)
            })
            .sum::<usize>()
            .max(self.params.groups().len() * capacity(n).pow(2));
        8 * cap + self.point_bytes() * n
    }

    fn clone_data(&self) -> Self {
        Self {
            params: self.params,
            corr: self.corr.clone(),
            frames: self.frames.clone(),
            sizes: self.sizes.clone(),
            xy: self.xy.clone(),
            h: self.h.clone(),
            v: self.v.clone(),
            groups: Vec::new(),
            weights: Default::default(),
            axis: self.axis.clone(),
            basis_weights: Default::default(),
            grid: Default::default(),
            solo: self.solo,
        }
    }

    fn refactor(&mut self) -> Result<()> {
        self.refactor_reusing(&[])
    }

    /// [`Pattern::refactor`], copying the groups of `reuse` (same points, length scales and
    /// means) whose outputs and variances are unchanged.
    fn refactor_reusing(&mut self, reuse: &[Group]) -> Result<()> {
        let n = self.xy.len();
        self.changed(false);
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
            let (ls, par, parallel) = (self.params.length_scales, self.par(), self.parallel());
            let chol = Chol::factor(n, "training", par, || match &self.corr {
                Correlation::Reduced(basis) => {
                    let fx = self.axis.get_or_init(|| basis.axis_features(&self.xy));
                    let mut k =
                        basis.headed_correlation(fx, fx, self.inputs(), self.inputs(), ls, s2);
                    for i in 0..n {
                        k[i * n + i] += noise;
                    }
                    k
                }
                Correlation::SquaredExp => {
                    self.corr.gram_par(self.inputs(), ls, s2, noise, parallel)
                }
            })?;
            let mut z = centered(&self.v, outs, self.params.mean);
            chol.solve_lower(&mut z, par);
            let factor = match self.solo {
                Some(_) => GrowFactor::from_owned(chol.l, n),
                None => GrowFactor::from_dense(&chol.l, n),
            };
            self.groups.push(Group {
                outs,
                signal_var: s2,
                noise_var: noise,
                factor,
                z,
            });
        }
        Ok(())
    }

    pub fn n_frames(&self) -> usize {
        self.frames.len()
    }

    /// Points per member frame, in factor order.
    pub fn sizes(&self) -> &[usize] {
        &self.sizes
    }

    /// A pattern with no frames (a placeholder; scoring against it is meaningless).
    pub fn empty() -> Self {
        Self {
            params: GpParams {
                length_scales: LengthScales {
                    wx: 1.0,
                    wy: 1.0,
                    wh: f64::INFINITY,
                },
                signal_var: [1.0; 2],
                noise_var: [1.0; 2],
                mean: [0.0; 2],
            },
            corr: Correlation::SquaredExp,
            frames: Vec::new(),
            sizes: Vec::new(),
            xy: Vec::new(),
            h: Vec::new(),
            v: Vec::new(),
            groups: Vec::new(),
            weights: Default::default(),
            axis: Default::default(),
            basis_weights: Default::default(),
            grid: Default::default(),
            solo: None,
        }
    }

    pub fn n_points(&self) -> usize {
        self.xy.len()
    }

    pub fn length_scales(&self) -> LengthScales {
        self.params.length_scales
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

    /// `log p(D_k)`: the GP marginal likelihood of all the pattern's velocities.
    pub fn log_marginal(&self) -> f64 {
        let n = self.xy.len() as f64;
        let mut total = -n * LN_2PI;
        for g in &self.groups {
            total -= 0.5 * g.z.iter().map(|x| x * x).sum::<f64>()
                + 0.5 * g.outs.len() as f64 * g.factor.log_det();
        }
        total
    }

    /// `log p(V_f | D_k)` for each frame `f`, from one batched triangular solve.
    pub fn score(&self, frames: &[FrameRef<'_>]) -> Result<Vec<f64>> {
        let n = self.xy.len();
        let pts: Vec<Point> = frames.iter().flat_map(|f| f.xy.iter().copied()).collect();
        let pts_h = concat_headings(frames.iter().copied());
        let total_m = pts.len();
        let mut out: Vec<f64> = frames
            .iter()
            .map(|f| -(f.xy.len() as f64) * LN_2PI)
            .collect();
        let (par, parallel) = (self.par(), self.parallel());
        let corr = self.cross_to(
            Inputs {
                xy: &pts,
                h: &pts_h,
            },
            1.0,
            parallel,
        );
        for g in &self.groups {
            let mut vbuf: Vec<f64> = corr.iter().map(|c| c * g.signal_var).collect();
            g.factor.solve_lower(&mut vbuf, par);
            let vall = MatRef::from_column_major_slice(&vbuf, n, total_m);
            let z = MatRef::from_column_major_slice(&g.z, n, g.outs.len());
            let mut col = 0;
            for (f, o) in frames.iter().zip(out.iter_mut()) {
                let m = f.xy.len();
                let v = vall.subcols(col, m);
                col += m;
                let (logdet, quad) = self.schur_terms(f, v, z, g)?;
                *o -= 0.5 * quad + 0.5 * g.outs.len() as f64 * logdet;
            }
        }
        Ok(out)
    }

    /// Per output group, `K⁻¹ (v − μ)` (n x outputs): cached until the pattern changes.
    fn weights(&self) -> &Vec<Vec<f64>> {
        let n = self.xy.len();
        self.weights.get_or_init(|| {
            self.groups
                .iter()
                .map(|g| {
                    let mut a = g.z.clone();
                    faer::linalg::triangular_solve::solve_upper_triangular_in_place(
                        g.factor.mat().transpose(),
                        MatMut::from_column_major_slice_mut(&mut a, n, g.outs.len()),
                        self.par(),
                    );
                    a
                })
                .collect()
        })
    }

    /// Posterior mean velocity at `q`: `μ + σ² R(q, X) K⁻¹ (v − μ)` per output, queries in
    /// blocks of [`QUERY_BLOCK`].
    pub fn predict_mean(&self, q: &[Point]) -> Vec<[f64; 2]> {
        self.predict_mean_at(Inputs::positions(q))
    }

    /// [`Pattern::predict_mean`] at positions and previous headings.
    pub fn predict_mean_at(&self, q: Inputs<'_>) -> Vec<[f64; 2]> {
        let mut out = vec![self.params.mean; q.len()];
        if let Correlation::Reduced(basis) = &self.corr {
            // The same mean in weight space: O(M) a query, against O(n (m_x + m_y)) for the
            // correlations with every point (most of a rollout over heading).
            let m = basis.len();
            let weights = self.basis_weights(basis);
            for (block, ob) in q.chunks(QUERY_BLOCK).zip(out.chunks_mut(QUERY_BLOCK)) {
                let phi_t = basis.features_of(block);
                for (g, w) in self.groups.iter().zip(weights) {
                    for (c, &d) in g.outs.iter().enumerate() {
                        let wc = &w[c * m..(c + 1) * m];
                        for (o, col) in ob.iter_mut().zip(phi_t.chunks(m)) {
                            o[d] += col.iter().zip(wc).map(|(x, y)| x * y).sum::<f64>();
                        }
                    }
                }
            }
            return out;
        }
        for (block, ob) in q.chunks(QUERY_BLOCK).zip(out.chunks_mut(QUERY_BLOCK)) {
            let corr = self.cross_to(block, 1.0, self.parallel());
            self.add_mean(&corr, ob);
        }
        out
    }

    /// Per group, the posterior mean's weights on a reduced-rank correlation's basis functions,
    /// `w = σ² S Φ_Xᵀ K⁻¹ (v − μ)` (outputs x M, `S` the spectral weights): the mean at `q` is
    /// then `μ + φ(q)ᵀ w`, the function-space `μ + σ² R(q, X) K⁻¹ (v − μ)` with
    /// `R(q, X) = φ(q)ᵀ S Φ_X`. Cached until the pattern changes.
    fn basis_weights(&self, basis: &Basis) -> &Vec<Vec<f64>> {
        self.basis_weights.get_or_init(|| {
            let (n, m) = (self.xy.len(), basis.len());
            let s: Vec<f64> = (basis.sqrt_spectral(self.params.length_scales).iter())
                .map(|r| r * r)
                .collect();
            let mut out: Vec<Vec<f64>> = (self.groups.iter())
                .map(|g| vec![0.0; m * g.outs.len()])
                .collect();
            // Φ_Xᵀ a in blocks of points, so the features take M x QUERY_BLOCK at most.
            let mut start = 0;
            for block in self.inputs().chunks(QUERY_BLOCK) {
                let phi_t = basis.features_of(block);
                for ((g, a), w) in self.groups.iter().zip(self.weights()).zip(&mut out) {
                    for c in 0..g.outs.len() {
                        let ac = &a[c * n + start..c * n + start + block.len()];
                        let wc = &mut w[c * m..(c + 1) * m];
                        for (col, &ai) in phi_t.chunks(m).zip(ac) {
                            for (x, &f) in wc.iter_mut().zip(col) {
                                *x += f * ai;
                            }
                        }
                    }
                }
                start += block.len();
            }
            for (g, w) in self.groups.iter().zip(&mut out) {
                for wc in w.chunks_mut(m) {
                    for (x, sj) in wc.iter_mut().zip(&s) {
                        *x *= g.signal_var * sj;
                    }
                }
            }
            out
        })
    }

    /// `scale · R(X, q)` of the pattern's points `X` and `q` (column-major `n x q.len()`); with a
    /// reduced-rank correlation, from the points' cached basis values.
    fn cross_to(&self, q: Inputs<'_>, scale: f64, parallel: bool) -> Vec<f64> {
        let ls = self.params.length_scales;
        match &self.corr {
            Correlation::Reduced(basis) => {
                let fx = self.axis.get_or_init(|| basis.axis_features(&self.xy));
                let fq = basis.axis_features(q.xy);
                basis.headed_correlation(fx, &fq, self.inputs(), q, ls, scale)
            }
            Correlation::SquaredExp => self.corr.cross_par(self.inputs(), q, ls, scale, parallel),
        }
    }

    /// Drop what is cached of the points' solution (and, when the points changed, of the points).
    fn changed(&mut self, points: bool) {
        self.weights = Default::default();
        self.basis_weights = Default::default();
        if points {
            self.axis = Default::default();
            self.grid = Default::default();
        }
    }

    /// `out[j] += σ² R(q_j, X) K⁻¹ (v − μ)` per output, for the correlations `corr = R(X, q)`.
    fn add_mean(&self, corr: &[f64], out: &mut [[f64; 2]]) {
        let n = self.xy.len();
        for (g, a) in self.groups.iter().zip(self.weights()) {
            for (c, &d) in g.outs.iter().enumerate() {
                let ad = &a[c * n..(c + 1) * n];
                for (j, o) in out.iter_mut().enumerate() {
                    let col = &corr[j * n..(j + 1) * n];
                    o[d] += g.signal_var * col.iter().zip(ad).map(|(x, y)| x * y).sum::<f64>();
                }
            }
        }
    }

    /// Posterior mean and variance of the latent field at each of the points `q`, from the cached
    /// factor (queries in blocks, so memory stays `n x QUERY_BLOCK`; each block's correlations
    /// serve both the mean and the variance).
    pub fn posterior(&self, q: &[Point]) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
        self.posterior_at(Inputs::positions(q))
    }

    /// [`Pattern::posterior`] at positions and previous headings.
    pub fn posterior_at(&self, q: Inputs<'_>) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
        let n = self.xy.len();
        let mut mean = vec![self.params.mean; q.len()];
        let mut var = Vec::with_capacity(q.len());
        let ls = self.params.length_scales;
        for (block, mb) in q.chunks(QUERY_BLOCK).zip(mean.chunks_mut(QUERY_BLOCK)) {
            let corr = self.cross_to(block, 1.0, self.parallel());
            self.add_mean(&corr, mb);
            let prior = self.corr.diag(block, ls);
            let mut out = vec![[0.0; 2]; block.len()];
            for g in &self.groups {
                let mut v: Vec<f64> = corr.iter().map(|c| c * g.signal_var).collect();
                g.factor.solve_lower(&mut v, self.par());
                for (j, o) in out.iter_mut().enumerate() {
                    let explained: f64 = v[j * n..(j + 1) * n].iter().map(|x| x * x).sum();
                    for &d in g.outs {
                        o[d] = if self.corr.unsupported(block.xy[j]) {
                            g.signal_var
                        } else {
                            (g.signal_var * prior[j] - explained).max(0.0)
                        };
                    }
                }
            }
            var.extend(out);
        }
        (mean, var)
    }

    /// The low-data flags at `q`, threshold `f` of the prior variance ([`crate::low_data`]): the
    /// nearest training points' bound, the full solve where it cannot decide.
    pub fn low_data_at(&self, q: Inputs<'_>, f: f64) -> Vec<bool> {
        let grid = self.grid.get_or_init(|| PointGrid::new(&self.xy));
        let model = low_data::Model {
            train: self.inputs(),
            params: &self.params,
            corr: &self.corr,
            groups: (self.groups.iter())
                .map(|g| (g.outs, g.signal_var, g.noise_var))
                .collect(),
        };
        low_data::flags(&model, grid, q, f, |r| self.posterior_at(r).1)
    }

    /// Joint posterior of the latent field at `q`: the mean per point and, per output, the
    /// `m x m` covariance `σ² R_qq − Vᵀ V` (column-major), `V = L⁻¹ σ² R(X, q)`.
    pub fn predict_joint(&self, q: &[Point]) -> (Vec<[f64; 2]>, [Vec<f64>; 2]) {
        self.predict_joint_at(Inputs::positions(q))
    }

    /// [`Pattern::predict_joint`] at positions and previous headings.
    pub fn predict_joint_at(&self, q: Inputs<'_>) -> (Vec<[f64; 2]>, [Vec<f64>; 2]) {
        let (n, m) = (self.xy.len(), q.len());
        let corr = self.cross_to(q, 1.0, false);
        let rqq = self.corr.cross(q, q, self.params.length_scales, 1.0);
        let mut cov = [Vec::new(), Vec::new()];
        for g in &self.groups {
            let mut v: Vec<f64> = corr.iter().map(|c| c * g.signal_var).collect();
            g.factor.solve_lower(&mut v, Par::Seq);
            let mut c: Vec<f64> = rqq.iter().map(|x| x * g.signal_var).collect();
            let vr = MatRef::from_column_major_slice(&v, n, m);
            matmul(
                MatMut::from_column_major_slice_mut(&mut c, m, m),
                Accum::Add,
                vr.transpose(),
                vr,
                -1.0,
                Par::Seq,
            );
            // No support outside a reduced-rank basis: report the prior variance there.
            for (i, p) in q.xy.iter().enumerate() {
                if self.corr.unsupported(*p) {
                    c[i * m + i] += g.signal_var;
                }
            }
            for &d in g.outs {
                cov[d] = c.clone();
            }
        }
        (self.predict_mean_at(q), cov)
    }

    /// `log p(V_f | D_k \\ f)` for a member frame, without touching the factor: leave-one-block-out
    /// (R&W §5.4.2 for a block). With `P = K⁻¹`, `a = K⁻¹(v − μ)` and `I` the frame's rows,
    /// the conditional is `N(v_I ; v_I − P_II⁻¹ a_I, P_II⁻¹)`, so its log density is
    /// `−½ a_Iᵀ P_II⁻¹ a_I + ½ log|P_II| − (l/2) log 2π`. `P_II = WᵀW` with `W = L⁻¹ E_I`, which
    /// is zero above row `p`: a forward solve of the trailing block only.
    pub fn loo_score(&self, id: usize) -> Result<Option<f64>> {
        let Some(pos) = self.frames.iter().position(|&f| f == id) else {
            return Ok(None);
        };
        let (p, l, n) = (
            self.sizes[..pos].iter().sum::<usize>(),
            self.sizes[pos],
            self.xy.len(),
        );
        if n == l {
            return Ok(None);
        }
        let weights = self.weights();
        let mut total = -(l as f64) * LN_2PI;
        for (g, a) in self.groups.iter().zip(weights) {
            let m = n - p;
            let mut w = vec![0.0; m * l];
            for c in 0..l {
                w[c * m + c] = 1.0;
            }
            let trailing = g.factor.mat().submatrix(p, p, m, m);
            faer::linalg::triangular_solve::solve_lower_triangular_in_place(
                trailing,
                MatMut::from_column_major_slice_mut(&mut w, m, l),
                Par::Seq,
            );
            let wr = MatRef::from_column_major_slice(&w, m, l);
            let mut pii = vec![0.0; l * l];
            matmul(
                MatMut::from_column_major_slice_mut(&mut pii, l, l),
                Accum::Replace,
                wr.transpose(),
                wr,
                1.0,
                Par::Seq,
            );
            let k = g.outs.len();
            let ai: Vec<f64> = (0..k)
                .flat_map(|col| a[col * n + p..col * n + p + l].iter().copied())
                .collect();
            let (log_det_pii, quad) = small::gaussian_terms(pii, l, ai)?;
            total += -0.5 * quad + 0.5 * k as f64 * log_det_pii;
        }
        Ok(Some(total))
    }

    /// Append frame `id` (not already here) as the last rows of every factor.
    pub fn insert(&mut self, id: usize, f: FrameRef<'_>) -> Result<()> {
        let (n, m) = (self.xy.len(), f.xy.len());
        let crosses: Vec<Vec<f64>> = (self.groups.iter())
            .map(|g| self.cross_to(f.inputs(), g.signal_var, false))
            .collect();
        self.changed(true);
        for (g, mut vbuf) in self.groups.iter_mut().zip(crosses) {
            g.factor.solve_lower(&mut vbuf, Par::Seq);
            let v = MatRef::from_column_major_slice(&vbuf, n, m);
            let k = g.outs.len();
            let mut r = schur(&f, v, g, &self.params, &self.corr, Par::Seq);
            small::cholesky(&mut r, m)?;
            // New whitened residuals: z_new = R⁻¹ (v_f − μ − Vᵀ z).
            let mut rz = residual(
                &f,
                v,
                MatRef::from_column_major_slice(&g.z, n, k),
                g.outs,
                &self.params,
                Par::Seq,
            );
            small::solve_lower(&r, m, &mut rz);
            let mut z = Vec::with_capacity((n + m) * k);
            for c in 0..k {
                z.extend_from_slice(&g.z[c * n..(c + 1) * n]);
                z.extend_from_slice(&rz[c * m..(c + 1) * m]);
            }
            g.z = z;
            g.factor.append(&vbuf, &r, m);
        }
        self.frames.push(id);
        self.sizes.push(m);
        extend_headings(&mut self.h, n, f.h, m);
        self.xy.extend_from_slice(f.xy);
        self.v.extend_from_slice(f.v);
        Ok(())
    }

    /// Remove frame `id`; returns false if it is not here.
    pub fn remove(&mut self, id: usize) -> Result<bool> {
        let Some(pos) = self.frames.iter().position(|&f| f == id) else {
            return Ok(false);
        };
        let start: usize = self.sizes[..pos].iter().sum();
        let l = self.sizes[pos];
        self.changed(true);
        self.frames.remove(pos);
        self.sizes.remove(pos);
        self.xy.drain(start..start + l);
        if !self.h.is_empty() {
            self.h.drain(start..start + l);
        }
        self.v.drain(start..start + l);
        if self.xy.is_empty() {
            self.groups.clear();
            return Ok(true);
        }
        let mut stable = true;
        for g in &mut self.groups {
            stable &= g.factor.delete(start, l);
        }
        if !stable {
            self.refactor()?;
            return Ok(true);
        }
        // The leading part of z is unchanged; re-whiten the rest (n² work, far below the update).
        let n = self.xy.len();
        for g in &mut self.groups {
            let mut z = centered(&self.v, g.outs, self.params.mean);
            g.factor.solve_lower(&mut z, Par::Seq);
            g.z = z;
            debug_assert_eq!(g.z.len(), n * g.outs.len());
        }
        Ok(true)
    }
}

impl Pattern {
    /// `(log |S|, ‖chol(S)⁻¹ r‖²)` for one frame and one output group. A standalone GP scores
    /// test sets of any size, so large ones go to faer (in parallel where allowed).
    fn schur_terms(
        &self,
        f: &FrameRef<'_>,
        v: MatRef<'_, f64>,
        z: MatRef<'_, f64>,
        g: &Group,
    ) -> Result<(f64, f64)> {
        let (p, par, m) = (&self.params, self.par(), f.xy.len());
        let s = schur(f, v, g, p, &self.corr, par);
        let mut r = residual(f, v, z, g.outs, p, par);
        if self.solo.is_none() || m <= SMALL_MAX {
            return small::gaussian_terms(s, m, r);
        }
        let chol = Chol::factor(m, "predictive", par, || s.clone())?;
        chol.solve_lower(&mut r, par);
        Ok((chol.log_det(), r.iter().map(|x| x * x).sum()))
    }
}

/// `dst -= Vᵀ x` for a column-major `dst` of `V.ncols()` rows (a no-op for an empty pattern).
fn sub_vt_times(dst: &mut [f64], v: MatRef<'_, f64>, x: MatRef<'_, f64>, par: Par) {
    if v.nrows() > 0 {
        let d = MatMut::from_column_major_slice_mut(dst, v.ncols(), x.ncols());
        matmul(d, Accum::Add, v.transpose(), x, -1.0, par);
    }
}

/// `S = σ² R(X_f, X_f) + σ_n² I − VᵀV` (m x m, column-major).
fn schur(
    f: &FrameRef<'_>,
    v: MatRef<'_, f64>,
    g: &Group,
    p: &GpParams,
    corr: &Correlation,
    par: Par,
) -> Vec<f64> {
    let parallel = !matches!(par, Par::Seq);
    let mut s = corr.gram_par(
        f.inputs(),
        p.length_scales,
        g.signal_var,
        g.noise_var,
        parallel,
    );
    sub_vt_times(&mut s, v, v, par);
    s
}

/// `r = v_f − μ − Vᵀ z` for the outputs of a group (m x k, column-major).
fn residual(
    f: &FrameRef<'_>,
    v: MatRef<'_, f64>,
    z: MatRef<'_, f64>,
    outs: &[usize],
    p: &GpParams,
    par: Par,
) -> Vec<f64> {
    let mut r = centered(f.v, outs, p.mean);
    sub_vt_times(&mut r, v, z, par);
    r
}

/// Queries per block of a posterior: bounds the cross-correlation buffer to `n x QUERY_BLOCK`.
const QUERY_BLOCK: usize = 1024;

/// Points that are non-empty and finite.
pub fn check_points(name: &str, xy: &[Point]) -> Result<()> {
    if xy.is_empty() {
        return Err(Error::Shape(format!(
            "{name} is empty: at least one point is needed"
        )));
    }
    check_finite(name, xy.as_flattened())
}

/// Headings that are empty (none known) or one per point, each finite or `NaN` (unknown).
pub fn check_headings(name: &str, h: &[f64], n: usize) -> Result<()> {
    if !h.is_empty() && h.len() != n {
        return Err(Error::Shape(format!(
            "{name} has {} headings for {n} points; give one per point (NaN where a vehicle has \
             no previous step) or none",
            h.len()
        )));
    }
    if let Some(i) = h.iter().position(|x| x.is_infinite()) {
        return Err(Error::InvalidInput(format!(
            "{name}[{i}] is infinite; a heading is an angle in radians, or NaN where unknown"
        )));
    }
    Ok(())
}

/// Points and velocities that are non-empty, finite and row for row.
pub fn check_pair(xy_name: &str, xy: &[Point], v_name: &str, v: &[[f64; 2]]) -> Result<()> {
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

/// `log N(V_f ; μ, σ² R_ff + σ_n² I)` summed over both outputs: the prior predictive of a frame
/// (the new-pattern term of Algorithm 8).
pub fn prior_score(f: FrameRef<'_>, p: &GpParams) -> Result<f64> {
    prior_score_with(&Correlation::SquaredExp, f, p)
}

/// [`prior_score`] under the correlation `corr`.
pub fn prior_score_with(corr: &Correlation, f: FrameRef<'_>, p: &GpParams) -> Result<f64> {
    Ok(prior_scores_with(corr, f, std::slice::from_ref(p))?[0])
}

/// [`prior_score_with`] for several parameter sets (Algorithm 8's auxiliary patterns): the
/// frame's reduced-rank eigenfunctions are evaluated once for all of them.
pub fn prior_scores_with(corr: &Correlation, f: FrameRef<'_>, ps: &[GpParams]) -> Result<Vec<f64>> {
    let features = match corr {
        Correlation::Reduced(basis) => Some(basis.axis_features(f.xy)),
        Correlation::SquaredExp => None,
    };
    ps.iter()
        .map(|p| {
            let c = match (corr, &features) {
                (Correlation::Reduced(basis), Some(ft)) => {
                    basis.headed_correlation(ft, ft, f.inputs(), f.inputs(), p.length_scales, 1.0)
                }
                _ => corr.cross(f.inputs(), f.inputs(), p.length_scales, 1.0),
            };
            gaussian_prior(&c, f, p)
        })
        .collect()
}

/// `log N(V_f ; μ, σ² C + σ_n² I)` summed over both outputs, for the correlation matrix `c`.
fn gaussian_prior(c: &[f64], f: FrameRef<'_>, p: &GpParams) -> Result<f64> {
    let m = f.xy.len();
    let mut total = -(m as f64) * LN_2PI;
    for outs in p.groups() {
        let (s2, n2) = p.group_vars(outs);
        let mut a: Vec<f64> = c.iter().map(|c| c * s2).collect();
        for i in 0..m {
            a[i * m + i] += n2;
        }
        let (log_det, quad) = small::gaussian_terms(a, m, centered(f.v, outs, p.mean))?;
        total -= 0.5 * quad + 0.5 * outs.len() as f64 * log_det;
    }
    Ok(total)
}

#[cfg(test)]
#[path = "tests/pattern.rs"]
mod tests;
