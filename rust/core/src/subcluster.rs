//! The parallel sampler of the DP mixture of reduced-rank GP fields: each pattern reduced to the
//! sums of its frames (`hsgp_sums`), every frame assigned in parallel given drawn fields, and
//! whole patterns split and merged by Metropolis–Hastings moves built from sub-patterns
//! (docs/inference.md, "The sub-cluster sampler").
//!
//! **One sweep.**
//! 1. *Instantiate* (`subcluster_pass.rs`): given the labels, draw the mixture weights of the `K`
//!    patterns, `(π_1..π_K, π_rest) ~ Dir(n_1..n_K, α)`, and each pattern's basis weights from
//!    their Gaussian posterior given its sums (one `M x M` factor per output group).
//! 2. *Assign*, in parallel over frames: `p(z_i = k) ∝ π_k Π_j N(v_j; μ + φ(x_j)ᵀ a_k, σ_n,k²)`,
//!    `O(l M)` per frame and pattern by the fused kernel of `field_blocks.rs`, a counter-based
//!    uniform per frame (the same labels for any thread count).
//! 3. *Sum* the statistics of the frames that moved into and out of each pattern.
//! 4. *Split and merge* (`subcluster_moves.rs`), then slice-sample each pattern's length scales
//!    and noise from its sums (`O(M³)`, no pass over the data), then α.
//!
//! **Exact.** Steps 1–2 are a blocked Gibbs step of the augmented target
//! `p(z, θ | V) p(π, a | z, θ, V)`: for labels that keep all `K` patterns (the patterns are the
//! weights' labels), `p(z | π, a) ∝ Π_i π_{z_i} f(V_i | a_{z_i})`, and zero where a pattern would
//! be left empty. So frames are drawn from that product one at a time in frame order, a frame that
//! is the last of its pattern staying where it is: its exact conditional. The draws need no
//! state of other frames, so they are made in parallel beforehand and only the "last frame"
//! bookkeeping runs in order (`O(N)`, integers only; shard by shard, the leader walking only the
//! frames of patterns none of whose frames drew them: `subcluster_stays.rs`). This pass never creates nor empties a
//! pattern; the split–merge moves do, and make the chain ergodic. (The restricted step of Chang &
//! Fisher 2013 lets a pattern empty; it then merges and never splits, which does not keep the
//! posterior: with two frames, `{1}{2} → {12}` has positive probability and its reverse none.)
//! The hyperparameters and α are Gibbs steps of the collapsed target given the partition; the
//! moves are Metropolis–Hastings on it. The instantiated weights live for one pass only.
//!
//! Every random number comes from a stream or a counter-based uniform keyed by (seed, sweep,
//! phase, entity), and every parallel result is reduced in a fixed order, so a run does not depend
//! on the thread count.

use std::sync::{Arc, OnceLock};
use std::time::Instant;

use rand_distr::{Distribution, Gamma};
use rayon::prelude::*;

use crate::basis::Basis;
use crate::error::{Error, Result};
use crate::frame::LengthScales;
use crate::gibbs::{
    Assignment, Data, NoiseScope, PatternInfo, Sampler, SamplerKind, Settings, SplitMergeStats,
    SweepStats,
};
use crate::gp::GpParams;
use crate::hsgp_sums::{Posterior, Sums};
use crate::pattern_model::Likelihood;
use crate::rng::{Phase, stream};
use crate::special::ln_gamma;

#[path = "subcluster_coalesce.rs"]
mod coalesce;
#[path = "subcluster_moves.rs"]
mod moves;
#[path = "subcluster_pass.rs"]
mod pass;
#[path = "subcluster_peel.rs"]
mod peel;
#[path = "subcluster_shard.rs"]
pub mod shard;
#[path = "subcluster_stays.rs"]
pub mod stays;

pub use shard::Store;

/// Where a chain starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Start {
    /// The collapsed sampler's sequential initialisation (Python's default).
    Sequential,
    /// Every frame in one pattern.
    One,
    /// Many patterns: every frame its own up to [`MANY_PATTERNS`] frames, else that many
    /// contiguous blocks of frames.
    Many,
}

/// Patterns of a [`Start::Many`] start.
pub const MANY_PATTERNS: usize = 256;

impl std::str::FromStr for Start {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "sequential" => Ok(Self::Sequential),
            "one" => Ok(Self::One),
            "many" => Ok(Self::Many),
            _ => Err(crate::error::unknown_option(
                "init",
                &["sequential", "one", "many"],
                s,
            )),
        }
    }
}

/// A state as groups, for [`SubclusterSampler::set_state`]: each frame's pattern slot (`slots`)
/// numbered by the patterns' order in `infos`, and each group's length scales and noise pair.
fn as_groups(
    infos: &[PatternInfo],
    slots: &[usize],
) -> (Vec<usize>, Vec<LengthScales>, Vec<[f64; 2]>) {
    let group: std::collections::HashMap<usize, usize> =
        infos.iter().enumerate().map(|(g, p)| (p.slot, g)).collect();
    (
        slots.iter().map(|l| group[l]).collect(),
        infos.iter().map(|p| p.length_scales).collect(),
        infos.iter().map(|p| p.noise_var).collect(),
    )
}

/// Group numbers of a [`Start::One`] or [`Start::Many`] start for `n` frames.
pub fn start_groups(start: Start, n: usize) -> Vec<usize> {
    match start {
        Start::One | Start::Sequential => vec![0; n],
        Start::Many => {
            let k = n.clamp(1, MANY_PATTERNS);
            (0..n).map(|i| i * k / n).collect()
        }
    }
}

/// Seconds spent per part of the sweep, accumulated over the run.
#[derive(Clone, Copy, Debug, Default)]
pub struct Timings {
    /// Drawing the mixture weights and every pattern's basis weights.
    pub fields: f64,
    /// Every frame's label given them (the parallel pass).
    pub assign: f64,
    /// The sums of the frames that moved.
    pub sums: f64,
    pub split_merge: f64,
    pub length_scales: f64,
    pub noise: f64,
    pub alpha: f64,
}

impl Timings {
    /// Each part's name and seconds.
    pub fn parts(&self) -> [(&'static str, f64); 7] {
        [
            ("fields", self.fields),
            ("assign", self.assign),
            ("sums", self.sums),
            ("split_merge", self.split_merge),
            ("length_scales", self.length_scales),
            ("noise", self.noise),
            ("alpha", self.alpha),
        ]
    }
}

/// Peel and absorb moves (`subcluster_peel.rs`) proposed and accepted, accumulated over the run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PeelStats {
    pub peel_proposed: u64,
    pub peel_accepted: u64,
    pub absorb_proposed: u64,
    pub absorb_accepted: u64,
}

/// A pattern: the sums of its frames, its hyperparameters, and its factor at them (on demand).
#[derive(Clone, Debug)]
struct Part {
    sums: Sums,
    params: GpParams,
    generation: u32,
    fit: Option<Fit>,
}

/// A pattern's Gram matrix and its posterior at the pattern's hyperparameters.
#[derive(Clone, Debug)]
struct Fit {
    gram: Arc<Vec<f64>>,
    post: Posterior,
}

/// A pattern's sums factored under some hyperparameters: what the hyperparameter steps refit.
struct Candidate<'a> {
    basis: &'a Basis,
    sums: &'a Sums,
    fit: Fit,
}

impl crate::gibbs::Refit for Candidate<'_> {
    fn params(&self) -> &GpParams {
        &self.fit.post.params
    }
    fn log_marginal(&self) -> f64 {
        self.fit.post.log_marginal
    }
    fn n_points(&self) -> usize {
        self.sums.vecs.n_points
    }
    fn refit(&self, params: GpParams) -> Result<Self> {
        let post = self
            .fit
            .post
            .refit(self.basis, self.sums, &self.fit.gram, params)?;
        Ok(Self {
            fit: Fit {
                gram: Arc::clone(&self.fit.gram),
                post,
            },
            ..*self
        })
    }
}

/// The sub-cluster sampler's state.
#[derive(Clone, Debug)]
pub struct SubclusterSampler {
    settings: Settings,
    /// The frames: in this process, or in shards served elsewhere (`subcluster_shard.rs`).
    store: Store,
    basis: Arc<Basis>,
    /// The basis's lower half of frequencies per axis, for the launches' sub-fields.
    coarse: Arc<Basis>,
    slots: Vec<Option<Part>>,
    generations: Vec<u32>,
    /// Each frame's slot, when the leader holds the labels (empty when the shards hold them).
    labels: Vec<usize>,
    /// The chain's number on the shards when they hold its labels (`subcluster_held.rs`): every
    /// step that selects frames by label is then a request the shards answer.
    held: Option<u64>,
    alpha: f64,
    sweep: u64,
    pub timings: Timings,
    pub split_merge: SplitMergeStats,
    pub peels: PeelStats,
    /// Each frame's mean velocity, for informed split–merge pairs (computed once, on demand).
    frame_means: OnceLock<Arc<Vec<[f64; 2]>>>,
    /// Tests: leave the proposal probability out of the split–merge ratio (a wrong chain).
    #[cfg(test)]
    pub(crate) wrong_ratio: bool,
    /// Tests: the peel and absorb moves without split–merge moves.
    #[cfg(test)]
    pub(crate) only_peel: bool,
}

const NONE: usize = usize::MAX;

impl SubclusterSampler {
    /// A sampler with every frame unassigned; call [`SubclusterSampler::initialize`] next.
    pub fn new(data: Arc<Data>, settings: Settings) -> Result<Self> {
        Self::with_store(Store::local(data), settings)
    }

    /// A sampler over frames held by `store` (this process's, or shards served elsewhere).
    pub fn with_store(store: Store, mut settings: Settings) -> Result<Self> {
        settings.validate()?;
        settings.resolve_heading(store.data().map(|d| &**d))?;
        let Likelihood::Hsgp(basis) = &settings.likelihood else {
            unreachable!("validate() refuses the sub-cluster sampler without a basis");
        };
        let basis = Arc::clone(basis);
        let [mx, my] = basis.counts();
        let [hx, hy] = basis.heading_counts();
        let half = [mx.div_ceil(2), my.div_ceil(2)];
        let coarse = Arc::new(
            Basis::new(basis.center(), basis.half_widths(), half)?
                .with_heading(basis.harmonics(), [hx.min(half[0]), hy.min(half[1])])?,
        );
        // The same starting α as the collapsed sampler (the same stream).
        let alpha = crate::gibbs::initial_alpha(&settings)?;
        let n = store.len();
        Ok(Self {
            settings,
            store,
            basis,
            coarse,
            slots: Vec::new(),
            generations: Vec::new(),
            labels: vec![NONE; n],
            held: None,
            alpha,
            sweep: 0,
            timings: Timings::default(),
            split_merge: SplitMergeStats::default(),
            peels: PeelStats::default(),
            frame_means: OnceLock::new(),
            #[cfg(test)]
            wrong_ratio: false,
            #[cfg(test)]
            only_peel: false,
        })
    }

    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// The frames, when they are all in this process (not a sharded chain).
    pub fn data(&self) -> Option<&Arc<Data>> {
        self.store.data()
    }

    /// The frames' store.
    pub fn store(&self) -> &Store {
        &self.store
    }

    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    pub fn sweeps_done(&self) -> u64 {
        self.sweep
    }

    pub fn set_sweeps_done(&mut self, sweeps: u64) {
        self.sweep = sweeps;
    }

    /// The slot of each frame's pattern, when the leader holds the labels (empty when the
    /// shards hold them: [`Self::gather_labels`]).
    pub fn labels(&self) -> &[usize] {
        &self.labels
    }

    /// The slot of each frame's pattern, wherever the labels are (gathered from the shards when
    /// they hold them).
    pub fn gather_labels(&self) -> Result<Vec<usize>> {
        match self.held {
            Some(chain) => self.store.held_labels(chain),
            None => Ok(self.labels.clone()),
        }
    }

    /// The chain's number on the shards when they hold its labels.
    pub fn held_chain(&self) -> Option<u64> {
        self.held
    }

    /// Leave the frames' labels with the shards that hold the frames: from now on the pass, the
    /// moves and the rebuilds send requests that the shards answer from their labels, and the
    /// leader keeps only the patterns' sums (the same chain, bitwise). Each state set afterwards
    /// gets a fresh chain number, so that labels a replaced worker held can never be used again.
    pub fn hold_labels_on_shards(&mut self) -> Result<()> {
        if self.held.is_some() {
            return Ok(());
        }
        let chain = shard::fresh_chain_id();
        if self.is_initialized() {
            self.store.set_held_labels(chain, &self.labels)?;
        }
        self.labels = Vec::new();
        self.held = Some(chain);
        Ok(())
    }

    /// Counts of (label at the last mark, label now) over every frame, increasing, when the
    /// shards hold the labels (`None` otherwise); the shards then mark their labels. The mark is
    /// set with the labels and at each call: the previous sweep's labels, for its ARI.
    pub fn label_table(&self) -> Result<Option<Vec<[u64; 3]>>> {
        self.held.map(|c| self.store.held_table(c)).transpose()
    }

    /// Whether every frame has a pattern.
    fn is_initialized(&self) -> bool {
        match self.held {
            Some(_) => self.live().next().is_some(),
            None => !self.labels.contains(&NONE),
        }
    }

    fn live(&self) -> impl Iterator<Item = (usize, &Part)> {
        self.slots
            .iter()
            .enumerate()
            .filter_map(|(k, s)| s.as_ref().map(|s| (k, s)))
    }

    fn part(&self, k: usize) -> &Part {
        self.slots[k].as_ref().expect("a live pattern slot")
    }

    fn part_mut(&mut self, k: usize) -> &mut Part {
        self.slots[k].as_mut().expect("a live pattern slot")
    }

    /// Frames whose sums are `s` moved from pattern `from` to `to` (both fits to redo).
    fn move_sums(&mut self, from: usize, to: usize, s: &Sums) {
        let dest = self.part_mut(to);
        dest.sums.add(s);
        dest.fit = None;
        let src = self.part_mut(from);
        src.sums.sub(s);
        src.fit = None;
    }

    fn id(&self, k: usize) -> u64 {
        (u64::from(self.part(k).generation) << 32) | k as u64
    }

    /// Patterns in slot order.
    pub fn patterns(&self) -> Vec<PatternInfo> {
        self.live()
            .map(|(k, p)| PatternInfo {
                slot: k,
                id: (u64::from(p.generation) << 32) | k as u64,
                n_frames: p.sums.n_frames,
                length_scales: p.params.length_scales,
                noise_var: p.params.noise_var,
            })
            .collect()
    }

    /// The noise pair the chain is at (per pattern: the pair it started at).
    pub fn noise_var(&self) -> [f64; 2] {
        self.settings.base.noise_var
    }

    /// Put the chain at the noise pair `noise` (a resumed chain): the chain's pair, and every
    /// pattern's when the noise is one for all.
    pub fn set_noise_var(&mut self, noise: [f64; 2]) -> Result<()> {
        crate::gibbs::check_noise_pair(noise)?;
        self.settings.base.noise_var = noise;
        if self.settings.noise_scope == NoiseScope::Global {
            for p in self.slots.iter_mut().flatten() {
                p.params.noise_var = noise;
                p.fit = None;
            }
        }
        self.refresh_fits()
    }

    /// Bytes held by the patterns' sums and cached factors.
    pub fn memory_bytes(&self) -> usize {
        let m = self.basis.len();
        let sums = 8 * (self.live().next().map_or(0, |(_, p)| p.sums.h.len()) + 3 * m);
        let factor = 8 * m * m * (1 + self.settings.base.groups().len());
        self.live().count() * (sums + factor) + 8 * self.labels.len()
    }

    fn check_memory(&self, extra: usize) -> Result<()> {
        let Some(budget) = self.settings.memory_budget else {
            return Ok(());
        };
        let needed = self.memory_bytes() + extra;
        if needed > budget {
            return Err(Error::MemoryBudget {
                needed,
                budget,
                likelihood: "hsgp",
            });
        }
        Ok(())
    }

    fn add_part(&mut self, sums: Sums, params: GpParams, fit: Option<Fit>) -> usize {
        let k = match self.slots.iter().position(Option::is_none) {
            Some(k) => k,
            None => {
                self.slots.push(None);
                self.generations.push(0);
                self.slots.len() - 1
            }
        };
        self.generations[k] += 1;
        self.slots[k] = Some(Part {
            sums,
            params,
            generation: self.generations[k],
            fit,
        });
        k
    }

    /// Pattern `k`'s Gram matrix and posterior at its hyperparameters, computed if stale.
    fn fit_of(&self, k: usize) -> Result<Fit> {
        let p = self.part(k);
        if let Some(f) = &p.fit {
            return Ok(f.clone());
        }
        let gram = Arc::new(p.sums.gram(&self.basis));
        let post = Posterior::new(&self.basis, &p.sums, &gram, p.params)?;
        Ok(Fit { gram, post })
    }

    /// Factor every pattern whose cached fit is stale (in parallel).
    fn refresh_fits(&mut self) -> Result<()> {
        let stale: Vec<usize> = self
            .live()
            .filter(|(_, p)| p.fit.is_none())
            .map(|(k, _)| k)
            .collect();
        let fits: Vec<Result<Fit>> = stale.par_iter().map(|&k| self.fit_of(k)).collect();
        for (&k, f) in stale.iter().zip(fits) {
            self.part_mut(k).fit = Some(f?);
        }
        Ok(())
    }

    /// Where a chain starts: the collapsed sampler's sequential initialisation, or one or many
    /// patterns ([`Start`]). Frames already assigned (a state that was set) keep their labels.
    pub fn initialize(&mut self, start: Start, stop: &dyn Fn() -> bool) -> Result<()> {
        if self.is_initialized() {
            return Ok(());
        }
        let n = self.store.len();
        match start {
            Start::Sequential => self.initialize_sequential(stop),
            Start::One | Start::Many => {
                let groups = start_groups(start, n);
                let k = groups.iter().max().map_or(0, |g| g + 1);
                let ls = vec![self.settings.base.length_scales; k];
                self.set_state(&groups, &ls, None, self.alpha)
            }
        }
    }

    /// The collapsed sampler's sequential initialisation of the first
    /// [`INIT_SEQUENTIAL`](crate::gibbs::INIT_SEQUENTIAL) frames (all of them, when fewer), then
    /// every later frame drawn (map: placed) by the instantiated conditional over those patterns,
    /// in parallel: the collapsed sampler would place them by cheap score and build a pattern
    /// holding a copy of every point, which on a million frames is most of the memory.
    fn initialize_sequential(&mut self, stop: &dyn Fn() -> bool) -> Result<()> {
        if self.basis.harmonics() > 0 {
            return self.initialize_over_position(stop);
        }
        let n = self.store.len();
        let n0 = n.min(crate::gibbs::INIT_SEQUENTIAL);
        let first = match self.store.data() {
            Some(d) if n0 == n => Arc::clone(d),
            _ => Arc::new(self.store.frames(&(0..n0).collect::<Vec<_>>())?),
        };
        let settings = Settings {
            sampler: SamplerKind::Collapsed,
            ..self.settings.clone()
        };
        let mut s = Sampler::new_with_data(first, settings)?;
        s.initialize(stop)?;
        let (mut labels, ls, noise) = as_groups(&s.patterns(), s.labels());
        drop(s);
        if n0 < n {
            let later = self.place_later(&labels, &ls, &noise, stop)?;
            labels.extend(later);
        }
        self.set_state(&labels, &ls, Some(&noise), self.alpha)?;
        self.coalesce(stop)
    }

    /// Fields over heading start from the start of fields over position on the same position
    /// basis (the sequential initialisation, the placement of later frames and the coarsened
    /// start), each pattern at the starting heading length scale. The collapsed sampler's moves
    /// over the heading basis cost `(2J + 1)²` times the position ones (its factors are `M x M`),
    /// and the coarsened start one factorisation per pair of patterns; over position both are
    /// what a position fit pays. Where a chain starts, not a step of it: no effect on the target.
    fn initialize_over_position(&mut self, stop: &dyn Fn() -> bool) -> Result<()> {
        let [mx, my] = self.basis.counts();
        let position = Basis::new(self.basis.center(), self.basis.half_widths(), [mx, my])?;
        let wh = self.settings.base.length_scales.wh;
        let mut settings = self.settings.clone();
        settings.likelihood = Likelihood::Hsgp(Arc::new(position));
        settings.heading_prior = None;
        settings.base = settings.base.with_length_scales(LengthScales {
            wh: f64::INFINITY,
            ..settings.base.length_scales
        });
        let mut start = Self::with_store(self.store.clone(), settings)?;
        start.alpha = self.alpha;
        start.initialize_sequential(stop)?;
        let (labels, mut ls, noise) = as_groups(&start.patterns(), &start.gather_labels()?);
        for l in &mut ls {
            l.wh = wh;
        }
        let alpha = start.alpha;
        drop(start);
        self.set_state(&labels, &ls, Some(&noise), alpha)
    }

    /// Set a state directly: `labels` as group numbers (equal numbers share a pattern), each
    /// group's length scales and (per-pattern noise) noise pair, and α. The sums are built from
    /// the frames, in parallel.
    pub fn set_state(
        &mut self,
        labels: &[usize],
        length_scales: &[LengthScales],
        noise_var: Option<&[[f64; 2]]>,
        alpha: f64,
    ) -> Result<()> {
        crate::gibbs::check_state(self.store.len(), labels, length_scales, noise_var, alpha)?;
        // The non-empty groups, numbered in order; each frame's number among them.
        let mut size = vec![0usize; length_scales.len()];
        for &g in labels {
            size[g] += 1;
        }
        let groups: Vec<usize> = (0..size.len()).filter(|&g| size[g] > 0).collect();
        let mut index = vec![usize::MAX; size.len()];
        for (j, &g) in groups.iter().enumerate() {
            index[g] = j;
        }
        let m = self.basis.len();
        self.slots.clear();
        self.generations.clear();
        self.check_memory(groups.len() * 8 * (m * m * 3 + 8 * m))?;
        let sums = match self.held {
            // The shards take the labels (group `j` is slot `j` below) and sum them: a fresh chain
            // number, the last one's labels dropped.
            Some(old) => {
                let chain = shard::fresh_chain_id();
                let slots: Vec<usize> = labels.iter().map(|&g| index[g]).collect();
                self.store.set_held_labels(chain, &slots)?;
                drop(slots);
                let identity: Vec<usize> = (0..groups.len()).collect();
                let sums = self
                    .store
                    .held_regroup(chain, &self.basis, &identity, groups.len())?;
                self.held = Some(chain);
                // A shard that cannot drop them (a lost worker) has lost them already.
                let _ = self.store.forget_held(old);
                sums
            }
            None => self
                .store
                .sums_of_groups(&self.basis, labels, &index, groups.len())?,
        };
        self.alpha = alpha;
        let mut slot = Vec::with_capacity(groups.len());
        for (&g, s) in groups.iter().zip(sums) {
            let mut params = self.settings.pattern_params(length_scales[g]);
            if let Some(nv) = noise_var {
                params.noise_var = nv[g];
            }
            slot.push(self.add_part(s, params, None));
        }
        if self.held.is_none() {
            // In place: a second label vector would be the largest transient of a rebuild.
            self.labels.clear();
            self.labels.extend(labels.iter().map(|&g| slot[index[g]]));
        }
        self.refresh_fits()
    }

    /// [`Self::set_state`] with every frame in group `group[slot]` of its pattern's slot (a
    /// fit's canonical rebuild): when the shards hold the labels, they relabel their frames and
    /// sum them, and no label crosses. `group` maps every live slot.
    pub fn regroup(
        &mut self,
        group: &[usize],
        length_scales: &[LengthScales],
        noise_var: Option<&[[f64; 2]]>,
        alpha: f64,
    ) -> Result<()> {
        let live: Vec<(usize, usize)> = self.live().map(|(k, p)| (k, p.sums.n_frames)).collect();
        if let Some(&(k, _)) = live
            .iter()
            .find(|(k, _)| group.get(*k).is_none_or(|&g| g >= length_scales.len()))
        {
            return Err(Error::InvalidInput(format!(
                "a regrouping gives pattern slot {k} no group of the {} given",
                length_scales.len()
            )));
        }
        let Some(chain) = self.held else {
            let labels: Vec<usize> = self.labels.iter().map(|&l| group[l]).collect();
            return self.set_state(&labels, length_scales, noise_var, alpha);
        };
        // The checks of `set_state` but the labels' (the shards hold them).
        crate::gibbs::check_state(0, &[], length_scales, noise_var, alpha)?;
        // As `set_state`: the non-empty groups in order, group `j` in slot `j`.
        let mut size = vec![0usize; length_scales.len()];
        for &(k, n) in &live {
            size[group[k]] += n;
        }
        let groups: Vec<usize> = (0..size.len()).filter(|&g| size[g] > 0).collect();
        let mut index = vec![usize::MAX; size.len()];
        for (j, &g) in groups.iter().enumerate() {
            index[g] = j;
        }
        let mut map = vec![usize::MAX; self.slots.len()];
        for &(k, _) in &live {
            map[k] = index[group[k]];
        }
        let m = self.basis.len();
        self.slots.clear();
        self.generations.clear();
        self.check_memory(groups.len() * 8 * (m * m * 3 + 8 * m))?;
        let sums = self
            .store
            .held_regroup(chain, &self.basis, &map, groups.len())?;
        self.alpha = alpha;
        for (&g, s) in groups.iter().zip(sums) {
            let mut params = self.settings.pattern_params(length_scales[g]);
            if let Some(nv) = noise_var {
                params.noise_var = nv[g];
            }
            self.add_part(s, params, None);
        }
        self.refresh_fits()
    }

    /// The sums of each set of frames (each in frame order): in parallel over fixed chunks of
    /// frames added in chunk order, shards added in shard order (the same numbers for any thread
    /// count).
    fn sums_of_sets(&self, sets: &[&[usize]]) -> Result<Vec<Sums>> {
        self.store.sums_of_sets(&self.basis, sets)
    }

    /// One sweep: the parallel assignment pass, split–merge moves, the noise, the length scales
    /// and α.
    pub fn sweep(&mut self, stop: &dyn Fn() -> bool) -> Result<SweepStats> {
        if !self.is_initialized() {
            self.initialize(Start::Sequential, stop)?;
        }
        if stop() {
            return Err(Error::Interrupted);
        }
        self.sweep += 1;
        let moved = self.assignment_pass(stop)?;
        if self.settings.split_merge.moves_per_sweep > 0 {
            let t = Instant::now();
            self.peel_absorb_moves()?;
            #[cfg(test)]
            let skip = self.only_peel;
            #[cfg(not(test))]
            let skip = false;
            if !skip {
                self.split_merge_moves(stop)?;
            }
            self.timings.split_merge += t.elapsed().as_secs_f64();
        }
        if self.settings.noise_prior.is_some() {
            let t = Instant::now();
            self.update_noise()?;
            self.timings.noise += t.elapsed().as_secs_f64();
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
        self.refresh_fits()?;
        Ok(SweepStats {
            moves: moved,
            n_patterns: self.live().count(),
            alpha: self.alpha,
            log_joint: self.log_joint(),
        })
    }

    /// Slice-sample every pattern's (log w_x, log w_y) from its sums, in parallel over patterns,
    /// each on the stream of its stable id (as the collapsed sampler does).
    fn update_length_scales(&mut self) -> Result<()> {
        self.refresh_fits()?;
        let keys: Vec<(usize, u64)> = self.live().map(|(k, _)| (k, self.id(k))).collect();
        let (priors, fraction) = (
            self.settings.length_scale_priors(),
            self.settings.length_scale_fraction,
        );
        let updated: Vec<Fit> = keys
            .par_iter()
            .map(|&(k, id)| {
                let mut rng = stream(self.settings.seed, self.sweep, Phase::LengthScales, id);
                let c = self.candidate(k);
                let width = crate::gibbs::length_scale_width(c.sums.vecs.n_points);
                crate::gibbs::length_scale_step(c, &priors, fraction, width, &mut rng).fit
            })
            .collect();
        for ((k, _), fit) in keys.iter().zip(updated) {
            self.install_fit(*k, fit);
        }
        Ok(())
    }

    fn candidate(&self, k: usize) -> Candidate<'_> {
        let p = self.part(k);
        Candidate {
            basis: &self.basis,
            sums: &p.sums,
            fit: p
                .fit
                .clone()
                .expect("fits refreshed before a hyperparameter step"),
        }
    }

    fn install_fit(&mut self, k: usize, fit: Fit) {
        let p = self.part_mut(k);
        p.params = fit.post.params;
        p.fit = Some(fit);
    }

    /// Slice-sample the noise: each pattern's pair from its sums (per pattern), or the chain's
    /// pair (global), every pattern refactored per candidate.
    fn update_noise(&mut self) -> Result<()> {
        let Some(prior) = self.settings.noise_prior else {
            return Ok(());
        };
        self.refresh_fits()?;
        let scale = self.settings.base.signal_var;
        if self.settings.noise_scope == NoiseScope::PerPattern {
            let keys: Vec<(usize, u64)> = self.live().map(|(k, _)| (k, self.id(k))).collect();
            let updated: Vec<Result<Option<Fit>>> = keys
                .par_iter()
                .map(|&(k, id)| {
                    let mut rng = stream(self.settings.seed, self.sweep, Phase::Noise, id);
                    let c = self.candidate(k);
                    Ok(crate::gibbs::noise_step(&c, prior, scale, &mut rng)?.map(|c| c.fit))
                })
                .collect();
            for ((k, _), fit) in keys.iter().zip(updated) {
                if let Some(fit) = fit? {
                    self.install_fit(*k, fit);
                }
            }
            return Ok(());
        }
        self.update_global_noise(prior, scale)
    }

    /// One noise pair for every pattern: slice-sample `log σ_n,x²` then `log σ_n,y²`, each
    /// candidate refactoring every pattern (in parallel).
    fn update_global_noise(
        &mut self,
        prior: crate::gibbs::NoisePrior,
        scale: [f64; 2],
    ) -> Result<()> {
        let slots: Vec<usize> = self.live().map(|(k, _)| k).collect();
        let mut rng = stream(self.settings.seed, self.sweep, Phase::Noise, 0);
        let points: usize = self.live().map(|(_, p)| p.sums.vecs.n_points).sum();
        for d in 0..2 {
            let noise0 = self.settings.base.noise_var;
            let x0 = noise0[d].ln();
            let data_term: f64 = slots.iter().map(|&k| self.log_marginal_of(k)).sum();
            let f0 = prior.log_density(x0, scale[d]) + data_term;
            let refit = |x: f64| -> Result<Vec<Fit>> {
                slots
                    .par_iter()
                    .map(|&k| {
                        let p = self.part(k);
                        let mut params = p.params;
                        params.noise_var[d] = x.exp();
                        let fit = p.fit.as_ref().expect("fits refreshed");
                        let post = Posterior::new(&self.basis, &p.sums, &fit.gram, params)?;
                        Ok(Fit {
                            gram: Arc::clone(&fit.gram),
                            post,
                        })
                    })
                    .collect()
            };
            let step =
                crate::gibbs::global_noise_step(x0, f0, points, prior, scale[d], &mut rng, |x| {
                    let fits = refit(x)?;
                    Ok((fits.iter().map(|f| f.post.log_marginal).sum(), fits))
                })?;
            let Some((x, fits)) = step else {
                continue;
            };
            self.settings.base.noise_var[d] = x.exp();
            for (&k, fit) in slots.iter().zip(fits) {
                self.install_fit(k, fit);
            }
        }
        Ok(())
    }

    fn log_marginal_of(&self, k: usize) -> f64 {
        match &self.part(k).fit {
            Some(f) => f.post.log_marginal,
            None => self
                .fit_of(k)
                .map_or(f64::NEG_INFINITY, |f| f.post.log_marginal),
        }
    }

    fn update_alpha(&mut self) {
        let n = self.store.len();
        let k = self.live().count();
        let mut rng = stream(self.settings.seed, self.sweep, Phase::Alpha, 0);
        self.alpha = crate::gibbs::alpha_step(self.alpha, k, n, &mut rng);
    }

    /// `log p(z, w, α, V)`: the collapsed sampler's log joint (CRP, priors of the length scales,
    /// of α and of the noise, and every pattern's marginal likelihood), from the sums.
    pub fn log_joint(&self) -> f64 {
        let n = self.store.len() as f64;
        let a = self.alpha;
        let mut total = ln_gamma(a) - ln_gamma(n + a);
        if self.settings.alpha.is_none() {
            total += -0.5 * (2.0 * std::f64::consts::PI).ln() - 1.5 * a.ln() - 0.5 / a;
        }
        if self.settings.noise_scope == NoiseScope::Global {
            total += self.noise_log_prior(self.settings.base.noise_var);
        }
        for (k, p) in self.live() {
            total += self.pattern_term(p.sums.n_frames, &p.params, self.log_marginal_of(k));
        }
        total
    }

    /// A pattern's terms of [`Self::log_joint`]: `log α + log Γ(n)`, its marginal likelihood
    /// `log_marginal`, the priors of its length scales and (per-pattern noise) of its noise.
    fn pattern_term(&self, n: usize, params: &GpParams, log_marginal: f64) -> f64 {
        let mut t = self.alpha.ln() + ln_gamma(n as f64) + log_marginal;
        if !self.settings.fixed_length_scales {
            t += self.settings.length_scale_log_prior(params.length_scales);
        }
        if self.settings.noise_scope == NoiseScope::PerPattern {
            t += self.noise_log_prior(params.noise_var);
        }
        t
    }

    /// The noise prior's log density at a pair (0 when the noise is fixed).
    fn noise_log_prior(&self, nv: [f64; 2]) -> f64 {
        let Some(prior) = self.settings.noise_prior else {
            return 0.0;
        };
        let scale = self.settings.base.signal_var;
        (0..2)
            .map(|d| prior.log_density(nv[d].ln(), scale[d]))
            .sum()
    }

    fn frame_means(&self) -> Result<Arc<Vec<[f64; 2]>>> {
        if let Some(m) = self.frame_means.get() {
            return Ok(Arc::clone(m));
        }
        let m = Arc::new(self.store.means()?);
        Ok(Arc::clone(self.frame_means.get_or_init(|| m)))
    }

    /// Whether labels are drawn (Gibbs) or taken at the mode (map).
    fn map(&self) -> bool {
        self.settings.assignment == Assignment::Map
    }
}

/// A Gamma(shape, 1) draw.
fn gamma(shape: f64, rng: &mut impl rand::Rng) -> Result<f64> {
    let g = Gamma::new(shape, 1.0).map_err(|e| Error::InvalidInput(e.to_string()))?;
    Ok(g.sample(rng))
}

#[cfg(test)]
#[path = "tests/subcluster.rs"]
mod tests;
