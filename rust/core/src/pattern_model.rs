//! One interface for a motion pattern's GP, whatever the likelihood: the sampler scores, moves
//! and resamples patterns through [`PatternModel`] and never knows which model runs.
//!
//! - `exact` ([`Pattern`]): the full squared-exponential GP, a growable Cholesky factor.
//! - `hsgp` ([`ReducedPattern`]): the reduced-rank GP of [`crate::hsgp`]. One fit is one model
//!   (the kernel `k̃`); how a pattern computes with it is a detail: a pattern of fewer points
//!   than basis functions keeps the dense `n x n` factor of `k̃` (cheaper, same densities to
//!   round-off), a larger one the `M x M` statistics.

use std::sync::Arc;

use crate::correlation::Correlation;
use crate::error::{Error, Result};
use crate::frame::{FrameRef, Inputs};
use crate::frame::{LengthScales, Point};
use crate::gp::GpParams;
use crate::hsgp::{Basis, HsgpPattern};
use crate::pattern::{Pattern, prior_score_with, prior_scores_with};

/// A pattern's GP: its data, marginal likelihood, scores of frames, moves and posterior.
pub trait PatternModel: Send + Sync + std::fmt::Debug {
    fn params(&self) -> &GpParams;
    fn n_frames(&self) -> usize;
    /// Training frames, in the pattern's internal order.
    fn frames(&self) -> &[usize];
    /// All its points and velocities, frames in [`PatternModel::frames`] order.
    fn points(&self) -> (&[Point], &[[f64; 2]]);
    /// The points' previous headings (`NaN`: unknown), or empty when no frame has them.
    fn headings(&self) -> &[f64];
    /// `log p(D_k)`.
    fn log_marginal(&self) -> f64;
    /// `log p(V_f | D_k)` of frames not in the pattern.
    fn score(&self, frames: &[FrameRef<'_>]) -> Result<Vec<f64>>;
    /// `log p(V_f | D_k \ f)` of a member frame; `None` if it is not a member or the only one.
    fn loo_score(&self, id: usize) -> Result<Option<f64>>;
    fn insert(&mut self, id: usize, f: FrameRef<'_>) -> Result<()>;
    fn remove(&mut self, id: usize) -> Result<bool>;
    /// The same frames under other hyperparameters.
    fn with_params(&self, params: GpParams) -> Result<Box<dyn PatternModel>>;
    /// Posterior mean at each input (a position, and a previous heading for a field over
    /// heading; `NaN` or none: the field averaged over heading).
    fn predict_mean_at(&self, q: Inputs<'_>) -> Vec<[f64; 2]>;
    /// Posterior mean and latent variance at each input.
    fn posterior_at(&self, q: Inputs<'_>) -> (Vec<[f64; 2]>, Vec<[f64; 2]>);
    /// Posterior mean and, per output, the joint latent covariance (column-major).
    fn predict_joint_at(&self, q: Inputs<'_>) -> (Vec<[f64; 2]>, [Vec<f64>; 2]);
    /// Whether each input's latent posterior variance exceeds `f` times the prior's in either
    /// output: the low-data flags of a rollout.
    fn low_data_at(&self, q: Inputs<'_>, f: f64) -> Vec<bool> {
        let (_, var) = self.posterior_at(q);
        let s2 = self.params().signal_var;
        var.iter()
            .map(|&v| crate::low_data::is_low(v, s2, f))
            .collect()
    }
    /// Whether the field takes a heading beside the position.
    fn headed(&self) -> bool {
        self.params().length_scales.wh.is_finite()
    }
    /// Bytes held now, and after adding a frame of `l` points.
    fn bytes(&self) -> usize;
    fn bytes_after_insert(&self, l: usize) -> usize;
    fn clone_box(&self) -> Box<dyn PatternModel>;

    fn length_scales(&self) -> LengthScales {
        self.params().length_scales
    }

    /// [`PatternModel::predict_mean_at`] of positions alone.
    fn predict_mean(&self, q: &[Point]) -> Vec<[f64; 2]> {
        self.predict_mean_at(Inputs::positions(q))
    }

    /// [`PatternModel::posterior_at`] of positions alone.
    fn posterior(&self, q: &[Point]) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
        self.posterior_at(Inputs::positions(q))
    }

    /// [`PatternModel::predict_joint_at`] of positions alone.
    fn predict_joint(&self, q: &[Point]) -> (Vec<[f64; 2]>, [Vec<f64>; 2]) {
        self.predict_joint_at(Inputs::positions(q))
    }

    fn n_points(&self) -> usize {
        self.points().0.len()
    }

    fn with_length_scales(&self, ls: LengthScales) -> Result<Box<dyn PatternModel>> {
        self.with_params(self.params().with_length_scales(ls))
    }

    /// The same frames with the signal variances and means set to those of its own velocities
    /// (variances floored at `floor`); `None` if they are unchanged.
    fn with_own_moments(&self, floor: [f64; 2]) -> Result<Option<Box<dyn PatternModel>>> {
        let (_, v) = self.points();
        let n = v.len() as f64;
        let mut mean = [0.0; 2];
        let mut var = [0.0; 2];
        for d in 0..2 {
            mean[d] = v.iter().map(|r| r[d]).sum::<f64>() / n;
            var[d] = (v.iter().map(|r| (r[d] - mean[d]).powi(2)).sum::<f64>() / n).max(floor[d]);
        }
        let p = *self.params();
        if var == p.signal_var && mean == p.mean {
            return Ok(None);
        }
        self.with_params(GpParams {
            signal_var: var,
            mean,
            ..p
        })
        .map(Some)
    }

    /// `(id, frame)` of every member, in internal order.
    fn members(&self) -> Vec<(usize, FrameRef<'_>)> {
        let (xy, v) = self.points();
        let h = self.headings();
        let mut start = 0;
        self.frames()
            .iter()
            .zip(self.sizes())
            .map(|(&id, &l)| {
                let f = FrameRef {
                    xy: &xy[start..start + l],
                    v: &v[start..start + l],
                    h: if h.is_empty() {
                        &[]
                    } else {
                        &h[start..start + l]
                    },
                };
                start += l;
                (id, f)
            })
            .collect()
    }

    /// Points per member frame, in internal order.
    fn sizes(&self) -> &[usize];
}

impl Clone for Box<dyn PatternModel> {
    fn clone(&self) -> Self {
        self.clone_box()
    }
}

impl PatternModel for Pattern {
    fn params(&self) -> &GpParams {
        &self.params
    }
    fn n_frames(&self) -> usize {
        Pattern::n_frames(self)
    }
    fn frames(&self) -> &[usize] {
        &self.frames
    }
    fn sizes(&self) -> &[usize] {
        Pattern::sizes(self)
    }
    fn points(&self) -> (&[Point], &[[f64; 2]]) {
        Pattern::points(self)
    }
    fn headings(&self) -> &[f64] {
        Pattern::inputs(self).h
    }
    fn log_marginal(&self) -> f64 {
        Pattern::log_marginal(self)
    }
    fn score(&self, frames: &[FrameRef<'_>]) -> Result<Vec<f64>> {
        Pattern::score(self, frames)
    }
    fn loo_score(&self, id: usize) -> Result<Option<f64>> {
        Pattern::loo_score(self, id)
    }
    fn insert(&mut self, id: usize, f: FrameRef<'_>) -> Result<()> {
        Pattern::insert(self, id, f)
    }
    fn remove(&mut self, id: usize) -> Result<bool> {
        Pattern::remove(self, id)
    }
    fn with_params(&self, params: GpParams) -> Result<Box<dyn PatternModel>> {
        Ok(Box::new(Pattern::with_params(self, params)?))
    }
    fn predict_mean_at(&self, q: Inputs<'_>) -> Vec<[f64; 2]> {
        Pattern::predict_mean_at(self, q)
    }
    fn posterior_at(&self, q: Inputs<'_>) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
        Pattern::posterior_at(self, q)
    }
    fn low_data_at(&self, q: Inputs<'_>, f: f64) -> Vec<bool> {
        Pattern::low_data_at(self, q, f)
    }
    fn predict_joint_at(&self, q: Inputs<'_>) -> (Vec<[f64; 2]>, [Vec<f64>; 2]) {
        Pattern::predict_joint_at(self, q)
    }
    fn bytes(&self) -> usize {
        Pattern::bytes(self)
    }
    fn bytes_after_insert(&self, l: usize) -> usize {
        Pattern::bytes_after_insert(self, l)
    }
    fn clone_box(&self) -> Box<dyn PatternModel> {
        Box::new(self.clone())
    }
}

/// A pattern of the reduced-rank model, kept dense while it has at most `M` points and as
/// `M x M` statistics beyond (back to dense below `M / 2`, so a pattern near the threshold does
/// not convert on every move).
#[derive(Clone, Debug)]
pub enum ReducedPattern {
    Dense(Pattern),
    Basis(HsgpPattern),
}

impl ReducedPattern {
    pub fn new(
        basis: Arc<Basis>,
        params: GpParams,
        members: &[(usize, FrameRef<'_>)],
    ) -> Result<Self> {
        let n: usize = members.iter().map(|m| m.1.xy.len()).sum();
        let dense = n <= basis.len();
        Self::build(basis, params, members, dense)
    }

    fn build(
        basis: Arc<Basis>,
        params: GpParams,
        members: &[(usize, FrameRef<'_>)],
        dense: bool,
    ) -> Result<Self> {
        Ok(if dense {
            Self::Dense(Pattern::with_correlation(
                Correlation::Reduced(basis),
                params,
                members,
            )?)
        } else {
            Self::Basis(HsgpPattern::new(basis, params, members)?)
        })
    }

    fn basis(&self) -> Arc<Basis> {
        match self {
            Self::Dense(p) => match p.correlation() {
                Correlation::Reduced(b) => Arc::clone(b),
                Correlation::SquaredExp => unreachable!("a reduced pattern has a basis"),
            },
            Self::Basis(p) => Arc::clone(p.basis()),
        }
    }

    fn inner(&self) -> &dyn PatternModel {
        match self {
            Self::Dense(p) => p,
            Self::Basis(p) => p,
        }
    }

    fn inner_mut(&mut self) -> &mut dyn PatternModel {
        match self {
            Self::Dense(p) => p,
            Self::Basis(p) => p,
        }
    }

    /// Switch representation if the size calls for it.
    fn settle(self) -> Result<Self> {
        let basis = self.basis();
        let (n, m) = (self.inner().n_points(), basis.len());
        let want_dense = match &self {
            Self::Dense(_) => n <= m,
            Self::Basis(_) => n < m / 2,
        };
        if want_dense == matches!(self, Self::Dense(_)) {
            return Ok(self);
        }
        let members = self.inner().members();
        Self::build(basis, *self.inner().params(), &members, want_dense)
    }
}

impl PatternModel for HsgpPattern {
    fn params(&self) -> &GpParams {
        &self.params
    }
    fn n_frames(&self) -> usize {
        HsgpPattern::n_frames(self)
    }
    fn frames(&self) -> &[usize] {
        HsgpPattern::frames(self)
    }
    fn sizes(&self) -> &[usize] {
        HsgpPattern::sizes(self)
    }
    fn points(&self) -> (&[Point], &[[f64; 2]]) {
        HsgpPattern::points(self)
    }
    fn headings(&self) -> &[f64] {
        HsgpPattern::inputs(self).h
    }
    fn log_marginal(&self) -> f64 {
        HsgpPattern::log_marginal(self)
    }
    fn score(&self, frames: &[FrameRef<'_>]) -> Result<Vec<f64>> {
        HsgpPattern::score(self, frames)
    }
    fn loo_score(&self, id: usize) -> Result<Option<f64>> {
        HsgpPattern::loo_score(self, id)
    }
    fn insert(&mut self, id: usize, f: FrameRef<'_>) -> Result<()> {
        HsgpPattern::insert(self, id, f)
    }
    fn remove(&mut self, id: usize) -> Result<bool> {
        HsgpPattern::remove(self, id)
    }
    fn with_params(&self, params: GpParams) -> Result<Box<dyn PatternModel>> {
        Ok(Box::new(HsgpPattern::with_params(self, params)?))
    }
    fn predict_mean_at(&self, q: Inputs<'_>) -> Vec<[f64; 2]> {
        HsgpPattern::predict_mean_at(self, q)
    }
    fn posterior_at(&self, q: Inputs<'_>) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
        HsgpPattern::posterior_at(self, q)
    }
    fn low_data_at(&self, q: Inputs<'_>, f: f64) -> Vec<bool> {
        HsgpPattern::low_data_at(self, q, f)
    }
    fn predict_joint_at(&self, q: Inputs<'_>) -> (Vec<[f64; 2]>, [Vec<f64>; 2]) {
        HsgpPattern::predict_joint_at(self, q)
    }
    fn bytes(&self) -> usize {
        HsgpPattern::bytes(self)
    }
    fn bytes_after_insert(&self, l: usize) -> usize {
        HsgpPattern::bytes(self) + 56 * l
    }
    fn clone_box(&self) -> Box<dyn PatternModel> {
        Box::new(self.clone())
    }
}

impl PatternModel for ReducedPattern {
    fn params(&self) -> &GpParams {
        self.inner().params()
    }
    fn n_frames(&self) -> usize {
        self.inner().n_frames()
    }
    fn frames(&self) -> &[usize] {
        self.inner().frames()
    }
    fn sizes(&self) -> &[usize] {
        self.inner().sizes()
    }
    fn points(&self) -> (&[Point], &[[f64; 2]]) {
        self.inner().points()
    }
    fn headings(&self) -> &[f64] {
        self.inner().headings()
    }
    fn log_marginal(&self) -> f64 {
        self.inner().log_marginal()
    }
    fn score(&self, frames: &[FrameRef<'_>]) -> Result<Vec<f64>> {
        self.inner().score(frames)
    }
    fn loo_score(&self, id: usize) -> Result<Option<f64>> {
        self.inner().loo_score(id)
    }
    fn insert(&mut self, id: usize, f: FrameRef<'_>) -> Result<()> {
        self.inner_mut().insert(id, f)?;
        let me = std::mem::replace(self, placeholder());
        *self = me.settle()?;
        Ok(())
    }
    fn remove(&mut self, id: usize) -> Result<bool> {
        let found = self.inner_mut().remove(id)?;
        if found && self.n_points() > 0 {
            let me = std::mem::replace(self, placeholder());
            *self = me.settle()?;
        }
        Ok(found)
    }
    fn with_params(&self, params: GpParams) -> Result<Box<dyn PatternModel>> {
        Ok(Box::new(match self {
            Self::Dense(p) => Self::Dense(p.with_params(params)?),
            Self::Basis(p) => Self::Basis(p.with_params(params)?),
        }))
    }
    fn predict_mean_at(&self, q: Inputs<'_>) -> Vec<[f64; 2]> {
        self.inner().predict_mean_at(q)
    }
    fn posterior_at(&self, q: Inputs<'_>) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
        self.inner().posterior_at(q)
    }
    fn low_data_at(&self, q: Inputs<'_>, f: f64) -> Vec<bool> {
        self.inner().low_data_at(q, f)
    }
    fn predict_joint_at(&self, q: Inputs<'_>) -> (Vec<[f64; 2]>, [Vec<f64>; 2]) {
        self.inner().predict_joint_at(q)
    }
    fn bytes(&self) -> usize {
        self.inner().bytes()
    }
    fn bytes_after_insert(&self, l: usize) -> usize {
        let m = self.basis().len();
        match self {
            Self::Dense(p) if p.n_points() + l > m => {
                8 * m * m * (1 + p.params.groups().len()) + 56 * (p.n_points() + l)
            }
            _ => self.inner().bytes_after_insert(l),
        }
    }
    fn clone_box(&self) -> Box<dyn PatternModel> {
        Box::new(self.clone())
    }
}

/// An empty stand-in while a pattern is moved out and back in `settle` (never observed).
fn placeholder() -> ReducedPattern {
    ReducedPattern::Dense(Pattern::empty())
}

/// Which GP the patterns of a fit use. One fit is one model.
#[derive(Clone, Debug, Default)]
pub enum Likelihood {
    #[default]
    Exact,
    Hsgp(Arc<Basis>),
}

/// The name of a likelihood, as a setting spells it; the basis comes separately (it is sized
/// from the data), see [`Likelihood::new`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LikelihoodKind {
    Exact,
    Hsgp,
}

impl std::str::FromStr for LikelihoodKind {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "exact" => Ok(Self::Exact),
            "hsgp" => Ok(Self::Hsgp),
            _ => Err(crate::error::unknown_option(
                "likelihood",
                &["exact", "hsgp"],
                s,
            )),
        }
    }
}

impl Likelihood {
    /// The likelihood of `kind`; hsgp needs its basis.
    pub fn new(kind: LikelihoodKind, basis: Option<Arc<Basis>>) -> Result<Self> {
        match (kind, basis) {
            (LikelihoodKind::Exact, _) => Ok(Self::Exact),
            (LikelihoodKind::Hsgp, Some(b)) => Ok(Self::Hsgp(b)),
            (LikelihoodKind::Hsgp, None) => Err(Error::InvalidInput(
                "likelihood 'hsgp' needs a basis".into(),
            )),
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            Self::Exact => "exact",
            Self::Hsgp(_) => "hsgp",
        }
    }

    pub fn correlation(&self) -> Correlation {
        match self {
            Self::Exact => Correlation::SquaredExp,
            Self::Hsgp(b) => Correlation::Reduced(Arc::clone(b)),
        }
    }

    /// A new pattern holding `members`.
    pub fn pattern(
        &self,
        params: GpParams,
        members: &[(usize, FrameRef<'_>)],
    ) -> Result<Box<dyn PatternModel>> {
        Ok(match self {
            Self::Exact => Box::new(Pattern::new(params, members)?),
            Self::Hsgp(b) => Box::new(ReducedPattern::new(Arc::clone(b), params, members)?),
        })
    }

    /// `log N(V_f ; μ, σ² r(X_f, X_f) + σ_n² I)`: the frame's density under a new pattern.
    pub fn prior_score(&self, f: FrameRef<'_>, p: &GpParams) -> Result<f64> {
        prior_score_with(&self.correlation(), f, p)
    }

    /// [`Likelihood::prior_score`] for several parameter sets at once.
    pub fn prior_scores(&self, f: FrameRef<'_>, ps: &[GpParams]) -> Result<Vec<f64>> {
        prior_scores_with(&self.correlation(), f, ps)
    }

    /// Bytes a pattern of `n` points would hold at most (both likelihoods grow factors by
    /// [`crate::factor::capacity`]).
    pub fn pattern_bytes(&self, n: usize, groups: usize) -> usize {
        let dense = 8 * groups * crate::factor::capacity(n).pow(2) + 56 * n;
        match self {
            Self::Exact => dense,
            Self::Hsgp(b) => {
                let m = b.len();
                if n <= m {
                    dense
                } else {
                    8 * m * m * (1 + groups) + 56 * n
                }
            }
        }
    }
}
