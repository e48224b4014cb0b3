//! The collapsed Gibbs sampler of the DP mixture of GP velocity fields (docs/model.md;
//! docs/engine.md, "One sweep").
//!
//! State: an assignment of every frame to a pattern (patterns live in a generational arena, so
//! their ids are stable), per-pattern length scales, and α. One sweep visits every frame in
//! order: remove it from its pattern (a rank-l update), score it against every pattern by the
//! append trial — from a cache keyed by pattern version, so only patterns that changed are
//! re-scored — and against new patterns by Neal's Algorithm 8, then insert it where it was drawn.
//! Length scales are then slice-sampled per pattern and α by slice sampling on log α.
//!
//! Every random draw comes from a stream keyed by (seed, sweep, phase, entity) and every
//! parallel result is reduced in slot order, so a run does not depend on the thread count.

use std::sync::Arc;
use std::time::Instant;

use rand::RngExt;
use rand_distr::{Distribution, Gamma};
use rayon::prelude::*;

use crate::error::{Error, Result, unknown_option};
use crate::frame::FrameRef;
use crate::frame::{LengthScales, Point};
use crate::gp::GpParams;
use crate::pattern_model::{Likelihood, PatternModel};
use crate::proposal::{self, CellGrid, CellStats};
use crate::rng::{Phase, stream};
use crate::slice::slice_step;
use crate::special::{ln_gamma, ln_gamma_pdf, log_sum_exp};

impl hyper::Refit for Box<dyn PatternModel> {
    fn params(&self) -> &GpParams {
        PatternModel::params(self.as_ref())
    }
    fn log_marginal(&self) -> f64 {
        PatternModel::log_marginal(self.as_ref())
    }
    fn n_points(&self) -> usize {
        PatternModel::n_points(self.as_ref())
    }
    fn refit(&self, params: GpParams) -> Result<Self> {
        self.with_params(params)
    }
}

#[path = "hyper.rs"]
mod hyper;
#[path = "noise.rs"]
mod noise;
#[path = "split_merge.rs"]
mod split_merge;
#[path = "sticky.rs"]
mod sticky;
pub(crate) use hyper::{
    Refit, global_noise_step, length_scale_step, length_scale_width, noise_step,
};
pub(crate) use noise::check_noise_pair;
pub use noise::{NoisePrior, NoiseScope};
pub(crate) use split_merge::frame_means;
pub use split_merge::{PairChoice, SplitMerge, SplitMergeStats};
pub use sticky::StickyPrior;

const NONE: usize = usize::MAX;
/// Frames scored together in one triangular solve when refreshing a pattern's scores.
const SCORE_BLOCK: usize = 64;
/// Slice-sampling steps of log α per sweep.
const ALPHA_STEPS: usize = 10;
/// Auxiliary patterns scored per parallel task.
const AUX_CHUNK: usize = 25;
// The limits of the settings live here and nowhere else: the binding exports them to Python
// (`dpgp._core.MAX_THREADS`, ...), which validates no setting itself (docs/engine-layout.md).
/// Most auxiliary patterns per frame (each costs an l x l factorisation).
pub const MAX_NEW_PATTERN_SAMPLES: usize = 100_000;
/// Most split–merge moves per sweep.
pub const MAX_SPLIT_MERGE_MOVES: usize = 1_000_000;
/// Most worker threads a sampler's pool may have (the pool is the caller's; see [`check_threads`]).
pub const MAX_THREADS: usize = 1024;
/// Range of a fixed concentration α: beyond it `log Γ(α) - log Γ(α + N)`, `-1/(2α)` and the
/// new-pattern weight `log(α / m)` are not finite in double precision.
pub const ALPHA_RANGE: (f64, f64) = (1e-100, 1e100);
/// Informed proposals: the cheap scores are tempered (they treat a frame's vehicles as
/// independent, so they are overconfident) and mixed with a uniform share, so that every
/// pattern keeps a chance to be proposed.
const TEMPER: f64 = 0.7;
const UNIFORM_SHARE: f64 = 0.02;
/// Patterns scored exactly when a frame is placed by the informed rule without a current
/// pattern (initialisation) or in MAP mode: the best ones by cheap score, plus its own.
const INFORMED_CANDIDATES: usize = 2;
/// Frames placed one by one by the (restricted) conditional at initialisation with informed
/// proposals; the rest join patterns by cheap score.
pub const INIT_SEQUENTIAL: usize = 1000;

/// The size of a sampler's thread pool: `None` for one thread per core (returned as 0, as
/// rayon takes it), else 1 to [`MAX_THREADS`].
pub fn check_threads(n: Option<usize>) -> Result<usize> {
    match n {
        None => Ok(0),
        Some(k @ 1..=MAX_THREADS) => Ok(k),
        Some(k) => Err(Error::InvalidInput(format!(
            "n_threads must be None or an integer in [1, {MAX_THREADS}], got {k}"
        ))),
    }
}

/// How a frame's new pattern is proposed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Proposal {
    /// Score the frame against every pattern and draw from the full conditional.
    Full,
    /// Propose a pattern by a cheap score over all of them and accept by the exact ratio of
    /// the proposed and current patterns (Metropolis-within-Gibbs; docs/engine.md, "Informed
    /// proposals").
    Informed,
}

/// How a frame's pattern is chosen from its conditional.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Assignment {
    /// Draw from the conditional: a true Gibbs sampler.
    Gibbs,
    /// Take the most probable pattern (the paper's Algorithm 1).
    Map,
}

// Settings arrive by name (from Python, a file or a command line): each enum parses its own
// names, and a wrong one is an `InvalidInput` that lists the right ones.
impl std::str::FromStr for Proposal {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "full" => Ok(Self::Full),
            "informed" => Ok(Self::Informed),
            _ => Err(unknown_option("proposal", &["full", "informed"], s)),
        }
    }
}

impl std::str::FromStr for Assignment {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "gibbs" => Ok(Self::Gibbs),
            "map" => Ok(Self::Map),
            _ => Err(unknown_option("assignment", &["gibbs", "map"], s)),
        }
    }
}

/// Which sampler runs the chain.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SamplerKind {
    /// Collapsed Gibbs, one frame at a time (the paper's; this module).
    #[default]
    Collapsed,
    /// Every frame in parallel given drawn fields, with sub-pattern split–merge moves
    /// (`subcluster`; the reduced-rank likelihood only).
    Subcluster,
}

impl std::str::FromStr for SamplerKind {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "collapsed" => Ok(Self::Collapsed),
            "subcluster" => Ok(Self::Subcluster),
            _ => Err(unknown_option("sampler", &["collapsed", "subcluster"], s)),
        }
    }
}

/// Everything that configures a run.
#[derive(Clone, Debug)]
pub struct Settings {
    pub assignment: Assignment,
    /// Signal variances, noise variance and means; its length scales are used for every pattern
    /// when `fixed_length_scales` is set.
    pub base: GpParams,
    pub fixed_length_scales: bool,
    /// Gamma(shape, scale) prior of each length scale.
    pub length_scale_prior: (f64, f64),
    /// Gamma(shape, scale) prior of each pattern's length scale in the previous heading
    /// (radians): fields over position and heading (`heading`). `None`: over position only
    /// (`w_h = ∞`, the paper's model).
    pub heading_prior: Option<(f64, f64)>,
    /// A fixed concentration; `None` samples it.
    pub alpha: Option<f64>,
    /// Auxiliary patterns of Algorithm 8.
    pub new_pattern_samples: usize,
    /// Set each pattern's signal variances and means to its own data's at the parameter step
    /// (what the paper's code does; never during the assignment sweep). New patterns start from
    /// `base`. The chain then no longer targets a fixed model's posterior.
    pub pattern_moments: bool,
    /// Share of the patterns whose length scales are resampled each sweep (chosen at random per
    /// pattern and sweep). Below 1 the score cache of the others survives the sweep; every
    /// pattern is still updated infinitely often, so the chain keeps the same posterior.
    pub length_scale_fraction: f64,
    pub seed: u64,
    /// The GP of every pattern: exact or reduced-rank.
    pub likelihood: Likelihood,
    pub proposal: Proposal,
    /// Bytes the patterns' factors and the score cache may hold; `None` for no limit.
    pub memory_budget: Option<usize>,
    /// Split–merge moves after each sweep's frame updates (split_merge.rs); off by default.
    pub split_merge: SplitMerge,
    /// Sample the noise pair each sweep under this prior (noise.rs); `None` keeps
    /// `base.noise_var` fixed.
    pub noise_prior: Option<NoisePrior>,
    /// One noise pair for all patterns, or each pattern's own (needs `noise_prior`; noise.rs).
    pub noise_scope: NoiseScope,
    /// The sticky prior on consecutive frames' labels (sticky.rs); `None`: the independent DP.
    pub dynamics: Option<StickyPrior>,
    /// The sampler that runs the chain.
    pub sampler: SamplerKind,
}

/// A number as Python's `{:g}` writes one far from 1 (`1e+100`, not 100 digits).
fn g(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-4..1e16).contains(&x.abs()) {
        return format!("{x}");
    }
    let s = format!("{x:e}");
    match s.split_once('e') {
        Some((m, e)) if !e.starts_with('-') => format!("{m}e+{e}"),
        _ => s,
    }
}

impl Default for Settings {
    /// Gibbs assignment, full proposals, the exact likelihood, unit GP parameters with sampled
    /// length scales under a Gamma(10, 1) prior, sampled α, 10 auxiliary patterns, no split–merge
    /// fixed noise and the independent DP: a valid start for `Settings { seed, ..Settings::default() }`.
    fn default() -> Self {
        Self {
            assignment: Assignment::Gibbs,
            base: GpParams {
                length_scales: LengthScales {
                    wx: 1.0,
                    wy: 1.0,
                    wh: f64::INFINITY,
                },
                signal_var: [1.0, 1.0],
                noise_var: [1.0, 1.0],
                mean: [0.0, 0.0],
            },
            fixed_length_scales: false,
            length_scale_prior: (10.0, 1.0),
            heading_prior: None,
            alpha: None,
            new_pattern_samples: 10,
            pattern_moments: false,
            length_scale_fraction: 1.0,
            seed: 0,
            likelihood: Likelihood::Exact,
            proposal: Proposal::Full,
            memory_budget: None,
            split_merge: SplitMerge::default(),
            noise_prior: None,
            noise_scope: NoiseScope::Global,
            dynamics: None,
            sampler: SamplerKind::Collapsed,
        }
    }
}

/// Shape and scale of the length-scale prior: each in this range (past it `ln Γ(a)` and `x / b`
/// leave double precision), and their product, the prior mean length scale where chains start, in
/// [`LENGTH_SCALE_MEAN_RANGE`].
pub const LENGTH_SCALE_PRIOR_RANGE: (f64, f64) = (1e-100, 1e100);
pub const LENGTH_SCALE_MEAN_RANGE: (f64, f64) = (1e-150, 1e100);

/// The rule of a Gamma(shape, scale) length-scale prior: both positive and finite, within
/// [`LENGTH_SCALE_PRIOR_RANGE`], their product within [`LENGTH_SCALE_MEAN_RANGE`]. Python calls
/// it too (a prior given by the user or read from a model file is checked before any work).
pub fn check_length_scale_prior((a, b): (f64, f64)) -> Result<()> {
    if !(a.is_finite() && a > 0.0 && b.is_finite() && b > 0.0) {
        return Err(Error::InvalidInput(format!(
            "length_scale_prior must be 'auto' or a Gamma (shape, scale) with both positive, got ({a}, {b})"
        )));
    }
    let ((lo, hi), (mlo, mhi)) = (LENGTH_SCALE_PRIOR_RANGE, LENGTH_SCALE_MEAN_RANGE);
    if !((lo..=hi).contains(&a) && (lo..=hi).contains(&b) && (mlo..=mhi).contains(&(a * b))) {
        return Err(Error::InvalidInput(format!(
            "length_scale_prior ({}, {}): shape and scale must lie in [{}, {}] and their product \
             (the prior mean length scale) in [{}, {}]; convert the positions to sensible units",
            g(a),
            g(b),
            g(lo),
            g(hi),
            g(mlo),
            g(mhi)
        )));
    }
    Ok(())
}

impl Settings {
    /// The Gamma priors of the sampled length-scale coordinates `(w_x, w_y[, w_h])`.
    pub(crate) fn length_scale_priors(&self) -> Vec<(f64, f64)> {
        let mut p = vec![self.length_scale_prior; 2];
        p.extend(self.heading_prior);
        p
    }

    /// `Σ log Gamma(w_i; a_i, b_i)` over the sampled coordinates of `ls`.
    pub(crate) fn length_scale_log_prior(&self, ls: LengthScales) -> f64 {
        self.length_scale_priors()
            .iter()
            .enumerate()
            .map(|(i, &(a, b))| ln_gamma_pdf(ls.coord(i), a, b))
            .sum()
    }

    /// Length scales drawn from their priors (`w_h = ∞` without a heading prior).
    pub(crate) fn draw_length_scales(&self, rng: &mut impl rand::Rng) -> Result<LengthScales> {
        let mut ls = LengthScales {
            wx: 1.0,
            wy: 1.0,
            wh: f64::INFINITY,
        };
        for (i, (a, b)) in self.length_scale_priors().into_iter().enumerate() {
            let g = Gamma::new(a, b).map_err(|e| Error::InvalidInput(e.to_string()))?;
            ls = ls.with_coord(i, g.sample(rng).max(1e-12));
        }
        Ok(ls)
    }

    /// `base` with length scales `ls`.
    pub(crate) fn pattern_params(&self, ls: LengthScales) -> GpParams {
        self.base.with_length_scales(ls)
    }

    /// A new pattern's parameters: `base` with length scales `ls` and noise pair `noise`.
    pub(crate) fn new_params(&self, ls: LengthScales, noise: [f64; 2]) -> GpParams {
        GpParams {
            noise_var: noise,
            ..self.pattern_params(ls)
        }
    }

    /// Fields over heading: check that the frames (when at hand) carry previous headings and a
    /// reduced-rank basis has heading harmonics, and start patterns at the prior's mean heading
    /// length scale unless one is fixed. Nothing to do over position.
    pub(crate) fn resolve_heading(&mut self, data: Option<&Data>) -> Result<()> {
        let Some((a, b)) = self.heading_prior else {
            return Ok(());
        };
        if data.is_some_and(|d| d.headings().is_empty()) {
            return Err(Error::InvalidInput(
                "fields over heading need each vehicle's previous heading: frames made by \
                 dpgp.make_frames from tracks carry them"
                    .into(),
            ));
        }
        if let Likelihood::Hsgp(basis) = &self.likelihood
            && basis.harmonics() == 0
        {
            return Err(Error::InvalidInput(
                "fields over heading on the reduced-rank engine need a basis with heading \
                 harmonics"
                    .into(),
            ));
        }
        let ls = self.base.length_scales;
        if !crate::heading::is_headed(ls.wh) {
            self.base.length_scales = ls.with_heading(a * b)?;
        }
        Ok(())
    }

    /// Every rule a setting must keep; [`Sampler::new`] calls it, and callers may call it early
    /// (before work that depends on the settings) with placeholders for what they resolve later.
    pub fn validate(&self) -> Result<()> {
        check_length_scale_prior(self.length_scale_prior)?;
        if let Some((a, b)) = self.heading_prior {
            if !(a.is_finite() && a > 0.0 && b.is_finite() && b > 0.0) {
                return Err(Error::InvalidInput(format!(
                    "heading_prior must be a Gamma (shape, scale) with both positive (radians), \
                     got ({a}, {b})"
                )));
            }
            if self.dynamics.is_some() {
                return Err(Error::InvalidInput(
                    "fields over heading do not run with dynamics='sticky' yet".into(),
                ));
            }
        }
        let (lo, hi) = ALPHA_RANGE;
        if let Some(al) = self.alpha
            && !(lo..=hi).contains(&al)
        {
            return Err(Error::InvalidInput(format!(
                "alpha must be None (sampled) or a number in [{}, {}] (beyond it the log joint \
                 is not finite in double precision), got {}",
                g(lo),
                g(hi),
                g(al)
            )));
        }
        if !(self.length_scale_fraction > 0.0 && self.length_scale_fraction <= 1.0) {
            return Err(Error::InvalidInput(format!(
                "length_scale_fraction must be in (0, 1], got {}",
                self.length_scale_fraction
            )));
        }
        if let Some(p) = &self.noise_prior {
            p.validate()?;
        }
        if self.noise_scope == NoiseScope::PerPattern && self.noise_prior.is_none() {
            return Err(Error::InvalidInput(
                "a per-pattern noise is sampled: it needs a noise prior (noise_var=\"per_pattern\" sets one)"
                    .into(),
            ));
        }
        if let Some(d) = &self.dynamics {
            d.validate()?;
        }
        if self.new_pattern_samples == 0 || self.new_pattern_samples > MAX_NEW_PATTERN_SAMPLES {
            return Err(Error::InvalidInput(format!(
                "new_pattern_samples must be an integer in [1, {MAX_NEW_PATTERN_SAMPLES}], got {}",
                self.new_pattern_samples
            )));
        }
        if self.sampler == SamplerKind::Subcluster {
            let why = if matches!(self.likelihood, Likelihood::Exact) {
                Some("needs likelihood='hsgp' (the exact GP has no finite weights to draw)")
            } else if self.pattern_moments {
                Some("cannot refit patterns to their own moments (pattern_moments)")
            } else if self.dynamics.is_some() {
                Some("does not run the sticky prior (dynamics='sticky') yet")
            } else {
                None
            };
            if let Some(why) = why {
                return Err(Error::InvalidInput(format!(
                    "sampler='subcluster' {why}; use sampler='collapsed'"
                )));
            }
        }
        if self.split_merge.moves_per_sweep > MAX_SPLIT_MERGE_MOVES {
            return Err(Error::InvalidInput(format!(
                "split_merge must be a number of moves per sweep in [0, {MAX_SPLIT_MERGE_MOVES}], got {}",
                self.split_merge.moves_per_sweep
            )));
        }
        Ok(())
    }
}

/// The training frames, stored flat.
#[derive(Clone, Debug)]
pub struct Data {
    xy: Vec<Point>,
    v: Vec<[f64; 2]>,
    offsets: Vec<usize>,
    /// Each point's previous heading (`NaN`: unknown), or empty: fields over position only.
    h: Vec<f64>,
}

impl Data {
    pub fn new(xy: Vec<Point>, v: Vec<[f64; 2]>, offsets: Vec<usize>) -> Result<Self> {
        if offsets.len() < 2 || offsets[0] != 0 || *offsets.last().unwrap_or(&0) != xy.len() {
            return Err(Error::Shape(
                "offsets must run from 0 to the number of points".into(),
            ));
        }
        if offsets.windows(2).any(|w| w[1] <= w[0]) {
            return Err(Error::Shape(
                "every frame must hold at least one vehicle".into(),
            ));
        }
        if xy.len() != v.len() {
            return Err(Error::Shape(format!(
                "{} positions but {} velocities",
                xy.len(),
                v.len()
            )));
        }
        crate::error::check_finite("positions", xy.as_flattened())?;
        crate::error::check_finite("velocities", v.as_flattened())?;
        Ok(Self {
            xy,
            v,
            offsets,
            h: Vec::new(),
        })
    }

    /// The same frames with each point's previous heading (radians, `NaN` where unknown).
    pub fn with_headings(self, h: Vec<f64>) -> Result<Self> {
        crate::pattern::check_headings("headings", &h, self.xy.len())?;
        if h.len() != self.xy.len() {
            return Err(Error::Shape(format!(
                "{} headings for {} points; give one per point",
                h.len(),
                self.xy.len()
            )));
        }
        Ok(Self { h, ..self })
    }

    /// The points' previous headings, or empty.
    pub fn headings(&self) -> &[f64] {
        &self.h
    }

    pub fn len(&self) -> usize {
        self.offsets.len() - 1
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Every frame's points and velocities, frames one after another.
    pub fn points(&self) -> (&[Point], &[[f64; 2]]) {
        (&self.xy, &self.v)
    }

    /// Where each frame's points start (and, last, their number).
    pub fn offsets(&self) -> &[usize] {
        &self.offsets
    }

    pub fn frame(&self, i: usize) -> FrameRef<'_> {
        let (a, b) = (self.offsets[i], self.offsets[i + 1]);
        FrameRef {
            xy: &self.xy[a..b],
            v: &self.v[a..b],
            h: if self.h.is_empty() {
                &[]
            } else {
                &self.h[a..b]
            },
        }
    }
}

/// Seconds spent per part of the sweep, accumulated over the run.
#[derive(Clone, Copy, Debug, Default)]
pub struct Timings {
    /// Batch re-scoring of every stale (frame, pattern) pair at the start of a sweep.
    pub refresh: f64,
    /// Scores computed frame by frame: the own pattern (leave-one-out) and patterns that changed.
    pub scoring: f64,
    pub moves: f64,
    pub new_pattern: f64,
    pub length_scales: f64,
    pub alpha: f64,
    pub split_merge: f64,
    pub noise: f64,
}

impl Timings {
    /// Each part's name and seconds.
    pub fn parts(&self) -> [(&'static str, f64); 8] {
        [
            ("refresh", self.refresh),
            ("scoring", self.scoring),
            ("moves", self.moves),
            ("new_pattern", self.new_pattern),
            ("length_scales", self.length_scales),
            ("alpha", self.alpha),
            ("split_merge", self.split_merge),
            ("noise", self.noise),
        ]
    }
}

/// How often informed proposals led to an exact evaluation, and how often those were accepted.
#[derive(Clone, Copy, Debug, Default)]
pub struct ProposalStats {
    /// Frames whose proposal differed from their pattern (each costs two exact scores).
    pub proposed: u64,
    pub accepted: u64,
}

/// What one sweep did.
#[derive(Clone, Copy, Debug)]
pub struct SweepStats {
    pub moves: usize,
    pub n_patterns: usize,
    pub alpha: f64,
    pub log_joint: f64,
}

#[derive(Clone, Debug)]
struct Slot {
    pattern: Box<dyn PatternModel>,
    /// Per-cell velocity statistics for the informed proposal.
    cells: Option<CellStats>,
    generation: u32,
    version: u64,
}

/// A pattern as reported outside: its arena slot, stable id, size and length scales.
#[derive(Clone, Copy, Debug)]
pub struct PatternInfo {
    pub slot: usize,
    pub id: u64,
    pub n_frames: usize,
    pub length_scales: LengthScales,
    /// Its noise pair (the chain's pair unless the noise is per pattern).
    pub noise_var: [f64; 2],
}

/// The sampler's state and caches.
#[derive(Clone, Debug)]
pub struct Sampler {
    settings: Settings,
    data: Arc<Data>,
    slots: Vec<Option<Slot>>,
    generations: Vec<u32>,
    labels: Vec<usize>,
    alpha: f64,
    sweep: u64,
    next_version: u64,
    /// `cache[frame][slot] = (pattern version, log p(frame | pattern))`.
    cache: Vec<Vec<(u64, f64)>>,
    /// The cells of the informed proposal's statistics.
    grid: Option<Arc<CellGrid>>,
    pub timings: Timings,
    pub proposals: ProposalStats,
    pub split_merge: SplitMergeStats,
    /// Each frame's mean velocity, for informed split–merge pairs (computed once, on demand).
    frame_means: std::sync::OnceLock<Arc<Vec<[f64; 2]>>>,
    /// Links and ρ under the sticky prior.
    links: Option<sticky::Links>,
}

impl Sampler {
    /// A sampler with every frame unassigned; call [`Sampler::initialize`] next.
    pub fn new(data: Data, settings: Settings) -> Result<Self> {
        Self::new_with_data(Arc::new(data), settings)
    }

    /// [`Sampler::new`] over frames shared with others (the sub-cluster sampler's, say).
    pub fn new_with_data(data: Arc<Data>, mut settings: Settings) -> Result<Self> {
        settings.validate()?;
        settings.resolve_heading(Some(&data))?;
        let n = data.len();
        let alpha = initial_alpha(&settings)?;
        let grid = (settings.proposal == Proposal::Informed).then(|| {
            // Cells of half a typical length scale: the prior mean, or the fixed scales.
            let (a, b) = settings.length_scale_prior;
            let cell = if settings.fixed_length_scales {
                let ls = settings.base.length_scales;
                [0.5 * ls.wx, 0.5 * ls.wy]
            } else {
                [0.5 * a * b; 2]
            };
            Arc::new(CellGrid::new(&data.xy, cell))
        });
        let links = match &settings.dynamics {
            Some(d) => Some(sticky::Links::new(d.clone(), n)?),
            None => None,
        };
        Ok(Self {
            links,
            grid,
            proposals: ProposalStats::default(),
            settings,
            data,
            slots: Vec::new(),
            generations: Vec::new(),
            labels: vec![NONE; n],
            alpha,
            sweep: 0,
            next_version: 1,
            cache: vec![Vec::new(); n],
            timings: Timings::default(),
            split_merge: SplitMergeStats::default(),
            frame_means: std::sync::OnceLock::new(),
        })
    }

    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    pub fn data(&self) -> &Data {
        &self.data
    }

    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    pub fn sweeps_done(&self) -> u64 {
        self.sweep
    }

    /// Set the sweep counter (a resumed chain): the random streams are keyed by
    /// (seed, sweep, phase, entity), so this is the whole position of the random stream.
    pub fn set_sweeps_done(&mut self, sweeps: u64) {
        self.sweep = sweeps;
    }

    fn fresh_version(&mut self) -> u64 {
        self.next_version += 1;
        self.next_version
    }

    fn live(&self) -> impl Iterator<Item = (usize, &Slot)> {
        self.slots
            .iter()
            .enumerate()
            .filter_map(|(k, s)| s.as_ref().map(|s| (k, s)))
    }

    fn add_pattern(&mut self, pattern: Box<dyn PatternModel>) -> usize {
        let version = self.fresh_version();
        let cells = self.grid.as_ref().map(|g| {
            let mut c = CellStats::new(Arc::clone(g));
            for (_, f) in pattern.members() {
                c.add(f, 1.0);
            }
            c
        });
        let k = match self.slots.iter().position(Option::is_none) {
            Some(k) => k,
            None => {
                self.slots.push(None);
                self.generations.push(0);
                self.slots.len() - 1
            }
        };
        self.generations[k] += 1;
        self.slots[k] = Some(Slot {
            pattern,
            cells,
            generation: self.generations[k],
            version,
        });
        k
    }

    /// Slot `k`, which the caller knows to be live (a frame's label or a list of live slots
    /// names it): an internal invariant, not something input can break.
    fn live_slot(&self, k: usize) -> &Slot {
        self.slots[k].as_ref().expect("a live pattern slot")
    }

    fn live_slot_mut(&mut self, k: usize) -> &mut Slot {
        self.slots[k].as_mut().expect("a live pattern slot")
    }

    /// Patterns in slot order.
    pub fn patterns(&self) -> Vec<PatternInfo> {
        self.live()
            .map(|(k, s)| PatternInfo {
                slot: k,
                id: (u64::from(s.generation) << 32) | k as u64,
                n_frames: s.pattern.n_frames(),
                length_scales: s.pattern.length_scales(),
                noise_var: s.pattern.params().noise_var,
            })
            .collect()
    }

    /// The slot of each frame's pattern.
    pub fn labels(&self) -> &[usize] {
        &self.labels
    }

    /// The pattern in `slot`, if any.
    pub fn pattern(&self, slot: usize) -> Option<&dyn PatternModel> {
        self.slots
            .get(slot)
            .and_then(|s| s.as_ref())
            .map(|s| s.pattern.as_ref())
    }

    /// Bytes held by the patterns and the score cache.
    pub fn memory_bytes(&self) -> usize {
        let patterns: usize = self
            .live()
            .map(|(_, s)| s.pattern.bytes() + s.cells.as_ref().map_or(0, CellStats::bytes))
            .sum();
        patterns + 16 * self.data.len() * self.slots.len()
    }

    /// Fail with [`Error::MemoryBudget`] before growing the state by `extra` bytes past the
    /// budget, so that nothing is allocated and the state stays as it was.
    fn check_memory(&self, extra: usize) -> Result<()> {
        let Some(budget) = self.settings.memory_budget else {
            return Ok(());
        };
        let needed = self.memory_bytes() + extra;
        if needed > budget {
            return Err(Error::MemoryBudget {
                needed,
                budget,
                likelihood: self.settings.likelihood.name(),
            });
        }
        Ok(())
    }

    /// Bytes the parallel per-pattern steps (length scales, noise) add: each worker holds up to
    /// two candidate copies of the pattern it updates, and at most the largest patterns are
    /// updated at once, one per worker.
    pub(crate) fn candidate_bytes(&self) -> usize {
        let mut sizes: Vec<usize> = self.live().map(|(_, s)| s.pattern.bytes()).collect();
        sizes.sort_unstable_by(|a, b| b.cmp(a));
        let workers = rayon::current_num_threads();
        2 * sizes.iter().take(workers).sum::<usize>()
    }

    /// Sequential initialisation: frames join one at a time by the same conditional, seeing only
    /// the frames placed before them.
    ///
    /// With informed proposals, only the first [`INIT_SEQUENTIAL`] frames are placed so; each
    /// later frame joins the existing pattern with the best cheap score, and the patterns'
    /// GPs are rebuilt once at the end. Any starting state is valid for the chain, and the
    /// sweeps then correct it (new patterns included), so a large data set starts in seconds.
    pub fn initialize(&mut self, stop: &dyn Fn() -> bool) -> Result<()> {
        let mut placed = 0;
        let mut bulk: Vec<usize> = Vec::new();
        for i in 0..self.data.len() {
            if self.labels[i] != NONE {
                continue;
            }
            if i % 8 == 0 && stop() {
                return Err(Error::Interrupted);
            }
            if self.settings.proposal == Proposal::Informed
                && placed >= INIT_SEQUENTIAL
                && self.live().next().is_some()
            {
                bulk.push(i);
                continue;
            }
            let mut rng = stream(self.settings.seed, 0, Phase::Init, i as u64);
            self.update_frame(i, &mut rng, false)?;
            placed += 1;
        }
        if !bulk.is_empty() {
            self.place_by_cheap_score(&bulk, stop)?;
        }
        Ok(())
    }

    /// Put each frame of `frames` (unassigned, in order) into the existing pattern with the
    /// highest informed proposal probability, updating only the cell statistics on the way,
    /// then rebuild the GP of every pattern that grew from all its members at once.
    fn place_by_cheap_score(&mut self, frames: &[usize], stop: &dyn Fn() -> bool) -> Result<()> {
        let data = Arc::clone(&self.data);
        let mut joined: Vec<Vec<usize>> = vec![Vec::new(); self.slots.len()];
        for (n, &i) in frames.iter().enumerate() {
            if n % 64 == 0 && stop() {
                // Undo the cell statistics of the frames placed so far: they have no GP yet.
                for (k, members) in joined.iter().enumerate() {
                    for &j in members {
                        if let Some(c) = self.live_slot_mut(k).cells.as_mut() {
                            c.add(data.frame(j), -1.0);
                        }
                    }
                }
                return Err(Error::Interrupted);
            }
            let f = data.frame(i);
            let (cands, logq) = self.proposal(f, NONE, None);
            let (best, _) = argmax(&logq[..cands.len()]);
            let k = cands[best];
            if let Some(c) = self.live_slot_mut(k).cells.as_mut() {
                c.add(f, 1.0);
            }
            joined[k].push(i);
        }
        let groups = self.settings.base.groups().len();
        let grown: Vec<usize> = (0..joined.len())
            .filter(|&k| !joined[k].is_empty())
            .collect();
        let mut extra = 0;
        for &k in &grown {
            let p = &self.live_slot(k).pattern;
            let n = p.n_points()
                + joined[k]
                    .iter()
                    .map(|&i| data.frame(i).xy.len())
                    .sum::<usize>();
            extra += self.settings.likelihood.pattern_bytes(n, groups);
        }
        self.check_memory(extra)?;
        let rebuilt: Vec<Result<Box<dyn PatternModel>>> = grown
            .par_iter()
            .map(|&k| {
                let p = &self.live_slot(k).pattern;
                let mut members = p.members();
                members.extend(joined[k].iter().map(|&i| (i, data.frame(i))));
                self.settings.likelihood.pattern(*p.params(), &members)
            })
            .collect();
        for (&k, p) in grown.iter().zip(rebuilt) {
            let p = p?;
            let v = self.fresh_version();
            let slot = self.live_slot_mut(k);
            slot.pattern = p;
            slot.version = v;
            for &i in &joined[k] {
                self.labels[i] = k;
            }
        }
        Ok(())
    }

    /// Set a state directly (a loaded model, or a chosen start): `labels` as group numbers
    /// (any integers; equal numbers share a pattern) and the length scales of each group.
    pub fn set_state(
        &mut self,
        labels: &[usize],
        length_scales: &[LengthScales],
        alpha: f64,
    ) -> Result<()> {
        self.set_state_with_noise(labels, length_scales, None, alpha)
    }

    /// [`Sampler::set_state`] with each group's noise pair (per-pattern noise; `None`: the
    /// chain's pair for every group).
    pub fn set_state_with_noise(
        &mut self,
        labels: &[usize],
        length_scales: &[LengthScales],
        noise_var: Option<&[[f64; 2]]>,
        alpha: f64,
    ) -> Result<()> {
        check_state(self.data.len(), labels, length_scales, noise_var, alpha)?;
        if self.settings.heading_prior.is_some()
            && length_scales
                .iter()
                .any(|ls| !crate::heading::is_headed(ls.wh))
        {
            return Err(Error::InvalidInput(
                "a chain over heading needs each group's heading length scale (w_h); a state \
                 without them is a fit over position only"
                    .into(),
            ));
        }
        self.slots.clear();
        self.generations.clear();
        self.cache = vec![Vec::new(); self.data.len()];
        self.alpha = alpha;
        let data = Arc::clone(&self.data);
        let mut members: Vec<Vec<usize>> = vec![Vec::new(); length_scales.len()];
        for (i, &g) in labels.iter().enumerate() {
            members[g].push(i);
        }
        let groups: Vec<usize> = (0..members.len())
            .filter(|&g| !members[g].is_empty())
            .collect();
        let n_groups = self.settings.base.groups().len();
        let needed: usize = groups
            .iter()
            .map(|&g| {
                let n = members[g].iter().map(|&i| data.frame(i).xy.len()).sum();
                self.settings.likelihood.pattern_bytes(n, n_groups)
            })
            .sum();
        self.check_memory(needed)?;
        // Patterns are built independently (in parallel) and added in group order, so the
        // state is the same whatever the number of threads.
        let floor = self.moment_floor();
        let built: Vec<Result<Box<dyn PatternModel>>> = groups
            .par_iter()
            .map(|&g| {
                let frames: Vec<(usize, FrameRef)> =
                    members[g].iter().map(|&i| (i, data.frame(i))).collect();
                let mut params = self.settings.pattern_params(length_scales[g]);
                if let Some(nv) = noise_var {
                    params.noise_var = nv[g];
                }
                let pattern = self.settings.likelihood.pattern(params, &frames)?;
                if self.settings.pattern_moments
                    && let Some(p) = pattern.with_own_moments(floor)?
                {
                    return Ok(p);
                }
                Ok(pattern)
            })
            .collect();
        for (&g, pattern) in groups.iter().zip(built) {
            let k = self.add_pattern(pattern?);
            for &i in &members[g] {
                self.labels[i] = k;
            }
        }
        self.repair_links();
        Ok(())
    }

    /// One sweep: every frame's assignment, then length scales and α.
    pub fn sweep(&mut self, stop: &dyn Fn() -> bool) -> Result<SweepStats> {
        if self.labels.contains(&NONE) {
            self.initialize(stop)?;
        }
        self.sweep += 1;
        if self.settings.proposal == Proposal::Full {
            // The full conditional needs every pair: score the stale ones in level-3 batches.
            // Informed proposals score pairs on demand instead.
            let t = Instant::now();
            self.refresh_scores()?;
            self.timings.refresh += t.elapsed().as_secs_f64();
        }
        let mut moves = 0;
        for i in 0..self.data.len() {
            if i % 8 == 0 && stop() {
                return Err(Error::Interrupted);
            }
            let mut rng = stream(self.settings.seed, self.sweep, Phase::Assign, i as u64);
            moves += usize::from(self.update_frame(i, &mut rng, true)?);
        }
        if self.links.is_some() {
            let t = Instant::now();
            self.segment_moves()?;
            self.timings.moves += t.elapsed().as_secs_f64();
        }
        if self.settings.split_merge.moves_per_sweep > 0 {
            let t = Instant::now();
            self.split_merge_moves()?;
            self.timings.split_merge += t.elapsed().as_secs_f64();
        }
        if self.settings.noise_prior.is_some() {
            let t = Instant::now();
            self.update_noise()?;
            self.timings.noise += t.elapsed().as_secs_f64();
        }
        if self.settings.pattern_moments {
            let t = Instant::now();
            self.update_moments()?;
            self.timings.length_scales += t.elapsed().as_secs_f64();
        }
        if !self.settings.fixed_length_scales {
            let t = Instant::now();
            self.update_length_scales()?;
            self.timings.length_scales += t.elapsed().as_secs_f64();
        }
        if self.settings.alpha.is_none() {
            let t = Instant::now();
            self.update_alpha();
            self.timings.alpha += t.elapsed().as_secs_f64();
        }
        self.update_rho()?;
        Ok(SweepStats {
            moves,
            n_patterns: self.live().count(),
            alpha: self.alpha,
            log_joint: self.log_joint(),
        })
    }

    /// Score every (frame, pattern) pair whose cached score is stale, frames not in the pattern
    /// only, in blocks of frames per triangular solve, in parallel over (pattern, block).
    fn refresh_scores(&mut self) -> Result<()> {
        let nslots = self.slots.len();
        let mut jobs: Vec<(usize, Vec<usize>)> = Vec::new();
        for (k, s) in self.live() {
            let stale: Vec<usize> = (0..self.data.len())
                .filter(|&i| {
                    self.labels[i] != k && self.cache[i].get(k).is_none_or(|c| c.0 != s.version)
                })
                .collect();
            jobs.extend(stale.chunks(SCORE_BLOCK).map(|c| (k, c.to_vec())));
        }
        let results: Vec<Result<Vec<f64>>> = jobs
            .par_iter()
            .map(|(k, frames)| {
                let p = &self.live_slot(*k).pattern;
                let refs: Vec<FrameRef> = frames.iter().map(|&i| self.data.frame(i)).collect();
                p.score(&refs)
            })
            .collect();
        for ((k, frames), scores) in jobs.iter().zip(results) {
            let version = self.live_slot(*k).version;
            for (&i, s) in frames.iter().zip(scores?) {
                let row = &mut self.cache[i];
                if row.len() < nslots {
                    row.resize(nslots, (0, 0.0));
                }
                row[*k] = (version, s);
            }
        }
        Ok(())
    }

    /// Scores of frame `i` against every live pattern except `skip` (its own), from the cache
    /// where it is current. With `lookahead` (in a sweep), a stale pattern is scored in one batch
    /// against `i` and the next frames of the sweep that will need it too, which turns many
    /// single-frame solves into one level-3 solve; if the pattern changes again before those
    /// frames come, their scores are simply recomputed.
    fn scores_for(
        &mut self,
        i: usize,
        skip: usize,
        only: Option<&[usize]>,
        lookahead: bool,
    ) -> Result<Vec<(usize, f64)>> {
        let data = Arc::clone(&self.data);
        let n = data.len();
        let live: Vec<(usize, u64)> = self
            .live()
            .filter(|(k, _)| *k != skip && only.is_none_or(|o| o.contains(k)))
            .map(|(k, s)| (k, s.version))
            .collect();
        let is_stale = |j: usize, k: usize, v: u64| self.cache[j].get(k).is_none_or(|c| c.0 != v);
        let jobs: Vec<(usize, u64, Vec<usize>)> = live
            .iter()
            .filter(|&&(k, v)| is_stale(i, k, v))
            .map(|&(k, v)| {
                let mut frames = vec![i];
                if lookahead {
                    let next = (i + 1..n).filter(|&j| self.labels[j] != k && is_stale(j, k, v));
                    frames.extend(next.take(SCORE_BLOCK - 1));
                }
                (k, v, frames)
            })
            .collect();
        let results: Vec<Result<Vec<f64>>> = jobs
            .par_iter()
            .map(|(k, _, frames)| {
                let refs: Vec<FrameRef> = frames.iter().map(|&j| data.frame(j)).collect();
                self.live_slot(*k).pattern.score(&refs)
            })
            .collect();
        let nslots = self.slots.len();
        for ((k, version, frames), scores) in jobs.iter().zip(results) {
            for (&j, s) in frames.iter().zip(scores?) {
                let row = &mut self.cache[j];
                if row.len() < nslots {
                    row.resize(nslots, (0, 0.0));
                }
                row[*k] = (*version, s);
            }
        }
        Ok(live.iter().map(|&(k, _)| (k, self.cache[i][k].1)).collect())
    }

    /// Algorithm 8's auxiliary patterns for frame `f`: `(parameters, log weight)` each,
    /// weights `log(α/m) + log N(V_f ; μ, K_ff(w_j) + σ_n² I)`. A frame that was alone in its
    /// pattern brings that pattern's parameters as the first auxiliary. Per-pattern noise: each
    /// auxiliary draws its noise pair from the prior after its length scales.
    fn auxiliaries(
        &self,
        f: FrameRef<'_>,
        own: Option<GpParams>,
        rng: &mut impl rand::Rng,
    ) -> Result<Vec<(GpParams, f64)>> {
        let per_pattern = self.settings.per_pattern_noise();
        if self.settings.fixed_length_scales && !per_pattern {
            return Ok(vec![(
                self.settings.base,
                self.alpha.ln()
                    + self
                        .settings
                        .likelihood
                        .prior_score(f, &self.settings.base)?,
            )]);
        }
        let m = self.settings.new_pattern_samples;
        let fixed = self.settings.fixed_length_scales;
        let draws: Vec<GpParams> = (0..m)
            .map(|j| match (j, own) {
                (0, Some(p)) => Ok(p),
                _ => {
                    let ls = if fixed {
                        self.settings.base.length_scales
                    } else {
                        self.settings.draw_length_scales(rng)?
                    };
                    let noise = self.settings.new_noise(rng);
                    Ok(self.settings.new_params(ls, noise))
                }
            })
            .collect::<Result<_>>()?;
        let log_w0 = (self.alpha / m as f64).ln();
        // The draws come from one stream in order; their scores (a few µs each) are independent,
        // so score them in parallel chunks.
        let scored: Vec<Result<Vec<(GpParams, f64)>>> = draws
            .par_chunks(AUX_CHUNK)
            .map(|chunk| {
                let scores = self.settings.likelihood.prior_scores(f, chunk)?;
                Ok(chunk
                    .iter()
                    .zip(scores)
                    .map(|(&p, s)| (p, log_w0 + s))
                    .collect())
            })
            .collect();
        Ok(scored.into_iter().collect::<Result<Vec<_>>>()?.concat())
    }

    /// Take frame `i` out of pattern `k` (dropping the pattern if it was its only frame).
    fn detach_frame(&mut self, i: usize, k: usize) -> Result<()> {
        let data = Arc::clone(&self.data);
        let slot = self.live_slot_mut(k);
        if slot.pattern.n_frames() == 1 {
            self.slots[k] = None;
        } else {
            slot.pattern.remove(i)?;
            if let Some(c) = slot.cells.as_mut() {
                c.add(data.frame(i), -1.0);
            }
            let v = self.fresh_version();
            self.live_slot_mut(k).version = v;
        }
        self.labels[i] = NONE;
        Ok(())
    }

    /// Move frame `i` from `old` (or nowhere) into the live pattern `k`.
    fn move_frame(&mut self, i: usize, old: usize, k: usize) -> Result<()> {
        let data = Arc::clone(&self.data);
        let f = data.frame(i);
        let p = &self.live_slot(k).pattern;
        self.check_memory(p.bytes_after_insert(f.xy.len()).saturating_sub(p.bytes()))?;
        if old != NONE {
            self.detach_frame(i, old)?;
        }
        let v = self.fresh_version();
        let slot = self.live_slot_mut(k);
        slot.pattern.insert(i, f)?;
        if let Some(c) = slot.cells.as_mut() {
            c.add(f, 1.0);
        }
        slot.version = v;
        self.labels[i] = k;
        Ok(())
    }

    /// Move frame `i` from `old` (or nowhere) into a new pattern with parameters `params`.
    fn move_to_new(&mut self, i: usize, old: usize, params: GpParams) -> Result<()> {
        let data = Arc::clone(&self.data);
        let f = data.frame(i);
        let groups = self.settings.base.groups().len();
        self.check_memory(self.settings.likelihood.pattern_bytes(f.xy.len(), groups))?;
        let pattern = self.settings.likelihood.pattern(params, &[(i, f)])?;
        if old != NONE {
            self.detach_frame(i, old)?;
        }
        let k = self.add_pattern(pattern);
        self.labels[i] = k;
        Ok(())
    }

    /// Reassign frame `i` by its conditional; returns whether the partition changed.
    ///
    /// The frame's own pattern is scored by leave-one-block-out without touching its factor, so
    /// a frame that stays (most of them, after burn-in) costs no factor update at all.
    fn update_frame(
        &mut self,
        i: usize,
        rng: &mut impl rand::Rng,
        lookahead: bool,
    ) -> Result<bool> {
        if self.settings.proposal == Proposal::Full {
            return self.choose_among(i, None, rng, lookahead);
        }
        let old = self.labels[i];
        if old == NONE {
            // Sequential initialisation by the full conditional: the informed step needs a
            // current pattern, and a start close to the posterior saves many sweeps.
            return self.choose_among(i, None, rng, lookahead);
        }
        if self.settings.assignment == Assignment::Gibbs {
            return self.informed_step(i, rng);
        }
        // MAP mode: the exact choice among the patterns the cheap score ranks highest, the
        // frame's own, and a new one.
        let t = Instant::now();
        let f = self.data.frame(i);
        let block = self.block(i);
        let (cands, logq) = self.proposal(f, old, block.as_ref());
        let mut order: Vec<usize> = (0..cands.len()).collect();
        order.sort_by(|&a, &b| logq[b].total_cmp(&logq[a]));
        let mut only: Vec<usize> = order
            .iter()
            .take(INFORMED_CANDIDATES)
            .map(|&j| cands[j])
            .collect();
        if old != NONE && !only.contains(&old) {
            only.push(old);
        }
        self.timings.scoring += t.elapsed().as_secs_f64();
        self.choose_among(i, Some(&only), rng, lookahead)
    }

    /// Draw frame `i`'s pattern from its conditional restricted to the patterns `only` (all
    /// when `None`) and new ones (Algorithm 8), or take the most probable in MAP mode; returns
    /// whether the partition changed.
    ///
    /// The frame's own pattern is scored by leave-one-block-out without touching its factor, so
    /// a frame that stays (most of them, after burn-in) costs no factor update at all.
    fn choose_among(
        &mut self,
        i: usize,
        only: Option<&[usize]>,
        rng: &mut impl rand::Rng,
        lookahead: bool,
    ) -> Result<bool> {
        let data = Arc::clone(&self.data);
        let f = data.frame(i);
        let old = self.labels[i];
        let t = Instant::now();
        let own_ls = self.singleton_params(old);
        let block = self.block(i);
        let own_score = match own_ls {
            Some(_) => None,
            None if old == NONE => None,
            None if only.is_some_and(|o| !o.contains(&old)) => None,
            None => Some(self.own_weight(i, old, block.as_ref())?),
        };
        let mut candidates: Vec<(usize, f64)> = self
            .scores_for(i, old, only, lookahead)?
            .into_iter()
            .map(|(k, s)| {
                let n = self.live_slot(k).pattern.n_frames();
                (k, prior_log(block.as_ref(), k, n) + s)
            })
            .collect();
        if let Some(w) = own_score {
            candidates.push((old, w));
        }
        self.timings.scoring += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let mut aux = self.auxiliaries(f, own_ls, rng)?;
        if block.is_some() {
            let shift = self.new_shift(block.as_ref());
            aux.iter_mut().for_each(|a| a.1 += shift);
        }
        self.timings.new_pattern += t.elapsed().as_secs_f64();

        let mut logw: Vec<f64> = candidates.iter().map(|c| c.1).collect();
        let choice = match self.settings.assignment {
            Assignment::Gibbs => {
                logw.extend(aux.iter().map(|a| a.1));
                sample_log(&logw, rng)
            }
            Assignment::Map => {
                let aux_w: Vec<f64> = aux.iter().map(|a| a.1).collect();
                let (best, best_w) = argmax(&logw);
                if !logw.is_empty() && best_w >= log_sum_exp(&aux_w) {
                    best
                } else {
                    logw.len() + argmax(&aux_w).0
                }
            }
        };

        let t = Instant::now();
        let changed = if choice < candidates.len() {
            let k = candidates[choice].0;
            if k != old {
                self.move_frame(i, old, k)?;
            }
            k != old
        } else {
            let j = choice - candidates.len();
            // A singleton that draws its own length scales (auxiliary 0) keeps its pattern.
            if !(own_ls.is_some() && j == 0) {
                self.move_to_new(i, old, aux[j].0)?;
            }
            own_ls.is_none()
        };
        if let Some(b) = &block {
            let k = candidates.get(choice).map_or(NONE, |c| c.0);
            let mut u = sticky::uniforms(rng);
            let draw: Option<&mut dyn FnMut() -> f64> = match self.settings.assignment {
                Assignment::Gibbs => Some(&mut u),
                Assignment::Map => None,
            };
            self.relink(i, b, k, draw);
        }
        self.timings.moves += t.elapsed().as_secs_f64();
        Ok(changed)
    }

    /// The parameters a new pattern would need to be frame `i`'s pattern `k`, if the frame is
    /// alone in it: `base` with its length scales and noise pair.
    fn singleton_params(&self, k: usize) -> Option<GpParams> {
        self.slots
            .get(k)
            .and_then(|s| s.as_ref())
            .filter(|s| s.pattern.n_frames() == 1)
            .map(|s| {
                self.settings
                    .new_params(s.pattern.length_scales(), s.pattern.params().noise_var)
            })
    }

    /// `log [(n_k − 1) p(V_i | D_k \ i)]` for frame `i` in its own (non-singleton) pattern `k`.
    fn own_weight(&self, i: usize, k: usize, block: Option<&sticky::Block>) -> Result<f64> {
        let p = &self.live_slot(k).pattern;
        let loo = p.loo_score(i)?.unwrap_or(f64::NEG_INFINITY);
        Ok(prior_log(block, k, p.n_frames() - 1) + loo)
    }

    /// `log [n_k p(V_i | D_k)]` for a pattern `k` that does not hold frame `i`, from the cache
    /// when current.
    fn other_weight(&mut self, i: usize, k: usize, block: Option<&sticky::Block>) -> Result<f64> {
        let slot = self.live_slot(k);
        let (version, n) = (slot.version, slot.pattern.n_frames());
        let score = match self.cache[i].get(k) {
            Some(&(v, s)) if v == version => s,
            _ => {
                let s = slot.pattern.score(&[self.data.frame(i)])?[0];
                let row = &mut self.cache[i];
                if row.len() <= k {
                    row.resize(self.slots.len(), (0, 0.0));
                }
                row[k] = (version, s);
                s
            }
        };
        Ok(prior_log(block, k, n) + score)
    }

    /// The informed proposal for frame `f` whose pattern is `old` (or none): the candidate
    /// existing patterns (slots; not `old` if the frame is alone there) and the log proposal
    /// probability of each, then of "new" (last). It depends on the other frames only: the
    /// own pattern is scored with the frame left out.
    fn proposal(
        &self,
        f: FrameRef<'_>,
        old: usize,
        block: Option<&sticky::Block>,
    ) -> (Vec<usize>, Vec<f64>) {
        let grid = self.grid.as_ref().expect("informed proposals have a grid");
        let cells = grid.cells(f.xy);
        let mut cands = Vec::new();
        let mut logq = Vec::new();
        for (k, s) in self.live() {
            let own = k == old;
            let n = s.pattern.n_frames() - usize::from(own);
            if n == 0 {
                continue;
            }
            let cheap = s
                .cells
                .as_ref()
                .map_or(0.0, |c| c.score(f, &cells, own, s.pattern.params()));
            cands.push(k);
            logq.push(prior_log(block, k, n) + TEMPER * cheap);
        }
        let new = self.alpha.ln() + self.new_shift(block);
        logq.push(new + TEMPER * proposal::prior_score(f, &self.settings.base));
        let z = log_sum_exp(&logq);
        let floor = UNIFORM_SHARE / logq.len() as f64;
        let logq = logq
            .iter()
            .map(|w| ((1.0 - UNIFORM_SHARE) * (w - z).exp() + floor).ln())
            .collect();
        (cands, logq)
    }

    /// One Metropolis-within-Gibbs update of frame `i` (which has a pattern): propose from the
    /// cheap informed proposal and accept by the exact conditional. The target is Algorithm 8's
    /// conditional over existing patterns and auxiliary new ones; the proposal picks "new" as a
    /// group and then an auxiliary by its exact weight, so for any state `y`,
    /// `h(y) = log π(y) − log q(y)` is `log π(k) − log q(k)` for an existing pattern and
    /// `log Σ_aux π − log q(new)` for every auxiliary, and a proposal `y` from `x` is accepted
    /// with probability `min(1, exp(h(y) − h(x)))`. The auxiliaries are drawn only when "new"
    /// is the current or the proposed state; a frame proposed to stay costs nothing exact.
    fn informed_step(&mut self, i: usize, rng: &mut impl rand::Rng) -> Result<bool> {
        let data = Arc::clone(&self.data);
        let f = data.frame(i);
        let old = self.labels[i];
        let t = Instant::now();
        let block = self.block(i);
        let (cands, logq) = self.proposal(f, old, block.as_ref());
        let new = cands.len();
        let own_ls = self.singleton_params(old);
        let current = match own_ls {
            Some(_) => new,
            None => cands
                .iter()
                .position(|&k| k == old)
                .expect("a frame's own pattern is a candidate"),
        };
        let pick = sample_log(&logq, rng);
        self.timings.scoring += t.elapsed().as_secs_f64();
        if pick == current && own_ls.is_none() {
            if let Some(b) = &block {
                self.relink(i, b, old, Some(&mut sticky::uniforms(rng)));
            }
            return Ok(false);
        }
        self.proposals.proposed += 1;
        let t = Instant::now();
        let aux = if pick == new || own_ls.is_some() {
            let shift = self.new_shift(block.as_ref());
            let mut a = self.auxiliaries(f, own_ls, rng)?;
            if block.is_some() {
                a.iter_mut().for_each(|x| x.1 += shift);
            }
            let mass = log_sum_exp(&a.iter().map(|x| x.1).collect::<Vec<_>>());
            Some((a, mass))
        } else {
            None
        };
        self.timings.new_pattern += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let h_new = aux.as_ref().map(|a| a.1 - logq[new]);
        let h_current = match h_new {
            Some(h) if current == new => h,
            _ => self.own_weight(i, old, block.as_ref())? - logq[current],
        };
        let h_pick = if pick == new {
            h_new.expect("auxiliaries drawn for a new pattern")
        } else {
            self.other_weight(i, cands[pick], block.as_ref())? - logq[pick]
        };
        self.timings.scoring += t.elapsed().as_secs_f64();
        let log_u = rng.random::<f64>().ln();
        if log_u >= h_pick - h_current {
            if let Some(b) = &block {
                // Rejected: the frame keeps its pattern (a singleton's is "new").
                let k = if own_ls.is_some() { NONE } else { old };
                self.relink(i, b, k, Some(&mut sticky::uniforms(rng)));
            }
            return Ok(false);
        }
        self.proposals.accepted += 1;
        let t = Instant::now();
        let changed = if pick == new {
            let (aux, _) = aux.expect("auxiliaries drawn for a new pattern");
            let j = sample_log(&aux.iter().map(|a| a.1).collect::<Vec<_>>(), rng);
            if !(own_ls.is_some() && j == 0) {
                self.move_to_new(i, old, aux[j].0)?;
            }
            own_ls.is_none()
        } else {
            self.move_frame(i, old, cands[pick])?;
            true
        };
        if let Some(b) = &block {
            let k = if pick == new { NONE } else { cands[pick] };
            self.relink(i, b, k, Some(&mut sticky::uniforms(rng)));
        }
        self.timings.moves += t.elapsed().as_secs_f64();
        Ok(changed)
    }

    /// Floors of the per-pattern signal variances: a thousandth of the global ones.
    fn moment_floor(&self) -> [f64; 2] {
        self.settings.base.signal_var.map(|s| s * 1e-3)
    }

    /// Refit every pattern's signal variances and means to its own velocities (in parallel).
    fn update_moments(&mut self) -> Result<()> {
        let floor = self.moment_floor();
        let slots: Vec<usize> = self.live().map(|(k, _)| k).collect();
        let refit: Vec<Result<Option<Box<dyn PatternModel>>>> = slots
            .par_iter()
            .map(|&k| self.live_slot(k).pattern.with_own_moments(floor))
            .collect();
        for (&k, p) in slots.iter().zip(refit) {
            if let Some(p) = p? {
                let v = self.fresh_version();
                let slot = self.live_slot_mut(k);
                slot.pattern = p;
                slot.version = v;
            }
        }
        Ok(())
    }

    /// Slice-sample (log w_x, log w_y) of every pattern, in parallel over patterns; the factor
    /// at the accepted point becomes the pattern's cached factor.
    fn update_length_scales(&mut self) -> Result<()> {
        let keys: Vec<(usize, u64)> = self.patterns().iter().map(|p| (p.slot, p.id)).collect();
        self.check_memory(self.candidate_bytes())?;
        let sweep = self.sweep;
        let (priors, fraction) = (
            self.settings.length_scale_priors(),
            self.settings.length_scale_fraction,
        );
        let updated: Vec<Box<dyn PatternModel>> = keys
            .par_iter()
            .map(|&(k, id)| {
                let mut rng = stream(self.settings.seed, sweep, Phase::LengthScales, id);
                let current = self.live_slot(k).pattern.clone();
                hyper::length_scale_step(current, &priors, fraction, 0.5, &mut rng)
            })
            .collect();
        for ((k, _), p) in keys.iter().zip(updated) {
            let changed = p.length_scales() != self.live_slot(*k).pattern.length_scales();
            let v = if changed {
                self.fresh_version()
            } else {
                self.live_slot(*k).version
            };
            let slot = self.live_slot_mut(*k);
            slot.pattern = p;
            slot.version = v;
        }
        Ok(())
    }

    /// `log p(α | K, N)` up to a constant, on the log scale (Jacobian included).
    pub(crate) fn alpha_log_target(log_alpha: f64, k: usize, n: usize) -> f64 {
        let a = log_alpha.exp();
        if !(a.is_finite() && a > 0.0) {
            return f64::NEG_INFINITY;
        }
        (k as f64 - 1.5) * log_alpha - 0.5 / a + ln_gamma(a) - ln_gamma(n as f64 + a) + log_alpha
    }

    fn update_alpha(&mut self) {
        // Under the sticky prior the CRP is over the fresh draws only.
        let n = self.fresh_counts().map_or(self.data.len(), |c| c.1);
        let k = self.live().count();
        let mut rng = stream(self.settings.seed, self.sweep, Phase::Alpha, 0);
        self.alpha = alpha_step(self.alpha, k, n, &mut rng);
    }

    /// `log p(z, w, α, V)`: CRP prior, length-scale priors, α's prior (when sampled) and the GP
    /// marginal likelihood of every pattern.
    pub fn log_joint(&self) -> f64 {
        // Under the sticky prior: the CRP over fresh draws, and the links' prior.
        let fresh = self.fresh_counts();
        let n = fresh.as_ref().map_or(self.data.len(), |c| c.1) as f64;
        let a = self.alpha;
        let mut total = ln_gamma(a) - ln_gamma(n + a) + self.links_log_prior();
        if self.settings.alpha.is_none() {
            // InvGamma(1/2, 1/2) density of α.
            total += -0.5 * (2.0 * std::f64::consts::PI).ln() - 1.5 * a.ln() - 0.5 / a;
        }
        total += self.noise_log_prior();
        for (k, s) in self.live() {
            let nk = fresh.as_ref().map_or(s.pattern.n_frames(), |c| c.0[k]);
            total += a.ln() + ln_gamma(nk as f64) + s.pattern.log_marginal();
            if !self.settings.fixed_length_scales {
                total += self
                    .settings
                    .length_scale_log_prior(s.pattern.length_scales());
            }
        }
        total
    }

    /// The normalised conditional of training frame `i` given every other frame's pattern:
    /// one entry per live pattern (slot order; its own pattern scored without it), then "new"
    /// (the total mass of the auxiliary patterns, drawn from the stream of the next sweep).
    pub fn conditional_log_probs(&self, i: usize) -> Result<Vec<f64>> {
        if i >= self.data.len() {
            return Err(Error::InvalidInput(format!(
                "frame {i} out of range for {} frames",
                self.data.len()
            )));
        }
        let f = self.data.frame(i);
        let own = self.labels[i];
        let block = self.block(i);
        let mut logw = Vec::new();
        let mut own_ls = None;
        for (k, s) in self.live() {
            if k == own {
                if s.pattern.n_frames() == 1 {
                    own_ls = self.singleton_params(k);
                    logw.push(f64::NEG_INFINITY);
                    continue;
                }
                // The same leave-one-block-out score the sweep uses.
                let loo = s.pattern.loo_score(i)?.unwrap_or(f64::NEG_INFINITY);
                logw.push(prior_log(block.as_ref(), k, s.pattern.n_frames() - 1) + loo);
            } else {
                let n = s.pattern.n_frames();
                logw.push(prior_log(block.as_ref(), k, n) + s.pattern.score(&[f])?[0]);
            }
        }
        let mut rng = stream(self.settings.seed, self.sweep + 1, Phase::Assign, i as u64);
        let shift = self.new_shift(block.as_ref());
        let aux: Vec<f64> = self
            .auxiliaries(f, own_ls, &mut rng)?
            .iter()
            .map(|a| a.1 + shift)
            .collect();
        logw.push(log_sum_exp(&aux));
        let z = log_sum_exp(&logw);
        Ok(logw.iter().map(|w| w - z).collect())
    }

    /// `log p(V_i | D_k)` of every training frame `i` under every live pattern (rows: frames;
    /// columns: patterns in slot order, as [`Self::conditional_log_probs`]), its own pattern's
    /// without the frame (the sweep's leave-one-out score; `-inf` when the frame is alone in it):
    /// what each frame says about each pattern, without the prior. In parallel over frames; no
    /// random numbers, so the same whatever the thread count.
    pub fn training_log_likelihoods(&self) -> Result<Vec<Vec<f64>>> {
        let live: Vec<(usize, &Slot)> = self.live().collect();
        (0..self.data.len())
            .into_par_iter()
            .map(|i| {
                let f = self.data.frame(i);
                live.iter()
                    .map(|&(k, s)| {
                        if k != self.labels[i] {
                            Ok(s.pattern.score(&[f])?[0])
                        } else if s.pattern.n_frames() == 1 {
                            Ok(f64::NEG_INFINITY)
                        } else {
                            Ok(s.pattern.loo_score(i)?.unwrap_or(f64::NEG_INFINITY))
                        }
                    })
                    .collect()
            })
            .collect()
    }

    /// For frames not in the training set: `log p(V_f | D_k)` for every live pattern (rows:
    /// frames; columns: patterns in slot order) and the new-pattern term `log E_w N(V_f; μ, K(w))`
    /// by `new_pattern_samples` prior draws (deterministic per frame position and seed).
    pub fn score_frames(&self, frames: &[FrameRef<'_>]) -> Result<(Vec<Vec<f64>>, Vec<f64>)> {
        let live: Vec<&Slot> = self.live().map(|(_, s)| s).collect();
        let per_pattern: Vec<Result<Vec<f64>>> =
            live.par_iter().map(|s| s.pattern.score(frames)).collect();
        let cols: Vec<Vec<f64>> = per_pattern.into_iter().collect::<Result<_>>()?;
        let new: Vec<Result<f64>> = frames
            .par_iter()
            .enumerate()
            .map(|(j, f)| {
                let mut rng = stream(self.settings.seed, u64::MAX, Phase::Predict, j as u64);
                let aux = self.auxiliaries(*f, None, &mut rng)?;
                let w: Vec<f64> = aux.iter().map(|a| a.1).collect();
                Ok(log_sum_exp(&w) - self.alpha.ln())
            })
            .collect();
        let new: Vec<f64> = new.into_iter().collect::<Result<_>>()?;
        let rows = (0..frames.len())
            .map(|j| cols.iter().map(|c| c[j]).collect())
            .collect();
        Ok((rows, new))
    }
}

/// A chain's starting α: the fixed one, or a draw from its prior
/// `p(α) ∝ α^{-3/2} e^{-1/(2α)}` (α = 1/χ²₁) kept in [0.1, 10]: only a starting point, α is
/// sampled from then on.
pub(crate) fn initial_alpha(settings: &Settings) -> Result<f64> {
    match settings.alpha {
        Some(a) => Ok(a),
        None => {
            let g = Gamma::new(0.5, 2.0).map_err(|e| Error::InvalidInput(e.to_string()))?;
            let draw: f64 = g.sample(&mut stream(settings.seed, 0, Phase::Alpha, 0));
            Ok((1.0 / draw).clamp(0.1, 10.0))
        }
    }
}

/// [`ALPHA_STEPS`] slice steps of `log α` given `k` patterns over `n` draws from the DP.
pub(crate) fn alpha_step(alpha: f64, k: usize, n: usize, rng: &mut impl rand::Rng) -> f64 {
    // Each step costs O(1): take several so that α tracks K closely from the first sweeps.
    let mut x = alpha.ln();
    let mut fx = Sampler::alpha_log_target(x, k, n);
    for _ in 0..ALPHA_STEPS {
        (x, fx) = slice_step(x, fx, 1.0, rng, |y| Sampler::alpha_log_target(y, k, n));
    }
    x.exp()
}

/// The rules of a state given by hand: a label per frame, length scales (and, given, a noise
/// pair) for every label, and a positive α.
pub(crate) fn check_state(
    n: usize,
    labels: &[usize],
    length_scales: &[LengthScales],
    noise_var: Option<&[[f64; 2]]>,
    alpha: f64,
) -> Result<()> {
    if let Some(nv) = noise_var {
        if nv.len() != length_scales.len() {
            return Err(Error::Shape(format!(
                "{} noise pairs for {} groups",
                nv.len(),
                length_scales.len()
            )));
        }
        if !nv.as_flattened().iter().all(|v| v.is_finite() && *v > 0.0) {
            return Err(Error::InvalidInput(
                "every pattern's noise_var must be two positive variances".into(),
            ));
        }
    }
    if labels.len() != n {
        return Err(Error::Shape(format!(
            "{} labels for {} frames",
            labels.len(),
            n
        )));
    }
    if let Some(&bad) = labels.iter().find(|&&l| l >= length_scales.len()) {
        return Err(Error::Shape(format!(
            "label {bad} has no length scales ({} given)",
            length_scales.len()
        )));
    }
    if !(alpha.is_finite() && alpha > 0.0) {
        return Err(Error::InvalidInput(format!(
            "alpha must be positive, got {alpha}"
        )));
    }
    Ok(())
}

/// `log` of pattern `k`'s prior weight in a frame's conditional: `n` (its other frames) under
/// the DP, the sticky weight with a block.
fn prior_log(block: Option<&sticky::Block>, k: usize, n: usize) -> f64 {
    match block {
        Some(b) => b.log_weight(k),
        None => (n as f64).ln(),
    }
}

fn argmax(v: &[f64]) -> (usize, f64) {
    v.iter()
        .enumerate()
        .fold((0, f64::NEG_INFINITY), |best, (i, &x)| {
            if x > best.1 { (i, x) } else { best }
        })
}

/// Draw an index with probability proportional to `exp(logw)`.
fn sample_log(logw: &[f64], rng: &mut impl rand::Rng) -> usize {
    let m = logw.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let w: Vec<f64> = logw.iter().map(|x| (x - m).exp()).collect();
    let total: f64 = w.iter().sum();
    let mut u = rng.random::<f64>() * total;
    for (i, wi) in w.iter().enumerate() {
        u -= wi;
        if u < 0.0 {
            return i;
        }
    }
    w.iter().rposition(|&x| x > 0.0).unwrap_or(0)
}

#[cfg(test)]
#[path = "tests/gibbs.rs"]
mod tests;

/// The enumeration harness every sampler's exactness tests share.
#[cfg(test)]
pub(crate) mod enumeration {
    pub(crate) use super::noise::tests::{PRIOR as NOISE_PRIOR, enumerated_noise_integrated};
    pub(crate) use super::split_merge::tests::{
        canonical, enumerated, enumerated_by, headed_settings, three_scales_integrated, tiny,
        tiny_headed, tiny_hsgp, tiny_hsgp_headed, tiny_hsgp_headed_coarse, tiny_settings,
    };
}

#[cfg(test)]
#[path = "tests/gibbs_alpha_tests.rs"]
mod alpha_tests;
