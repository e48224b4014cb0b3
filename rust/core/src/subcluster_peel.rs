//! One frame between its pattern and a pattern of its own: the sub-cluster sampler's counterpart
//! of the collapsed sampler's new-pattern term (Neal's Algorithm 8), as a pair of
//! Metropolis–Hastings moves on the collapsed target.
//!
//! The assignment pass never empties a pattern (its last frame stays: the exact conditional
//! given the drawn fields), so a pattern that has shrunk to one frame waits for a merge, and a
//! merge picks that frame with probability `1/N`. These moves pick it directly:
//!
//! - **absorb** (half the moves): a pattern of one frame `i`, uniformly among the `S` such
//!   patterns, joins a pattern `k` drawn by affinity `q(k | i)` (mean velocities, from the sums);
//! - **peel** (the other half): a frame `i`, uniformly among the `N_ns` frames of patterns with
//!   at least two, leaves its pattern `k` for one of its own, whose hyperparameters are drawn from
//!   `½ prior + ½ log-normal around θ_k` (as a split's second pattern: `split_merge.rs`).
//!
//! A peel and the absorb that undoes it are each other's reverse, so the ratio of a peel is
//!
//! `α Γ(n_k − 1) / Γ(n_k) · p(D_k \ i | θ_k) p(V_i | θ_i) / p(D_k | θ_k) · p(θ_i) / q(θ_i | θ_k)
//!  · [(1/S') q(k | i, z')] / (1/N_ns)`,
//!
//! `S'` the patterns of one frame after it and `q(k | i, z')` the affinity there; an absorb's is its
//! inverse. Every marginal likelihood comes from sums (`O(M³)`, no pass over the data), and the
//! selection probabilities depend on the state only through counts both states give.

use rand::RngExt;

use super::SubclusterSampler;
use crate::error::Result;
use crate::gibbs::Assignment;
use crate::rng::{Phase, stream};
use crate::special::ln_gamma;

/// Share of the affinity spread uniformly over the targets, so that every pattern can be drawn.
const UNIFORM_SHARE: f64 = 0.1;
/// Bandwidth of the affinity, as a share of each velocity component's spread (as the informed
/// pairs of split–merge moves).
const H2: f64 = 0.0625;

impl SubclusterSampler {
    /// The configured number of peel and absorb moves (one per split–merge move).
    pub(super) fn peel_absorb_moves(&mut self) -> Result<()> {
        for m in 0..self.settings.split_merge.moves_per_sweep {
            let mut rng = stream(self.settings.seed, self.sweep, Phase::Peel, m as u64);
            if rng.random::<f64>() < 0.5 {
                self.try_absorb(&mut rng)?;
            } else {
                self.try_peel(&mut rng)?;
            }
        }
        Ok(())
    }

    /// `log q(k | i)` of every live pattern but `skip` (slots, log probabilities): the affinity
    /// of frame `i`'s mean velocity for each pattern's, with `sub` taken out of pattern `sub.0`.
    fn affinity(
        &self,
        i: usize,
        skip: usize,
        sub: Option<(usize, &crate::hsgp_sums::Sums)>,
    ) -> Result<(Vec<usize>, Vec<f64>)> {
        let mi = self.frame_means()?[i];
        let sv = self.settings.base.signal_var;
        let mut slots = Vec::new();
        let mut w = Vec::new();
        for (k, p) in self.live() {
            if k == skip {
                continue;
            }
            let (mut n, mut s) = (p.sums.vecs.n_points as f64, p.sums.vecs.v_sum);
            if let Some((kk, out)) = sub
                && kk == k
            {
                n -= out.vecs.n_points as f64;
                s = [s[0] - out.vecs.v_sum[0], s[1] - out.vecs.v_sum[1]];
            }
            let d2: f64 = (0..2).map(|d| (s[d] / n - mi[d]).powi(2) / sv[d]).sum();
            slots.push(k);
            w.push((-0.5 * d2 / H2).exp());
        }
        let total: f64 = w.iter().sum();
        let floor = UNIFORM_SHARE / w.len().max(1) as f64;
        let logq = w
            .iter()
            .map(|x| {
                let share = if total > 0.0 { x / total } else { 0.0 };
                ((1.0 - UNIFORM_SHARE) * share + floor).ln()
            })
            .collect();
        Ok((slots, logq))
    }

    fn singletons(&self) -> Vec<usize> {
        self.live()
            .filter(|(_, p)| p.sums.n_frames == 1)
            .map(|(k, _)| k)
            .collect()
    }

    /// A pattern of one frame joins another.
    fn try_absorb(&mut self, rng: &mut impl rand::Rng) -> Result<()> {
        let singles = self.singletons();
        if singles.is_empty() || self.live().count() < 2 {
            return Ok(());
        }
        self.peels.absorb_proposed += 1;
        let s =
            singles[((rng.random::<f64>() * singles.len() as f64) as usize).min(singles.len() - 1)];
        let i = match self.held {
            Some(chain) => *self
                .store
                .held_members(chain, &[s])?
                .0
                .first()
                .ok_or_else(|| crate::error::Error::Link("a pattern's frame is missing".into()))?,
            None => self
                .labels
                .iter()
                .position(|&l| l == s)
                .expect("a pattern holds a frame"),
        };
        let (slots, logq) = self.affinity(i, s, None)?;
        let pick = super::pass::pick_log(&logq, rng.random::<f64>());
        let (k, log_qk) = (slots[pick], logq[pick]);
        let (pk, ps) = (self.part(k).params, self.part(s).params);
        let nk = self.part(k).sums.n_frames;
        let mut merged = self.part(k).sums.clone();
        merged.add(&self.part(s).sums);
        let fit = self.fit_sums(&merged, pk)?;
        let log_target = -self.alpha.ln() + ln_gamma((nk + 1) as f64) - ln_gamma(nk as f64)
            + fit.post.log_marginal
            - self.log_marginal_of(k)
            - self.log_marginal_of(s);
        // The reverse peel: frame i among the frames of patterns of two or more after the move,
        // its hyperparameters from the proposal around θ_k (the prior ratio enters with them).
        let ns_after = self.non_singleton_frames() + 1 + usize::from(nk == 1);
        let log_prop = (singles.len() as f64).ln()
            - (ns_after as f64).ln()
            - self.test_q(log_qk)
            - self.settings.log_prior_over_proposal(&ps, &pk);
        if !self.accept_move(log_target, log_prop, rng) {
            return Ok(());
        }
        self.slots[s] = None;
        let p = self.part_mut(k);
        p.sums = merged;
        p.fit = Some(fit);
        self.relabel(&[], &[i], k)?;
        self.peels.absorb_accepted += 1;
        Ok(())
    }

    /// A frame leaves its pattern for a pattern of its own.
    fn try_peel(&mut self, rng: &mut impl rand::Rng) -> Result<()> {
        let n_ns = self.non_singleton_frames();
        if n_ns == 0 {
            return Ok(());
        }
        self.peels.peel_proposed += 1;
        // The r-th frame (in frame order) of the patterns of two or more.
        let r = ((rng.random::<f64>() * n_ns as f64) as usize).min(n_ns - 1);
        let (i, k) = match self.held {
            Some(chain) => {
                let many: Vec<usize> = self
                    .live()
                    .filter(|(_, p)| p.sums.n_frames >= 2)
                    .map(|(k, _)| k)
                    .collect();
                self.store.held_find(chain, &many, r)?
            }
            None => {
                let i = self
                    .labels
                    .iter()
                    .enumerate()
                    .filter(|&(_, &l)| self.part(l).sums.n_frames >= 2)
                    .nth(r)
                    .map(|(f, _)| f)
                    .expect("r is below the count");
                (i, self.labels[i])
            }
        };
        let pk = self.part(k).params;
        let Some((theta, prior_over_q)) = self.settings.split_params(&pk, rng)? else {
            return Ok(());
        };
        let nk = self.part(k).sums.n_frames;
        let own = self.frame_sums(i)?;
        let mut rest = self.part(k).sums.clone();
        rest.sub(&own);
        let fit_rest = self.fit_sums(&rest, pk)?;
        let fit_own = self.fit_sums(&own, theta)?;
        let log_target = self.alpha.ln() + ln_gamma((nk - 1) as f64) - ln_gamma(nk as f64)
            + fit_rest.post.log_marginal
            + fit_own.post.log_marginal
            - self.log_marginal_of(k);
        // The reverse absorb: i's pattern among the patterns of one frame after the move, then
        // k by the affinity there.
        let singles_after = self.singletons().len() + 1 + usize::from(nk == 2);
        let (slots, logq) = self.affinity(i, usize::MAX, Some((k, &own)))?;
        let log_qk = slots
            .iter()
            .zip(&logq)
            .find(|(s, _)| **s == k)
            .map(|(_, q)| *q)
            .expect("k stays live");
        // `affinity` above was over every live pattern; i's own pattern after the move is not
        // a target of its absorb, and every other pattern is: the same set.
        let log_prop =
            prior_over_q - (singles_after as f64).ln() + self.test_q(log_qk) + (n_ns as f64).ln();
        if !self.accept_move(log_target, log_prop, rng) {
            return Ok(());
        }
        let p = self.part_mut(k);
        p.sums = rest;
        p.fit = Some(fit_rest);
        let s = self.add_part(own, theta, Some(fit_own));
        self.relabel(&[], &[i], s)?;
        self.peels.peel_accepted += 1;
        Ok(())
    }

    /// `log q(k | i)` as the ratio takes it (tests: left out with `wrong_ratio`).
    fn test_q(&self, log_q: f64) -> f64 {
        #[cfg(test)]
        if self.wrong_ratio {
            return 0.0;
        }
        log_q
    }

    /// Frames of patterns with at least two.
    fn non_singleton_frames(&self) -> usize {
        self.live()
            .map(|(_, p)| p.sums.n_frames)
            .filter(|&n| n >= 2)
            .sum()
    }

    /// Accept a move whose target log ratio is `log_target` and proposal log ratio `log_prop`.
    fn accept_move(&self, log_target: f64, log_prop: f64, rng: &mut impl rand::Rng) -> bool {
        match self.settings.assignment {
            Assignment::Map => log_target > 0.0,
            Assignment::Gibbs => rng.random::<f64>().ln() < log_target + log_prop,
        }
    }
}
