//! Split–merge moves of whole patterns, interleaved with the single-frame Gibbs sweep.
//!
//! Single-frame moves split and merge patterns slowly: to move half of a pattern elsewhere,
//! every frame must first pass through a state of lower probability. These moves propose a
//! whole split or merge at once and accept it by an exact Metropolis–Hastings ratio.
//!
//! **Variant: sequentially-allocated merge–split (SAMS; Dahl & Newcomb 2022).** Two frames
//! `i ≠ j` are chosen. If they share a pattern `S`, a split is proposed: `i` and `j` seed two
//! patterns and the other frames of `S`, in random order, join one of them with probability
//! `∝ n_a p(V_f | D_a)` — the collapsed predictive every pattern already computes by the
//! append trial (exact) or a rank-l update of its sums (hsgp), given the frames allocated so
//! far. If they are in different patterns, the merge is proposed, and its reverse split is
//! replayed along the same kind of random order to give the proposal probability. We chose
//! SAMS over restricted-Gibbs split–merge (Jain & Neal 2004, 2007): restricted Gibbs needs
//! several intermediate Gibbs scans of the launch state per move (each a full pass over both
//! patterns with rank-l removals and insertions), while SAMS allocates each frame once; with a
//! pattern's predictive costing `n² l` in the exact GP, one pass is already the cost of the
//! move, and Dahl & Newcomb report SAMS mixing at least as well per unit of time.
//!
//! **Hyperparameters during a move.** The pattern keeping frame `i` keeps the length scales
//! (and, per pattern, the noise pair) it had: the split pattern's, or `i`'s pattern's in a
//! merge. The other split pattern draws its own, `θ_b`, before the allocation, from an even
//! mixture of their prior `p` (as Jain & Neal do for non-conjugate parameters) and a log-normal
//! `L` around the split pattern's `θ_S` (sd [`LOCAL_LS_SD`] per log length scale,
//! [`LOCAL_NOISE_SD`] per log noise variance). A prior draw alone is mostly useless for a
//! pattern of many frames: the noise prior spans orders of magnitude and the length-scale prior
//! has one mean for both axes, so almost every split was rejected for its new pattern's
//! parameters, not its frames. With `q = ½ p + ½ L(· | θ_S)` the ratio of a split is
//!
//! `α Γ(n_a) Γ(n_b) / Γ(n_S) · p(D_a | θ_S) p(D_b | θ_b) / p(D_S | θ_S) · p(θ_b) / q(θ_b | θ_S) / q(allocation)`,
//!
//! and a merge's is its inverse, with `θ_S = θ_a` and the reverse allocation's probability.
//! With neither the length scales nor the noise sampled, `θ_b` is the fixed one and
//! `p / q = 1`. The hyperparameters are then updated by the usual slice steps after the sweep.
//!
//! **Pairs.** `i` is uniform over frames; `j` is uniform over the others, or (informed) drawn
//! from an even mixture of uniform and a kernel on the frames' mean velocities (frames that
//! move alike are likely to share a pattern, so merges of them are proposed more often). That
//! distribution depends on the data only, never on the state, so the probability of choosing
//! `(i, j)` is the same for a move and its reverse and cancels from the ratio.
//!
//! In MAP mode (the paper's hill-climb) a move is taken when it raises the posterior.

use std::sync::Arc;

use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};

use super::{Assignment, Data, NONE, Sampler, Settings};
use crate::error::{Error, Result, unknown_option};
use crate::frame::FrameRef;
use crate::gp::GpParams;
use crate::pattern_model::PatternModel;
use crate::rng::{Phase, stream};
use crate::special::{ln_gamma, log_sum_exp};

/// The local part of a split pattern's proposal: sd of each `log w` around the split
/// pattern's, and of each `log σ_n²`.
pub const LOCAL_LS_SD: f64 = 0.25;
pub const LOCAL_NOISE_SD: f64 = 0.7;

/// How the second frame of a move's pair is chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PairChoice {
    Uniform,
    /// Half uniform, half by the similarity of the frames' mean velocities.
    Informed,
}

impl std::str::FromStr for PairChoice {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "uniform" => Ok(Self::Uniform),
            "informed" => Ok(Self::Informed),
            _ => Err(unknown_option(
                "split_merge_pairs",
                &["uniform", "informed"],
                s,
            )),
        }
    }
}

/// Split–merge settings: moves per sweep (0: off) and the pair choice.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SplitMerge {
    pub moves_per_sweep: usize,
    pub pairs: PairChoice,
}

impl Default for SplitMerge {
    fn default() -> Self {
        Self {
            moves_per_sweep: 0,
            pairs: PairChoice::Uniform,
        }
    }
}

/// Split and merge proposals and acceptances, accumulated over the run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SplitMergeStats {
    pub split_proposed: u64,
    pub split_accepted: u64,
    pub merge_proposed: u64,
    pub merge_accepted: u64,
}

/// Each frame's mean velocity, for informed pairs.
pub(crate) fn frame_means(data: &Data) -> Vec<[f64; 2]> {
    (0..data.len())
        .map(|i| {
            let f = data.frame(i);
            let n = f.v.len() as f64;
            let s =
                f.v.iter()
                    .fold([0.0, 0.0], |acc, r| [acc[0] + r[0], acc[1] + r[1]]);
            [s[0] / n, s[1] / n]
        })
        .collect()
}

/// How a move's pair and its new pattern's parameters are drawn: functions of the settings and
/// the data only, shared by every sampler's split–merge moves.
impl Settings {
    /// The second frame of a pair: uniform over the others, or by the informed mixture.
    pub(crate) fn pair_partner(
        &self,
        i: usize,
        means: &[[f64; 2]],
        rng: &mut impl rand::Rng,
    ) -> usize {
        let n = means.len();
        let uniform = |rng: &mut dyn FnMut() -> f64| {
            let j = ((rng() * (n - 1) as f64) as usize).min(n - 2);
            if j >= i { j + 1 } else { j }
        };
        let mut u = || rng.random::<f64>();
        if self.split_merge.pairs == PairChoice::Uniform || u() < 0.5 {
            return uniform(&mut u);
        }
        let w = self.similarity_weights(i, means);
        let total: f64 = w.iter().sum();
        let mut t = u() * total;
        for (j, wj) in w.iter().enumerate() {
            t -= wj;
            if t < 0.0 {
                return j;
            }
        }
        uniform(&mut u)
    }

    /// `exp(-½ Σ_d (v̄_i,d − v̄_j,d)² / (h² σ_d²))` for every frame `j` (0 for `j = i`): frames
    /// of similar mean velocity, on the scale of the signal variances (so in any units).
    fn similarity_weights(&self, i: usize, means: &[[f64; 2]]) -> Vec<f64> {
        let sv = self.base.signal_var;
        // Bandwidth: a quarter of the velocity spread; wide enough that every frame keeps weight.
        const H2: f64 = 0.0625;
        let mi = means[i];
        means
            .iter()
            .enumerate()
            .map(|(j, m)| {
                if j == i {
                    return 0.0;
                }
                let d2 = (0..2).map(|d| (m[d] - mi[d]).powi(2) / sv[d]).sum::<f64>();
                (-0.5 * d2 / H2).exp()
            })
            .collect()
    }

    /// Parameters of the new split pattern: length scales drawn from their prior (the fixed
    /// ones when fixed), then, per-pattern noise, the noise pair from its prior.
    pub(crate) fn prior_params(&self, rng: &mut impl rand::Rng) -> Result<GpParams> {
        let ls = if self.fixed_length_scales {
            self.base.length_scales
        } else {
            self.draw_length_scales(rng)?
        };
        let noise = self.new_noise(rng);
        Ok(self.new_params(ls, noise))
    }

    /// The split pattern `b`'s parameters, drawn from `½ p + ½ L(· | parent)`, and
    /// `log p(θ_b) − log q(θ_b | parent)` over the components the chain samples; `None` when
    /// the local draw falls outside the noise's support (the move is then rejected).
    pub(crate) fn split_params(
        &self,
        parent: &GpParams,
        rng: &mut impl rand::Rng,
    ) -> Result<Option<(GpParams, f64)>> {
        let sample_ls = !self.fixed_length_scales;
        let sample_noise = self.per_pattern_noise();
        if !(sample_ls || sample_noise) {
            return Ok(Some((self.prior_params(rng)?, 0.0)));
        }
        let theta = if rng.random::<f64>() < 0.5 {
            self.prior_params(rng)?
        } else {
            let mut jitter = |x: f64, sd: f64| {
                let z: f64 = StandardNormal.sample(&mut *rng);
                (x.ln() + sd * z).exp()
            };
            let ls = if sample_ls {
                let mut ls = parent.length_scales;
                for i in 0..self.length_scale_priors().len() {
                    ls = ls.with_coord(i, jitter(ls.coord(i), LOCAL_LS_SD));
                }
                ls
            } else {
                self.base.length_scales
            };
            let noise = if sample_noise {
                parent.noise_var.map(|v| jitter(v, LOCAL_NOISE_SD))
            } else {
                self.base.noise_var
            };
            if sample_noise && !self.noise_in_support(noise) {
                return Ok(None);
            }
            self.new_params(ls, noise)
        };
        Ok(Some((theta, self.log_prior_over_proposal(&theta, parent))))
    }

    /// `log p(θ) − log(½ p(θ) + ½ L(θ | parent))`, densities of the sampled components on the
    /// log scale (the same Jacobian in both).
    pub(crate) fn log_prior_over_proposal(&self, theta: &GpParams, parent: &GpParams) -> f64 {
        let normal = |x: f64, m: f64, sd: f64| {
            let z = (x - m) / sd;
            -0.5 * z * z - sd.ln() - 0.5 * crate::gp::LN_2PI
        };
        let (mut lp, mut ll) = (0.0, 0.0);
        if !self.fixed_length_scales {
            for (i, (a, b)) in self.length_scale_priors().into_iter().enumerate() {
                let (w, w0) = (theta.length_scales.coord(i), parent.length_scales.coord(i));
                let u = w.ln();
                lp += a * u - w / b - ln_gamma(a) - a * b.ln();
                ll += normal(u, w0.ln(), LOCAL_LS_SD);
            }
        }
        if self.per_pattern_noise()
            && let Some(prior) = self.noise_prior
        {
            let scale = self.base.signal_var;
            for d in 0..2 {
                let x = theta.noise_var[d].ln();
                lp += prior.log_density(x, scale[d]);
                ll += normal(x, parent.noise_var[d].ln(), LOCAL_NOISE_SD);
            }
        }
        lp - (log_sum_exp(&[lp, ll]) + 0.5f64.ln())
    }
}

/// A split allocation: the two patterns grown from the seeds, their numbers of items, and
/// `log q` of the allocation.
struct Allocation {
    a: Box<dyn PatternModel>,
    b: Box<dyn PatternModel>,
    items: (usize, usize),
    log_q: f64,
}

/// `log p(V_item | D)`: one frame's predictive, or the joint predictive of a segment's frames
/// (their points scored as one block).
pub(super) fn item_score(p: &dyn PatternModel, data: &Data, item: &[usize]) -> Result<f64> {
    if let [f] = item {
        return Ok(p.score(&[data.frame(*f)])?[0]);
    }
    let (mut xy, mut v) = (Vec::new(), Vec::new());
    for &f in item {
        let fr = data.frame(f);
        xy.extend_from_slice(fr.xy);
        v.extend_from_slice(fr.v);
    }
    let h = crate::frame::concat_headings(item.iter().map(|&f| data.frame(f)));
    Ok(p.score(&[FrameRef {
        xy: &xy,
        v: &v,
        h: &h,
    }])?[0])
}

impl Sampler {
    /// Run the configured number of split–merge moves (after the sweep's frame updates).
    pub(super) fn split_merge_moves(&mut self) -> Result<()> {
        let moves = self.settings.split_merge.moves_per_sweep;
        if moves == 0 || self.data.len() < 2 {
            return Ok(());
        }
        for m in 0..moves {
            let mut rng = stream(self.settings.seed, self.sweep, Phase::SplitMerge, m as u64);
            self.split_merge_step(&mut rng)?;
        }
        Ok(())
    }

    fn frame_means(&self) -> Arc<Vec<[f64; 2]>> {
        Arc::clone(
            self.frame_means
                .get_or_init(|| Arc::new(frame_means(&self.data))),
        )
    }

    /// One split or merge proposal, by the pair drawn from `rng`.
    pub(super) fn split_merge_step(&mut self, rng: &mut impl rand::Rng) -> Result<()> {
        let n = self.data.len();
        let i = ((rng.random::<f64>() * n as f64) as usize).min(n - 1);
        let j = self.settings.pair_partner(i, &self.frame_means(), rng);
        let (ki, kj) = (self.labels[i], self.labels[j]);
        if ki == NONE || kj == NONE {
            return Ok(());
        }
        if ki == kj {
            self.try_split(i, j, ki, rng)
        } else {
            self.try_merge(i, j, ki, kj, rng)
        }
    }

    /// Grow two patterns from the seed items `i` (params of `template`) and `j` (params
    /// `params_b`) over the items `rest` in a random order. An item is a frame, or under the sticky
    /// prior a segment (frames joined by links: one CRP draw), scored by the joint predictive
    /// of its frames. With `forced`, each item goes where `forced` says of its first frame (the
    /// reverse of a merge) and only its probability is accumulated.
    #[allow(clippy::too_many_arguments)]
    fn allocate(
        &self,
        i: &[usize],
        j: &[usize],
        template: &dyn PatternModel,
        params_b: GpParams,
        mut rest: Vec<Vec<usize>>,
        forced: Option<&dyn Fn(usize) -> bool>,
        rng: &mut impl rand::Rng,
    ) -> Result<Allocation> {
        let data = Arc::clone(&self.data);
        let lik = &self.settings.likelihood;
        let members = |item: &[usize]| -> Vec<(usize, FrameRef)> {
            item.iter().map(|&f| (f, data.frame(f))).collect()
        };
        let mut a = lik.pattern(*template.params(), &members(i))?;
        let mut b = lik.pattern(params_b, &members(j))?;
        // Fisher–Yates: a uniform order, independent of the state.
        for t in (1..rest.len()).rev() {
            let s = ((rng.random::<f64>() * (t + 1) as f64) as usize).min(t);
            rest.swap(t, s);
        }
        let (mut na, mut nb) = (1usize, 1usize);
        let mut log_q = 0.0;
        for item in &rest {
            let la = (na as f64).ln() + item_score(a.as_ref(), &data, item)?;
            let lb = (nb as f64).ln() + item_score(b.as_ref(), &data, item)?;
            let top = la.max(lb);
            let norm = top + ((la - top).exp() + (lb - top).exp()).ln();
            let to_a = match forced {
                Some(side) => side(item[0]),
                None => rng.random::<f64>() < (la - norm).exp(),
            };
            log_q += if to_a { la - norm } else { lb - norm };
            let (side, n) = if to_a {
                (&mut a, &mut na)
            } else {
                (&mut b, &mut nb)
            };
            for &f in item {
                side.insert(f, data.frame(f))?;
            }
            *n += 1;
        }
        Ok(Allocation {
            a,
            b,
            items: (na, nb),
            log_q,
        })
    }

    /// `log [α Γ(n_a) Γ(n_b) / Γ(n_a + n_b)]`: the CRP prior ratio of two patterns to their union.
    fn crp_split_ratio(&self, na: usize, nb: usize) -> f64 {
        self.alpha.ln() + ln_gamma(na as f64) + ln_gamma(nb as f64) - ln_gamma((na + nb) as f64)
    }

    /// Accept a move whose target log ratio is `log_target` and proposal log ratio `log_prop`.
    fn accept(&self, log_target: f64, log_prop: f64, rng: &mut impl rand::Rng) -> bool {
        match self.settings.assignment {
            Assignment::Map => log_target > 0.0,
            Assignment::Gibbs => rng.random::<f64>().ln() < log_target + log_prop,
        }
    }

    fn try_split(&mut self, i: usize, j: usize, k: usize, rng: &mut impl rand::Rng) -> Result<()> {
        self.split_merge.split_proposed += 1;
        let slot = self.live_slot(k);
        let template = slot.pattern.clone();
        let groups = self.settings.base.groups().len();
        self.check_memory(
            2 * self
                .settings
                .likelihood
                .pattern_bytes(template.n_points(), groups),
        )?;
        let (seed_i, seed_j) = (self.item_of(i), self.item_of(j));
        if seed_i[0] == seed_j[0] {
            // One segment: it cannot be split (links do not change in these moves).
            return Ok(());
        }
        let rest: Vec<Vec<usize>> = self
            .items(template.frames())
            .into_iter()
            .filter(|it| it[0] != seed_i[0] && it[0] != seed_j[0])
            .collect();
        let Some((params_b, prior_over_q)) = self.settings.split_params(template.params(), rng)?
        else {
            return Ok(());
        };
        let alloc = self.allocate(
            &seed_i,
            &seed_j,
            template.as_ref(),
            params_b,
            rest,
            None,
            rng,
        )?;
        let log_target = self.crp_split_ratio(alloc.items.0, alloc.items.1)
            + alloc.a.log_marginal()
            + alloc.b.log_marginal()
            - template.log_marginal();
        if !self.accept(log_target, prior_over_q - alloc.log_q, rng) {
            return Ok(());
        }
        self.split_merge.split_accepted += 1;
        self.slots[k] = None;
        for p in [alloc.a, alloc.b] {
            let members = p.frames().to_vec();
            let s = self.add_pattern(p);
            for f in members {
                self.labels[f] = s;
            }
        }
        Ok(())
    }

    fn try_merge(
        &mut self,
        i: usize,
        j: usize,
        ki: usize,
        kj: usize,
        rng: &mut impl rand::Rng,
    ) -> Result<()> {
        self.split_merge.merge_proposed += 1;
        let (a, b) = (
            self.live_slot(ki).pattern.clone(),
            self.live_slot(kj).pattern.clone(),
        );
        let groups = self.settings.base.groups().len();
        self.check_memory(
            2 * self
                .settings
                .likelihood
                .pattern_bytes(a.n_points() + b.n_points(), groups),
        )?;
        let mut members = a.members();
        members.extend(b.members());
        let merged = self.settings.likelihood.pattern(*a.params(), &members)?;
        drop(members);
        let (items_a, items_b) = (self.items(a.frames()), self.items(b.frames()));
        let log_target = -self.crp_split_ratio(items_a.len(), items_b.len())
            + merged.log_marginal()
            - a.log_marginal()
            - b.log_marginal();
        // The reverse split's proposal of b's parameters from a's.
        let q_over_prior = -self
            .settings
            .log_prior_over_proposal(b.params(), a.params());
        // The reverse split's log q is at most 0, so a uniform that rejects the ratio without it
        // rejects the move: most merges are refused before the costly reverse allocation.
        let log_u = match self.settings.assignment {
            Assignment::Map if log_target > 0.0 => f64::NEG_INFINITY,
            Assignment::Map => return Ok(()),
            Assignment::Gibbs => rng.random::<f64>().ln(),
        };
        if log_u >= log_target + q_over_prior {
            return Ok(());
        }
        if self.settings.assignment == Assignment::Gibbs {
            // The reverse split: seeds i and j, each other frame forced to the side it is on now.
            let (seed_i, seed_j) = (self.item_of(i), self.item_of(j));
            let rest: Vec<Vec<usize>> = items_a
                .into_iter()
                .chain(items_b)
                .filter(|it| it[0] != seed_i[0] && it[0] != seed_j[0])
                .collect();
            let labels = &self.labels;
            let side = |f: usize| labels[f] == ki;
            let params_b = self
                .settings
                .new_params(b.length_scales(), b.params().noise_var);
            let reverse = self.allocate(
                &seed_i,
                &seed_j,
                a.as_ref(),
                params_b,
                rest,
                Some(&side),
                rng,
            )?;
            if log_u >= log_target + q_over_prior + reverse.log_q {
                return Ok(());
            }
        }
        self.split_merge.merge_accepted += 1;
        self.slots[ki] = None;
        self.slots[kj] = None;
        let frames = merged.frames().to_vec();
        let s = self.add_pattern(merged);
        for f in frames {
            self.labels[f] = s;
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "tests/split_merge.rs"]
pub(crate) mod tests;
