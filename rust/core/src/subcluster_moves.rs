//! Split–merge moves of the sub-cluster sampler, proposed from two sub-patterns and accepted by
//! the exact Metropolis–Hastings ratio of the collapsed posterior.
//!
//! A move draws a pair of frames `(i, j)` as the collapsed sampler's moves do (uniform, or half
//! by similar mean velocity: a distribution of the data only, the same for a move and its
//! reverse). If they share a pattern `S`, a split of `S` is proposed; else the merge of their two
//! patterns `A ∋ i`, `B ∋ j`. The pattern holding `i` keeps its hyperparameters `θ_i`; the other
//! side's `θ_j` is drawn from `½ prior + ½ log-normal around θ_i` for a split, and is `B`'s for
//! a merge (its proposal density enters the ratio), exactly as in `split_merge.rs`.
//!
//! **Sub-patterns (the launch).** `S`'s frames are divided between two sub-patterns grown from the
//! anchors: each sub-pattern's field is drawn from its posterior given the anchor alone (`θ_i`,
//! `θ_j`), a sample of `S` (at most [`LAUNCH_FRAMES`] frames) is given sub-labels by those fields,
//! the fields are redrawn from the sub-labels' sums, [`LAUNCH_SCANS`] times. Then every frame of `S`
//! but the anchors gets its log-likelihood under both final sub-fields, in parallel, and in a
//! uniformly random order joins a side with probability `∝ n_side f(V_f | a_side)`, `n_side` the
//! frames on that side so far (an urn like the DP's own, so that for frames the sub-fields cannot
//! tell apart `q` is `Γ(n_l) Γ(n_r) / Γ(n_S)` and cancels the prior's ratio: two alike patterns can
//! merge). A split's proposal probability `q` is the product of those steps. The launch depends
//! only on `(S, i, j, θ_i, θ_j)` and fresh randomness, never on how `S` is split now, so a merge's
//! reverse split is scored by running the same launch on `A ∪ B` and the urn along a fresh order
//! with each frame forced to its side (restricted Gibbs launches, Jain & Neal 2004; the sequential
//! allocation of Dahl & Newcomb 2022; instantiated sub-fields).
//!
//! **Ratio** (split; a merge's is its inverse):
//! `α Γ(n_l) Γ(n_r) / Γ(n_S) · p(D_l | θ_i) p(D_r | θ_j) / p(D_S | θ_i) · p(θ_j) / q(θ_j | θ_i) / q`,
//! every marginal likelihood from sums (`O(M³)`, no pass over the data); the sums of a proposed
//! split are gathered in the same parallel pass that draws it. Any pattern may be proposed for a
//! split at any sweep (no "burn-out" age, which would make the move depend on the chain's path).
//!
//! The moves per sweep are a setting of the data's size only, never of the state.

use rand::RngExt;

use std::sync::Arc;

use super::shard::{Bank, Store};
use super::{Fit, SubclusterSampler};
use crate::error::{Error, Result};
use crate::gibbs::Assignment;
use crate::gp::GpParams;
use crate::hsgp_sums::{Posterior, Sums};
use crate::rng::{Phase, stream};
use crate::special::ln_gamma;

/// Most frames of `S` the launch scans (a uniform sample of them); the final step covers all.
pub const LAUNCH_FRAMES: usize = 256;
/// Restricted scans of the launch before the final step.
pub const LAUNCH_SCANS: usize = 2;

/// A proposed division of `S`: each frame's side (`true`: with `i`), the sums of both sides,
/// and `log q` of the division.
struct Division {
    left: Vec<bool>,
    sums: [Sums; 2],
    log_q: f64,
}

impl SubclusterSampler {
    /// Run the configured number of moves.
    pub(super) fn split_merge_moves(&mut self, stop: &dyn Fn() -> bool) -> Result<()> {
        if self.store.len() < 2 {
            return Ok(());
        }
        self.refresh_fits()?;
        for m in 0..self.settings.split_merge.moves_per_sweep {
            if stop() {
                return Err(Error::Interrupted);
            }
            let mut rng = stream(self.settings.seed, self.sweep, Phase::Launch, m as u64);
            let n = self.store.len();
            let i = ((rng.random::<f64>() * n as f64) as usize).min(n - 1);
            let j = self
                .settings
                .pair_partner(i, &self.frame_means()?, &mut rng);
            let (ki, kj) = match self.held {
                Some(chain) => {
                    let l = self.store.held_labels_of(chain, &[i, j])?;
                    (l[0], l[1])
                }
                None => (self.labels[i], self.labels[j]),
            };
            if ki == kj {
                self.try_split(i, j, ki, &mut rng)?;
            } else {
                self.try_merge(i, j, ki, kj, &mut rng)?;
            }
        }
        Ok(())
    }

    /// `log [α Γ(n_a) Γ(n_b) / Γ(n_a + n_b)]`.
    fn crp_split_ratio(&self, na: usize, nb: usize) -> f64 {
        self.alpha.ln() + ln_gamma(na as f64) + ln_gamma(nb as f64) - ln_gamma((na + nb) as f64)
    }

    /// The frames of pattern `k`, in order.
    fn members(&self, k: usize) -> Result<Vec<usize>> {
        Ok(match self.held {
            Some(chain) => self.store.held_members(chain, &[k])?.0,
            None => (0..self.labels.len())
                .filter(|&f| self.labels[f] == k)
                .collect(),
        })
    }

    /// Relabel: the frames of the patterns `map[j].0` go to `map[j].1`, then `frames` go to
    /// `to` (on the shards, when they hold the labels).
    pub(super) fn relabel(
        &mut self,
        map: &[(usize, usize)],
        frames: &[usize],
        to: usize,
    ) -> Result<()> {
        if let Some(chain) = self.held {
            return self.store.held_relabel(chain, map, frames, to);
        }
        if !map.is_empty() {
            for l in self.labels.iter_mut() {
                if let Some(&(_, b)) = map.iter().find(|(a, _)| a == l) {
                    *l = b;
                }
            }
        }
        for &f in frames {
            self.labels[f] = to;
        }
        Ok(())
    }

    fn try_split(&mut self, i: usize, j: usize, k: usize, rng: &mut impl rand::Rng) -> Result<()> {
        self.split_merge.split_proposed += 1;
        let parent = self.part(k).params;
        let Some((theta_j, prior_over_q)) = self.settings.split_params(&parent, rng)? else {
            return Ok(());
        };
        let frames = self.members(k)?;
        let div = self.launch(
            &frames,
            i,
            j,
            [parent, theta_j],
            None,
            &self.part(k).sums,
            rng,
        )?;
        let [nl, nr] = [div.sums[0].n_frames, div.sums[1].n_frames];
        let fit_l = self.fit_sums(&div.sums[0], parent)?;
        let fit_r = self.fit_sums(&div.sums[1], theta_j)?;
        let log_target =
            self.crp_split_ratio(nl, nr) + fit_l.post.log_marginal + fit_r.post.log_marginal
                - self.log_marginal_of(k);
        if !self.accept(log_target, prior_over_q - self.log_q(&div), rng) {
            return Ok(());
        }
        self.split_merge.split_accepted += 1;
        let [sl, sr] = div.sums;
        self.slots[k] = None;
        let a = self.add_part(sl, parent, Some(fit_l));
        let b = self.add_part(sr, theta_j, Some(fit_r));
        // The pattern's frames to the larger side's slot, then the smaller side's frames to
        // theirs (the fewest frame numbers to send).
        let n_left = div.left.iter().filter(|&&l| l).count();
        let small_left = 2 * n_left <= frames.len();
        let small: Vec<usize> = frames
            .iter()
            .zip(&div.left)
            .filter(|&(_, &l)| l == small_left)
            .map(|(&f, _)| f)
            .collect();
        let (big, to) = if small_left { (b, a) } else { (a, b) };
        self.relabel(&[(k, big)], &small, to)
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
        let (pa, pb) = (self.part(ki).params, self.part(kj).params);
        let mut merged = self.part(ki).sums.clone();
        merged.add(&self.part(kj).sums);
        let fit = self.fit_sums(&merged, pa)?;
        let (na, nb) = (self.part(ki).sums.n_frames, self.part(kj).sums.n_frames);
        let log_target = -self.crp_split_ratio(na, nb) + fit.post.log_marginal
            - self.log_marginal_of(ki)
            - self.log_marginal_of(kj);
        let q_over_prior = -self.settings.log_prior_over_proposal(&pb, &pa);
        // The reverse split's log q is at most 0: a uniform that rejects the ratio without it
        // rejects the move, before the launch is paid for.
        let log_u = match self.settings.assignment {
            Assignment::Map if log_target > 0.0 => f64::NEG_INFINITY,
            Assignment::Map => return Ok(()),
            Assignment::Gibbs => rng.random::<f64>().ln(),
        };
        if log_u >= log_target + q_over_prior {
            return Ok(());
        }
        if self.settings.assignment == Assignment::Gibbs {
            let (frames, side): (Vec<usize>, Vec<bool>) = match self.held {
                Some(chain) => {
                    let (frames, which) = self.store.held_members(chain, &[ki, kj])?;
                    (frames, which.iter().map(|&w| w == 0).collect())
                }
                None => {
                    let frames: Vec<usize> = (0..self.labels.len())
                        .filter(|&f| self.labels[f] == ki || self.labels[f] == kj)
                        .collect();
                    let side = frames.iter().map(|&f| self.labels[f] == ki).collect();
                    (frames, side)
                }
            };
            let div = self.launch(&frames, i, j, [pa, pb], Some(&side), &merged, rng)?;
            if log_u >= log_target + q_over_prior + self.log_q(&div) {
                return Ok(());
            }
        }
        self.split_merge.merge_accepted += 1;
        self.slots[ki] = None;
        self.slots[kj] = None;
        let s = self.add_part(merged, pa, Some(fit));
        self.relabel(&[(ki, s), (kj, s)], &[], s)
    }

    /// `log q` of a division as the ratio takes it.
    fn log_q(&self, div: &Division) -> f64 {
        #[cfg(test)]
        if self.wrong_ratio {
            return 0.0;
        }
        div.log_q
    }

    /// Accept a move whose target log ratio is `log_target` and proposal log ratio `log_prop`.
    fn accept(&self, log_target: f64, log_prop: f64, rng: &mut impl rand::Rng) -> bool {
        match self.settings.assignment {
            Assignment::Map => log_target > 0.0,
            Assignment::Gibbs => rng.random::<f64>().ln() < log_target + log_prop,
        }
    }

    pub(super) fn fit_sums(&self, sums: &Sums, params: GpParams) -> Result<Fit> {
        let gram = std::sync::Arc::new(sums.gram(&self.basis));
        let post = Posterior::new(&self.basis, sums, &gram, params)?;
        Ok(Fit { gram, post })
    }

    /// The sums of one frame.
    pub(super) fn frame_sums(&self, f: usize) -> Result<Sums> {
        Ok(self.sums_of_sets(&[&[f]])?.remove(0))
    }

    /// Divide `frames` (sorted; holding the anchors `i`, `j`) between two sub-patterns with
    /// hyperparameters `theta = [θ_i, θ_j]`: a launch, then every frame's side drawn from its
    /// final sub-label probabilities, or, with `forced`, the given sides scored.
    #[allow(clippy::too_many_arguments)]
    fn launch(
        &self,
        frames: &[usize],
        i: usize,
        j: usize,
        theta: [GpParams; 2],
        forced: Option<&[bool]>,
        whole: &Sums,
        rng: &mut impl rand::Rng,
    ) -> Result<Division> {
        let others: Vec<usize> = frames
            .iter()
            .copied()
            .filter(|&f| f != i && f != j)
            .collect();
        // A uniform sample of the other frames (partial Fisher–Yates), in frame order.
        let mut sample = others.clone();
        let take = sample.len().min(LAUNCH_FRAMES);
        for t in 0..take {
            let s = t
                + ((rng.random::<f64>() * (sample.len() - t) as f64) as usize)
                    .min(sample.len() - t - 1);
            sample.swap(t, s);
        }
        sample.truncate(take);
        sample.sort_unstable();

        // The scans read only the anchors and the sample: fetched once (one request per shard
        // holding some), then numbered by their order among all frames.
        let mut near_frames: Vec<usize> = sample.iter().copied().chain([i, j]).collect();
        near_frames.sort_unstable();
        let near = Store::local(Arc::new(self.store.frames(&near_frames)?));
        let local = |set: &[usize]| -> Vec<usize> {
            set.iter()
                .map(|f| near_frames.binary_search(f).expect("a fetched frame"))
                .collect()
        };
        let sums_near = |sets: [&[usize]; 2]| -> Result<Vec<Sums>> {
            let (a, b) = (local(sets[0]), local(sets[1]));
            near.sums_of_sets(&self.basis, &[&a, &b])
        };
        let [si, sj]: [Sums; 2] = sums_near([&[i], &[j]])?.try_into().expect("two sets");
        let mut sums = [si, sj];
        let mut fields = self.draw_sides(&sums, theta, rng)?;
        let mut log_pi = [0.5f64.ln(); 2];
        let sample_near = local(&sample);
        for _ in 0..LAUNCH_SCANS {
            let lls = self.side_logliks(&near, &sample_near, &fields, theta)?;
            let mut left_set = vec![i];
            let mut right_set = vec![j];
            for (f, ll) in sample.iter().zip(lls.chunks(2)) {
                let pl = side_prob(ll, log_pi);
                if rng.random::<f64>() < pl {
                    left_set.push(*f);
                } else {
                    right_set.push(*f);
                }
            }
            left_set.sort_unstable();
            right_set.sort_unstable();
            let [sl, sr]: [Sums; 2] = sums_near([&left_set, &right_set])?
                .try_into()
                .expect("two sets");
            sums = [sl, sr];
            let total = (left_set.len() + right_set.len()) as f64;
            log_pi = [
                (left_set.len() as f64 / total).ln(),
                (right_set.len() as f64 / total).ln(),
            ];
            fields = self.draw_sides(&sums, theta, rng)?;
        }
        self.final_division(frames, i, j, &fields, theta, forced, whole, rng)
    }

    /// Draws of the two sub-patterns' fields from their posteriors given `sums`, on the basis's
    /// lower half of frequencies per axis (a proposal needs only tell the sides apart, and a
    /// factor there costs a sixty-fourth of the full one's).
    fn draw_sides(
        &self,
        sums: &[Sums; 2],
        theta: [GpParams; 2],
        rng: &mut impl rand::Rng,
    ) -> Result<[[Vec<f64>; 2]; 2]> {
        let mut out: [[Vec<f64>; 2]; 2] = Default::default();
        let coarse = &self.coarse;
        for s in 0..2 {
            let sub = sums[s].restrict(&self.basis, coarse);
            let post = Posterior::new(coarse, &sub, &sub.gram(coarse), theta[s])?;
            let mut r = stream(rng.random::<u64>(), 0, Phase::Launch, s as u64);
            out[s] = post.weights(Some(&mut r));
        }
        Ok(out)
    }

    /// `[log f(V_f | a_l), log f(V_f | a_r)]` of each of `frames`, in parallel over tiles, with
    /// the sub-fields on the coarse basis (a quarter of the full one's work).
    fn side_logliks(
        &self,
        store: &Store,
        frames: &[usize],
        fields: &[[Vec<f64>; 2]; 2],
        theta: [GpParams; 2],
    ) -> Result<Vec<f64>> {
        let bank = Bank {
            weights: fields.to_vec(),
            noise: vec![theta[0].noise_var, theta[1].noise_var],
            mean: self.settings.base.mean,
        };
        store.logliks(&self.coarse, &bank, frames)
    }

    /// The final step over every frame but the anchors. Their log-likelihoods under the two
    /// final sub-fields are computed in parallel; then, in a uniformly random order, each frame
    /// joins a side with probability `∝ n_side f(V_f | a_side)`, `n_side` the frames on that side
    /// so far (the anchors count one each): an urn like the DP's own, so that `q` of a division
    /// whose frames the sub-fields cannot tell apart is `Γ(n_l) Γ(n_r) / Γ(n_S)`, which cancels the
    /// prior's ratio in a merge of two alike patterns. With `forced`, the given sides are scored.
    /// Last, the sums of the smaller side (in parallel over chunks of its frames), and of the
    /// other as `whole` (the sums of `frames`) less them.
    #[allow(clippy::too_many_arguments)]
    fn final_division(
        &self,
        frames: &[usize],
        i: usize,
        j: usize,
        fields: &[[Vec<f64>; 2]; 2],
        theta: [GpParams; 2],
        forced: Option<&[bool]>,
        whole: &Sums,
        rng: &mut impl rand::Rng,
    ) -> Result<Division> {
        let ll = self.side_logliks(&self.store, frames, fields, theta)?;
        let mut order: Vec<usize> = (0..frames.len())
            .filter(|&t| frames[t] != i && frames[t] != j)
            .collect();
        // Fisher–Yates: a uniform order, independent of the state.
        for t in (1..order.len()).rev() {
            let s = ((rng.random::<f64>() * (t + 1) as f64) as usize).min(t);
            order.swap(t, s);
        }
        let mut left: Vec<bool> = frames.iter().map(|&f| f == i).collect();
        let (mut nl, mut nr) = (1.0f64, 1.0f64);
        let mut log_q = 0.0;
        for &t in &order {
            let pl = side_prob(&ll[2 * t..2 * t + 2], [nl.ln(), nr.ln()]);
            let l = match forced {
                Some(side) => side[t],
                None => rng.random::<f64>() < pl,
            };
            log_q += if l { pl.ln() } else { (1.0 - pl).ln() };
            left[t] = l;
            if l {
                nl += 1.0;
            } else {
                nr += 1.0;
            }
        }
        let sums = match forced {
            Some(_) => [Sums::zeros(&self.basis), Sums::zeros(&self.basis)],
            None => {
                // The smaller side's sums from its frames, the other's as the rest of `whole`.
                let nl = left.iter().filter(|&&l| l).count();
                let small_left = 2 * nl <= frames.len();
                let small: Vec<usize> = frames
                    .iter()
                    .zip(&left)
                    .filter(|&(_, &l)| l == small_left)
                    .map(|(&f, _)| f)
                    .collect();
                let part = self.sums_of_sets(&[&small])?.remove(0);
                let mut rest = whole.clone();
                rest.sub(&part);
                if small_left {
                    [part, rest]
                } else {
                    [rest, part]
                }
            }
        };
        Ok(Division { left, sums, log_q })
    }
}

/// `r(l)`: the probability of the left side from the two log-likelihoods and log weights.
fn side_prob(ll: &[f64], log_pi: [f64; 2]) -> f64 {
    let (a, b) = (ll[0] + log_pi[0], ll[1] + log_pi[1]);
    1.0 / (1.0 + (b - a).exp())
}
