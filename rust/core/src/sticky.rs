//! The sticky prior on consecutive frames' labels (`dynamics="sticky"`; docs/dynamics.md).
//!
//! Frames come in runs (consecutive frames of one scene). Every frame `t` with a predecessor has
//! a binary link `s_t`: 1 means it stays in its predecessor's pattern (`z_t = z_{t−1}` forced),
//! 0 that it is a *fresh draw*; first frames of runs are always fresh. The prior is
//!
//! `p(z, s) = ρ^{#links=1} (1 − ρ)^{#links=0} · CRP_α(labels of the fresh draws)`,
//!
//! the sticky HDP-HMM (Fox et al. 2011) in the limit where every transition row is the global
//! pattern distribution plus self-transition mass, `π_j = ρ δ_j + (1 − ρ) β`. It keeps the
//! sampler collapsed and exact: the frames' GP likelihood depends on `z` only, a frame's update
//! is the plain sweep with other prior weights, and split–merge stays a CRP ratio, over
//! *segments* (frames joined by links, one fresh draw each).
//!
//! **Frame update.** The block `(z_t, s_t, s_{t+1})` is drawn jointly given the rest: with the
//! fresh draws of `t` and `t+1` removed from the CRP counts `m` (total `M`), `a = z_{t−1}`,
//! `b = z_{t+1}`, the prior weight of pattern `k` sums over the link options consistent with it:
//!
//! - `s_t = 1, s_{t+1} = 1`: `k = a = b`, weight `ρ²`;
//! - `s_t = 1, s_{t+1} = 0`: `k = a`, `ρ(1 − ρ) CRP(b | m)`;
//! - `s_t = 0, s_{t+1} = 1`: `k = b`, `(1 − ρ)ρ CRP(k | m)`;
//! - `s_t = 0, s_{t+1} = 0`: `(1 − ρ)² CRP(k | m) CRP(b | m + δ_k)`;
//!
//! `CRP(k | m) = m_k / (α + M)`, or `α / (α + M)` for a table not in `m` (a new pattern, or `b`
//! when its only fresh draw was `t+1`'s). A run's first frame has no `s_t` (factor 1, no
//! `s_t = 1`); its last no `s_{t+1}`. The links are then drawn given the chosen pattern.
//!
//! During the sequential initialisation a neighbour without a pattern yet counts as absent, and
//! `link[t]` is set only when both frames have a pattern: a frame is fresh exactly when its link
//! is off, so the counts never need the neighbour's future.

use std::sync::Arc;

use rand::RngExt;
use rand_distr::{Beta, Distribution};

use super::{NONE, Sampler};
use crate::error::{Error, Result};
use crate::rng::{Phase, stream};
use crate::special::ln_gamma;

/// Closest ρ may come to 0 or 1, so that both link values keep a positive weight.
const RHO_EDGE: f64 = 1e-12;

/// The sticky prior's setting: the frames' time order and ρ.
#[derive(Clone, Debug, PartialEq)]
pub struct StickyPrior {
    /// Each frame's predecessor (the frame one step earlier in its scene), `usize::MAX` for the
    /// first frame of a run.
    pub prev: Arc<[usize]>,
    /// A fixed ρ; `None` samples it.
    pub rho: Option<f64>,
    /// Beta(a, b) prior of ρ.
    pub rho_prior: (f64, f64),
}

impl StickyPrior {
    pub fn validate(&self) -> Result<()> {
        let (a, b) = self.rho_prior;
        if !(a.is_finite() && a > 0.0 && b.is_finite() && b > 0.0) {
            return Err(Error::InvalidInput(format!(
                "the stickiness prior must be Beta(a, b) with a, b positive, got ({a}, {b})"
            )));
        }
        if let Some(r) = self.rho
            && !(r > 0.0 && r < 1.0)
        {
            return Err(Error::InvalidInput(format!(
                "the stickiness must be in (0, 1), got {r}"
            )));
        }
        Ok(())
    }

    /// The successor of every frame, checking that the predecessors form runs over `n` frames.
    fn successors(&self, n: usize) -> Result<Vec<usize>> {
        if self.prev.len() != n {
            return Err(Error::Shape(format!(
                "{} predecessors for {n} frames",
                self.prev.len()
            )));
        }
        let mut next = vec![NONE; n];
        for (t, &p) in self.prev.iter().enumerate() {
            if p == NONE {
                continue;
            }
            if p >= n || p == t {
                return Err(Error::InvalidInput(format!(
                    "frame {t} has predecessor {p}, not another of the {n} frames"
                )));
            }
            if next[p] != NONE {
                return Err(Error::InvalidInput(format!(
                    "frames {} and {t} both follow frame {p}",
                    next[p]
                )));
            }
            next[p] = t;
        }
        // Every frame must be reached from a run's first frame: otherwise the links form a circle.
        let mut seen = 0;
        for t in (0..n).filter(|&t| self.prev[t] == NONE) {
            let mut f = t;
            while f != NONE {
                seen += 1;
                f = next[f];
            }
        }
        if seen != n {
            return Err(Error::InvalidInput(
                "the frames' predecessors form a circle".into(),
            ));
        }
        Ok(next)
    }
}

/// The links and ρ of a chain under the sticky prior.
#[derive(Clone, Debug)]
pub(super) struct Links {
    prior: StickyPrior,
    next: Vec<usize>,
    /// `link[t]`: frame `t` stays in its predecessor's pattern (never for a run's first frame).
    link: Vec<bool>,
    rho: f64,
    /// Segment moves proposed and accepted, over the run.
    pub(super) segment_moves: (u64, u64),
}

impl Links {
    pub(super) fn new(prior: StickyPrior, n: usize) -> Result<Self> {
        prior.validate()?;
        let next = prior.successors(n)?;
        let (a, b) = prior.rho_prior;
        let rho = prior.rho.unwrap_or(a / (a + b));
        Ok(Self {
            prior,
            next,
            link: vec![false; n],
            rho,
            segment_moves: (0, 0),
        })
    }

    fn prev(&self, t: usize) -> usize {
        self.prior.prev[t]
    }

    /// The frames of the segment holding `t` (its fresh draw first, in time order).
    pub(super) fn segment_of(&self, t: usize) -> Vec<usize> {
        let mut start = t;
        while self.link[start] {
            start = self.prev(start);
        }
        self.segment_from(start)
    }

    fn segment_from(&self, start: usize) -> Vec<usize> {
        let mut out = vec![start];
        let mut f = self.next[start];
        while f != NONE && self.link[f] {
            out.push(f);
            f = self.next[f];
        }
        out
    }

    /// The segments among `frames` (one pattern's members), in the order of their fresh draws
    /// in `frames`.
    pub(super) fn segments(&self, frames: &[usize]) -> Vec<Vec<usize>> {
        frames
            .iter()
            .filter(|&&f| !self.link[f])
            .map(|&f| self.segment_from(f))
            .collect()
    }
}

/// The prior side of frame `t`'s block update.
#[derive(Clone, Debug)]
pub(super) struct Block {
    /// The predecessor's pattern, or `NONE` when `t` starts a run (or, at initialisation, its
    /// predecessor has no pattern yet).
    a: usize,
    /// The successor's pattern, or `NONE`.
    b: usize,
    /// Fresh draws per slot, without those of `t` and its successor.
    m: Vec<usize>,
    total: usize,
    rho: f64,
    alpha: f64,
}

impl Block {
    /// `CRP(k | m + extra·δ_k)` with `total` draws: the count, or α for a table not in `m`.
    fn crp(&self, k: usize, extra: usize, total: usize) -> f64 {
        let mk = self.m.get(k).copied().unwrap_or(0) + extra;
        let w = if mk > 0 { mk as f64 } else { self.alpha };
        w / (self.alpha + total as f64)
    }

    /// Prior weight of each link option `(s_t, s_{t+1})` for pattern `k` (`NONE`: a new one);
    /// a missing link is reported as `false`.
    pub(super) fn options(&self, k: usize) -> [((bool, bool), f64); 4] {
        let (rho, a, b) = (self.rho, self.a, self.b);
        let mut out = [((false, false), 0.0); 4];
        for (o, st, sn) in [
            (0, true, true),
            (1, true, false),
            (2, false, true),
            (3, false, false),
        ] {
            if (st && (a == NONE || k != a)) || (sn && (b == NONE || k != b)) {
                continue;
            }
            let mut w = 1.0;
            if a != NONE {
                w *= if st { rho } else { 1.0 - rho };
            }
            if b != NONE {
                w *= if sn { rho } else { 1.0 - rho };
            }
            if !st {
                // Frame t's fresh draw joins k's table (a new one for k = NONE).
                w *= self.crp(k, 0, self.total);
            }
            if b != NONE && !sn {
                // Then the successor's fresh draw joins b's, t's draw included.
                let extra = usize::from(!st && k == b);
                w *= self.crp(b, extra, self.total + usize::from(!st));
            }
            out[o] = ((st, sn), w);
        }
        out
    }

    /// `log w_k`: the prior weight of pattern `k` (`NONE`: new), link options summed.
    pub(super) fn log_weight(&self, k: usize) -> f64 {
        self.options(k).iter().map(|o| o.1).sum::<f64>().ln()
    }

    /// Draw the links given pattern `k`; in MAP mode (`rng` None) the most probable.
    pub(super) fn draw_links(
        &self,
        k: usize,
        rng: Option<&mut dyn FnMut() -> f64>,
    ) -> (bool, bool) {
        let opts = self.options(k);
        match rng {
            None => {
                opts.iter()
                    .fold(opts[3], |best, o| if o.1 > best.1 { *o } else { best })
                    .0
            }
            Some(u) => {
                let total: f64 = opts.iter().map(|o| o.1).sum();
                let mut x = u() * total;
                for o in &opts {
                    x -= o.1;
                    if o.1 > 0.0 && x < 0.0 {
                        return o.0;
                    }
                }
                opts.iter()
                    .rev()
                    .find(|o| o.1 > 0.0)
                    .map_or(opts[3].0, |o| o.0)
            }
        }
    }
}

impl Sampler {
    /// The prior side of frame `t`'s update, or `None` without the sticky prior.
    pub(super) fn block(&self, t: usize) -> Option<Block> {
        let links = self.links.as_ref()?;
        let label = |f: usize| if f == NONE { NONE } else { self.labels[f] };
        let (a, b) = (label(links.prev(t)), label(links.next[t]));
        let succ = links.next[t];
        let mut m = vec![0; self.slots.len()];
        let mut total = 0;
        for (f, &k) in self.labels.iter().enumerate() {
            if f != t && f != succ && k != NONE && !links.link[f] {
                m[k] += 1;
                total += 1;
            }
        }
        Some(Block {
            a,
            b,
            m,
            total,
            rho: links.rho,
            alpha: self.alpha,
        })
    }

    /// Set frame `t`'s links after its pattern `k` (`NONE`: the new one) was chosen.
    pub(super) fn relink(
        &mut self,
        t: usize,
        block: &Block,
        k: usize,
        rng: Option<&mut dyn FnMut() -> f64>,
    ) {
        let (st, sn) = block.draw_links(k, rng);
        let links = self.links.as_mut().expect("a block comes with links");
        links.link[t] = block.a != NONE && st;
        if block.b != NONE {
            let succ = links.next[t];
            links.link[succ] = sn;
        }
    }

    /// After a state is set from outside: keep the links its labels allow, drop the others.
    pub(super) fn repair_links(&mut self) {
        let labels = &self.labels;
        if let Some(links) = self.links.as_mut() {
            for t in 0..labels.len() {
                let p = links.prev(t);
                links.link[t] &= p != NONE && labels[t] != NONE && labels[t] == labels[p];
            }
        }
    }

    /// Fresh draws per slot and in all, under the sticky prior.
    pub(super) fn fresh_counts(&self) -> Option<(Vec<usize>, usize)> {
        let links = self.links.as_ref()?;
        let mut m = vec![0; self.slots.len()];
        let mut total = 0;
        for (f, &k) in self.labels.iter().enumerate() {
            if k != NONE && !links.link[f] {
                m[k] += 1;
                total += 1;
            }
        }
        Some((m, total))
    }

    /// Links on and off (frames with a predecessor only).
    fn link_counts(&self) -> Option<(usize, usize)> {
        let links = self.links.as_ref()?;
        let with_prev = (0..self.labels.len()).filter(|&t| links.prev(t) != NONE);
        let on = links.link.iter().filter(|&&l| l).count();
        Some((on, with_prev.count() - on))
    }

    /// `log p(s | ρ)` (+ log p(ρ) when ρ is sampled), or 0 without the sticky prior.
    pub(super) fn links_log_prior(&self) -> f64 {
        let (Some(links), Some((on, off))) = (self.links.as_ref(), self.link_counts()) else {
            return 0.0;
        };
        let rho = links.rho;
        let mut total = on as f64 * rho.ln() + off as f64 * (1.0 - rho).ln();
        if links.prior.rho.is_none() {
            let (a, b) = links.prior.rho_prior;
            total += (a - 1.0) * rho.ln() + (b - 1.0) * (1.0 - rho).ln() + ln_gamma(a + b)
                - ln_gamma(a)
                - ln_gamma(b);
        }
        total
    }

    /// Conjugate update of ρ from the links: Beta(a + on, b + off).
    pub(super) fn update_rho(&mut self) -> Result<()> {
        let Some((on, off)) = self.link_counts() else {
            return Ok(());
        };
        let links = self.links.as_ref().expect("link counts come with links");
        if links.prior.rho.is_some() {
            return Ok(());
        }
        let (a, b) = links.prior.rho_prior;
        let beta = Beta::new(a + on as f64, b + off as f64)
            .map_err(|e| Error::InvalidInput(e.to_string()))?;
        let mut rng = stream(self.settings.seed, self.sweep, Phase::Sticky, 0);
        let rho: f64 = beta.sample(&mut rng);
        self.links.as_mut().expect("links").rho = rho.clamp(RHO_EDGE, 1.0 - RHO_EDGE);
        Ok(())
    }

    /// What a new pattern's prior weight adds to Algorithm 8's `log α` (0 without a block).
    pub(super) fn new_shift(&self, block: Option<&Block>) -> f64 {
        block.map_or(0.0, |b| b.log_weight(NONE) - self.alpha.ln())
    }

    /// ρ, under the sticky prior.
    pub fn stickiness(&self) -> Option<f64> {
        self.links.as_ref().map(|l| l.rho)
    }

    /// Each frame's link (`true`: it stays in its predecessor's pattern), under the sticky prior.
    pub fn links(&self) -> Option<&[bool]> {
        self.links.as_ref().map(|l| l.link.as_slice())
    }

    /// Set the links and ρ (a resumed chain); links the labels do not allow are dropped.
    pub fn set_links(&mut self, link: &[bool], rho: f64) -> Result<()> {
        let n = self.labels.len();
        let Some(links) = self.links.as_mut() else {
            return Err(Error::InvalidInput(
                "links need the sticky prior (dynamics)".into(),
            ));
        };
        if link.len() != n {
            return Err(Error::Shape(format!("{} links for {n} frames", link.len())));
        }
        if !(rho > 0.0 && rho < 1.0) {
            return Err(Error::InvalidInput(format!(
                "the stickiness must be in (0, 1), got {rho}"
            )));
        }
        links.link.copy_from_slice(link);
        links.rho = links.prior.rho.unwrap_or(rho);
        self.repair_links();
        Ok(())
    }

    /// The items split–merge allocates among `frames` (one pattern's members): its segments
    /// under the sticky prior, else each frame alone.
    pub(super) fn items(&self, frames: &[usize]) -> Vec<Vec<usize>> {
        match self.links.as_ref() {
            Some(l) => l.segments(frames),
            None => frames.iter().map(|&f| vec![f]).collect(),
        }
    }

    /// The item (segment, or the frame alone) holding frame `t`.
    pub(super) fn item_of(&self, t: usize) -> Vec<usize> {
        match self.links.as_ref() {
            Some(l) => l.segment_of(t),
            None => vec![t],
        }
    }
}

impl Sampler {
    /// Segment moves, after the frame updates: a segment whose neighbours (the frames before and
    /// after it) lie in two different patterns, its own one of them, is proposed to move whole
    /// to the other. The proposal is deterministic and its own reverse (the neighbours do not
    /// move), so the Metropolis ratio is the target's:
    /// `m_to / m_own · p(V_seg | D_to) / p(V_seg | D_own \ seg)`, with `m` the fresh draws
    /// without the segment's (its own pattern keeps the neighbour's). Links do not change. This
    /// moves a whole segment between the two patterns around it, which frame moves reach only
    /// through improbable states when ρ is large.
    pub(super) fn segment_moves(&mut self) -> Result<()> {
        let Some(links) = self.links.as_ref() else {
            return Ok(());
        };
        let segments: Vec<Vec<usize>> = (0..self.labels.len())
            .filter(|&t| !links.link[t])
            .map(|t| links.segment_from(t))
            .collect();
        let data = Arc::clone(&self.data);
        for (j, seg) in segments.iter().enumerate() {
            let links = self.links.as_ref().expect("links");
            let (p, q) = (links.prev(seg[0]), links.next[seg[seg.len() - 1]]);
            if p == NONE || q == NONE {
                continue;
            }
            let (a, b, own) = (self.labels[p], self.labels[q], self.labels[seg[0]]);
            if a == b || (own != a && own != b) || own == NONE {
                continue;
            }
            let to = if own == a { b } else { a };
            let (m, _) = self.fresh_counts().expect("links");
            // The neighbour in `own` is in another segment: `m[own] >= 2`.
            let (m_own, m_to) = ((m[own] - 1) as f64, m[to] as f64);
            let mut without = self.live_slot(own).pattern.clone();
            for &f in seg {
                without.remove(f)?;
            }
            let s_own = super::split_merge::item_score(without.as_ref(), &data, seg)?;
            let s_to =
                super::split_merge::item_score(self.live_slot(to).pattern.as_ref(), &data, seg)?;
            let log_ratio = m_to.ln() - m_own.ln() + s_to - s_own;
            self.links.as_mut().expect("links").segment_moves.0 += 1;
            let accept = match self.settings.assignment {
                super::Assignment::Map => log_ratio > 0.0,
                super::Assignment::Gibbs => {
                    let mut rng =
                        stream(self.settings.seed, self.sweep, Phase::Sticky, 1 + j as u64);
                    rng.random::<f64>().ln() < log_ratio
                }
            };
            if !accept {
                continue;
            }
            self.links.as_mut().expect("links").segment_moves.1 += 1;
            let version = self.fresh_version();
            let slot = self.live_slot_mut(own);
            slot.pattern = without;
            slot.version = version;
            for &f in seg {
                if let Some(c) = slot.cells.as_mut() {
                    c.add(data.frame(f), -1.0);
                }
            }
            for &f in seg {
                self.labels[f] = NONE;
                self.move_frame(f, NONE, to)?;
            }
        }
        Ok(())
    }
}

/// The rng of a block's link draw as a closure of uniforms.
pub(super) fn uniforms(rng: &mut impl rand::Rng) -> impl FnMut() -> f64 + '_ {
    move || rng.random::<f64>()
}

#[cfg(test)]
#[path = "tests/sticky.rs"]
mod tests;
