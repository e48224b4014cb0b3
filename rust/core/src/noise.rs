//! The observation noise `(σ_n,x², σ_n,y²)` sampled inside the chain.
//!
//! One noise variance per velocity component, shared by every pattern (global). Each sweep
//! slice-samples `log σ_n,d²` for d = x, y from
//!
//! `p(log σ_n,d² | z, w, V) ∝ N(log(σ_n,d² / s_d²); m, τ²) · Π_k p(D_k | w_k, σ_n²)`,
//!
//! a weakly informative log-normal prior on the noise *as a share of the component's velocity
//! variance* `s_d²` (the data's, `Settings::base.signal_var`), so that converting units scales
//! the noise with the data and leaves the chain unchanged. Every candidate refactors every
//! pattern (in parallel); the factors at the accepted point become the patterns' factors.
//!
//! Two scopes ([`NoiseScope`]). **Global** (the core's default, `noise_var="global"` in Python):
//! one pair shared by all patterns, estimated from all frames. **Per pattern** (Python's default,
//! `noise_var="auto"`): each pattern's `GpParams::noise_var` is its own,
//! under the same prior; each sweep slice-samples every pattern's `log σ_n,x²` then `log σ_n,y²`
//! from `N(log(σ_n,d² / s_d²); m, τ²) · p(D_k | w_k, σ_n,k²)`, in parallel over patterns, each
//! pattern on its own random stream (keyed by its stable id, as the length-scale step), so the
//! chain does not depend on the thread count. A new pattern (Algorithm 8's auxiliaries, the
//! new-pattern term of scores, the second pattern of a split) draws its noise pair from the prior
//! with its length scales; a split's second pattern may instead draw it near the split pattern's
//! (split_merge.rs). Per pattern scores better held out and mixes better on US-101
//! (docs/inference.md, "The default: a noise pair per pattern").

use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use super::{Sampler, Settings};
use crate::error::{Error, Result, unknown_option};
use crate::gp::GpParams;
use crate::pattern_model::PatternModel;
use crate::rng::{Phase, stream};

/// Prior of the noise: `log(σ_n,d² / s_d²) ~ N(log_mean, sd²)` for each component d.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoisePrior {
    pub log_mean: f64,
    pub sd: f64,
}

impl NoisePrior {
    pub fn validate(&self) -> Result<()> {
        if !(self.log_mean.is_finite() && self.sd.is_finite() && self.sd > 0.0) {
            return Err(Error::InvalidInput(format!(
                "the noise prior needs a finite log mean and a positive sd, got ({}, {})",
                self.log_mean, self.sd
            )));
        }
        Ok(())
    }

    /// Log density of `x = log σ_n²` given the component's velocity variance `scale`.
    pub fn log_density(&self, x: f64, scale: f64) -> f64 {
        let z = (x - scale.ln() - self.log_mean) / self.sd;
        -0.5 * z * z - self.sd.ln() - 0.5 * crate::gp::LN_2PI
    }

    /// A draw of the noise pair from the prior given the velocity variances `scale` (x then y),
    /// kept at least [`MIN_RATIO`] times them (the prior puts ~1e-23 of its mass below that).
    pub fn sample(&self, scale: [f64; 2], rng: &mut impl rand::Rng) -> [f64; 2] {
        scale.map(|s| {
            let z: f64 = StandardNormal.sample(rng);
            (s.ln() + self.log_mean + self.sd * z)
                .exp()
                .max(MIN_RATIO * s)
        })
    }
}

/// The noise of new patterns, from the settings alone.
impl Settings {
    /// Whether each pattern samples its own noise pair.
    pub(crate) fn per_pattern_noise(&self) -> bool {
        self.noise_scope == NoiseScope::PerPattern && self.noise_prior.is_some()
    }

    /// Whether a noise pair is where the chain's noise may be: at least [`MIN_RATIO`] times
    /// each component's velocity variance, and finite.
    pub(crate) fn noise_in_support(&self, noise: [f64; 2]) -> bool {
        let scale = self.base.signal_var;
        (0..2).all(|d| noise[d].is_finite() && noise[d] >= MIN_RATIO * scale[d])
    }

    /// A new pattern's noise pair: a prior draw per pattern, else the chain's pair.
    pub(crate) fn new_noise(&self, rng: &mut impl rand::Rng) -> [f64; 2] {
        match self.noise_prior {
            Some(prior) if self.noise_scope == NoiseScope::PerPattern => {
                prior.sample(self.base.signal_var, rng)
            }
            _ => self.base.noise_var,
        }
    }
}

/// Whether the noise pair is one for all patterns or each pattern's own.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum NoiseScope {
    /// One pair shared by every pattern.
    #[default]
    Global,
    /// Each pattern has its own pair (sampled only with a noise prior).
    PerPattern,
}

impl std::str::FromStr for NoiseScope {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "global" => Ok(Self::Global),
            "per_pattern" => Ok(Self::PerPattern),
            _ => Err(unknown_option("noise_scope", &["global", "per_pattern"], s)),
        }
    }
}

/// Least noise, as a share of the velocity variance, a candidate may take: below it the
/// factors of repeated positions fail in double precision (model.py's MIN_NOISE_RATIO).
pub(crate) const MIN_RATIO: f64 = 1e-10;
/// Slice width on the log scale: about four posterior sds of `log σ_n²`, which shrinks like
/// `sqrt(2 / points)`; set by the data's size only, so the update stays a valid slice step.
pub(crate) fn width(points: usize) -> f64 {
    (4.0 * (2.0 / points.max(1) as f64).sqrt()).clamp(0.05, 1.0)
}

/// A noise pair a chain may be put at: two finite positive variances.
pub(crate) fn check_noise_pair(noise: [f64; 2]) -> Result<()> {
    if noise.iter().all(|v| v.is_finite() && *v > 0.0) {
        Ok(())
    } else {
        Err(Error::InvalidInput(format!(
            "noise_var must be two positive variances, got {noise:?}"
        )))
    }
}

impl Sampler {
    /// The noise pair the chain is at (fixed, or the last draw); per pattern, the pair new
    /// patterns' noise is not drawn from but the chain started at (see [`Sampler::patterns`]).
    pub fn noise_var(&self) -> [f64; 2] {
        self.settings.base.noise_var
    }

    /// Put the chain at the noise pair `noise` (a resumed chain): every pattern is refactored.
    pub fn set_noise_var(&mut self, noise: [f64; 2]) -> Result<()> {
        check_noise_pair(noise)?;
        if noise == self.settings.base.noise_var {
            return Ok(());
        }
        let slots: Vec<usize> = self.live().map(|(k, _)| k).collect();
        let ps = self.with_noise(&slots, noise)?;
        self.install_noise(noise, &slots, ps);
        Ok(())
    }

    /// Make `noise` the chain's noise pair and `ps` (the patterns of `slots` under it) theirs.
    fn install_noise(&mut self, noise: [f64; 2], slots: &[usize], ps: Vec<Box<dyn PatternModel>>) {
        self.settings.base.noise_var = noise;
        for (&k, p) in slots.iter().zip(ps) {
            let v = self.fresh_version();
            let slot = self.live_slot_mut(k);
            slot.pattern = p;
            slot.version = v;
        }
    }

    /// The prior's log density of the current noise pair, or of every pattern's pair per
    /// pattern (0 when the noise is fixed).
    pub(super) fn noise_log_prior(&self) -> f64 {
        let Some(prior) = self.settings.noise_prior else {
            return 0.0;
        };
        let b = &self.settings.base;
        let pair = |n: [f64; 2]| -> f64 {
            (0..2)
                .map(|d| prior.log_density(n[d].ln(), b.signal_var[d]))
                .sum()
        };
        match self.settings.noise_scope {
            NoiseScope::Global => pair(b.noise_var),
            NoiseScope::PerPattern => self
                .live()
                .map(|(_, s)| pair(s.pattern.params().noise_var))
                .sum(),
        }
    }

    /// Slice-sample each pattern's `log σ_n,x²` then `log σ_n,y²` (per-pattern noise), in
    /// parallel over patterns, each on its own stream keyed by the pattern's stable id. The width
    /// is [`width`] of the pattern's point count (fixed during the step).
    fn update_noise_per_pattern(&mut self, prior: NoisePrior) -> Result<()> {
        let keys: Vec<(usize, u64)> = self.patterns().iter().map(|p| (p.slot, p.id)).collect();
        self.check_memory(self.candidate_bytes())?;
        let (seed, sweep) = (self.settings.seed, self.sweep);
        let scale = self.settings.base.signal_var;
        let updated: Vec<Result<Option<Box<dyn PatternModel>>>> = keys
            .par_iter()
            .map(|&(k, id)| {
                let mut rng = stream(seed, sweep, Phase::Noise, id);
                super::hyper::noise_step(&self.live_slot(k).pattern, prior, scale, &mut rng)
            })
            .collect();
        for ((k, _), p) in keys.iter().zip(updated) {
            if let Some(p) = p? {
                let v = self.fresh_version();
                let slot = self.live_slot_mut(*k);
                slot.pattern = p;
                slot.version = v;
            }
        }
        Ok(())
    }

    /// The patterns in `slots` refactored under the noise pair `noise` (in parallel).
    fn with_noise(&self, slots: &[usize], noise: [f64; 2]) -> Result<Vec<Box<dyn PatternModel>>> {
        slots
            .par_iter()
            .map(|&k| {
                let p = &self.live_slot(k).pattern;
                p.with_params(GpParams {
                    noise_var: noise,
                    ..*p.params()
                })
            })
            .collect()
    }

    /// Slice-sample `log σ_n,x²` then `log σ_n,y²` (when the noise prior is set): the global
    /// pair, or each pattern's own.
    pub(super) fn update_noise(&mut self) -> Result<()> {
        let Some(prior) = self.settings.noise_prior else {
            return Ok(());
        };
        if self.settings.noise_scope == NoiseScope::PerPattern {
            return self.update_noise_per_pattern(prior);
        }
        let slots: Vec<usize> = self.live().map(|(k, _)| k).collect();
        // Each candidate holds a second copy of every pattern.
        let held: usize = self.live().map(|(_, s)| s.pattern.bytes()).sum();
        self.check_memory(held)?;
        let mut rng = stream(self.settings.seed, self.sweep, Phase::Noise, 0);
        let scale = self.settings.base.signal_var;
        for d in 0..2 {
            let noise0 = self.settings.base.noise_var;
            let x0 = noise0[d].ln();
            let data_term: f64 = self.live().map(|(_, s)| s.pattern.log_marginal()).sum();
            let f0 = prior.log_density(x0, scale[d]) + data_term;
            let step = crate::gibbs::global_noise_step(
                x0,
                f0,
                self.data.xy.len(),
                prior,
                scale[d],
                &mut rng,
                |x| {
                    let mut noise = noise0;
                    noise[d] = x.exp();
                    let ps = self.with_noise(&slots, noise)?;
                    Ok((ps.iter().map(|p| p.log_marginal()).sum(), ps))
                },
            )?;
            let Some((x, ps)) = step else {
                continue;
            };
            let mut noise = noise0;
            noise[d] = x.exp();
            self.install_noise(noise, &slots, ps);
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "tests/noise.rs"]
pub(crate) mod tests;
