//! The start made coarser: patterns of the initial state whose merge raises the log joint are
//! merged, the best pair first, before the first sweep.
//!
//! **Why.** The sequential initialisation sees only the first
//! [`INIT_SEQUENTIAL`](crate::gibbs::INIT_SEQUENTIAL) frames; a pattern it divides in two keeps
//! both halves once every frame is placed, and at scale the split–merge moves do not undo it: a
//! merge's reverse split must reproduce the halves' exact division, whose launch probability
//! falls exponentially in the frames they hold. Measured on 1M synthetic highway frames: the
//! chain kept one true pattern in three parts for 40 sweeps (ARI 0.933), and the state with those
//! parts merged has a log joint 120,290 nats higher, where a chain set there stays (ARI 1.0).
//!
//! **Exact.** This is part of where the chain starts, not a step of the chain: it draws no random
//! number and depends only on the initial patterns' sums, so the target, the chain's moves and
//! its reproducibility are unchanged.
//!
//! **Cost.** One `M x M` factorisation a pair of the `K` initial patterns, then `K` more a merge.

use rayon::prelude::*;

use super::SubclusterSampler;
use crate::error::{Error, Result};

impl SubclusterSampler {
    /// Merge, greedily, pairs of patterns whose merge raises [`Self::log_joint`]: the merged
    /// pattern takes the larger side's hyperparameters.
    pub(super) fn coalesce(&mut self, stop: &dyn Fn() -> bool) -> Result<()> {
        self.refresh_fits()?;
        let live: Vec<usize> = self.live().map(|(k, _)| k).collect();
        let pairs: Vec<(usize, usize)> = live
            .iter()
            .enumerate()
            .flat_map(|(x, &a)| live[x + 1..].iter().map(move |&b| (a, b)))
            .collect();
        let mut gains = self.merge_gains(&pairs)?;
        loop {
            if stop() {
                return Err(Error::Interrupted);
            }
            // The best pair; ties to the earliest listed (a fixed order: the pairs by slot, then
            // each merge's new pairs appended), so the start is the same for any thread count.
            let best =
                gains
                    .iter()
                    .enumerate()
                    .fold(None, |b: Option<(usize, f64)>, (x, &(_, _, g))| match b {
                        Some((_, bg)) if bg >= g => b,
                        _ => Some((x, g)),
                    });
            let Some((x, gain)) = best else { break };
            if !(gain > 0.0) {
                break;
            }
            let (a, b, _) = gains[x];
            let s = self.merge_now(a, b)?;
            gains.retain(|&(p, q, _)| p != a && p != b && q != a && q != b);
            let fresh: Vec<(usize, usize)> = self
                .live()
                .map(|(k, _)| k)
                .filter(|&k| k != s)
                .map(|k| (k.min(s), k.max(s)))
                .collect();
            gains.extend(self.merge_gains(&fresh)?);
        }
        Ok(())
    }

    /// `(a, b, Δ log joint)` of merging each pair, in parallel, in the pairs' order.
    fn merge_gains(&self, pairs: &[(usize, usize)]) -> Result<Vec<(usize, usize, f64)>> {
        pairs
            .par_iter()
            .map(|&(a, b)| {
                let (keep, sums) = self.merged(a, b);
                let fit = self.fit_sums(&sums, self.part(keep).params)?;
                let after =
                    self.pattern_term(sums.n_frames, &fit.post.params, fit.post.log_marginal);
                let before = [a, b].map(|k| {
                    let p = self.part(k);
                    self.pattern_term(p.sums.n_frames, &p.params, self.log_marginal_of(k))
                });
                Ok((a, b, after - before[0] - before[1]))
            })
            .collect()
    }

    /// The side whose hyperparameters a merge of `a` and `b` keeps (the larger; `a` on a tie)
    /// and the merged sums.
    fn merged(&self, a: usize, b: usize) -> (usize, crate::hsgp_sums::Sums) {
        let keep = if self.part(b).sums.n_frames > self.part(a).sums.n_frames {
            b
        } else {
            a
        };
        let mut sums = self.part(a).sums.clone();
        sums.add(&self.part(b).sums);
        (keep, sums)
    }

    /// Merge patterns `a` and `b` into a new slot (returned).
    fn merge_now(&mut self, a: usize, b: usize) -> Result<usize> {
        let (keep, sums) = self.merged(a, b);
        let params = self.part(keep).params;
        let fit = self.fit_sums(&sums, params)?;
        self.slots[a] = None;
        self.slots[b] = None;
        let s = self.add_part(sums, params, Some(fit));
        self.relabel(&[(a, s), (b, s)], &[], s)?;
        Ok(s)
    }
}
