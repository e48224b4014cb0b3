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
//! Why global: one pair shared by all patterns is estimated from all frames and keeps the
//! split–merge ratio free of noise proposals. A per-pattern noise, measured at the fitted
//! partition (benches/noise_per_pattern.py), scores better held out on three of six shared data
//! sets and is recommended; it is not implemented here (docs/inference.md).

use rayon::prelude::*;

use super::Sampler;
use crate::error::{Error, Result};
use crate::gp::GpParams;
use crate::pattern_model::PatternModel;
use crate::rng::{Phase, stream};
use crate::slice::slice_step;

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
}

/// Least noise, as a share of the velocity variance, a candidate may take: below it the
/// factors of repeated positions fail in double precision (model.py's MIN_NOISE_RATIO).
const MIN_RATIO: f64 = 1e-10;
/// Slice width on the log scale: about four posterior sds of `log σ_n²`, which shrinks like
/// `sqrt(2 / points)`; set by the data's size only, so the update stays a valid slice step.
fn width(points: usize) -> f64 {
    (4.0 * (2.0 / points.max(1) as f64).sqrt()).clamp(0.05, 1.0)
}

impl Sampler {
    /// The noise pair the chain is at (fixed, or the last draw).
    pub fn noise_var(&self) -> [f64; 2] {
        self.settings.base.noise_var
    }

    /// Put the chain at the noise pair `noise` (a resumed chain): every pattern is refactored.
    pub fn set_noise_var(&mut self, noise: [f64; 2]) -> Result<()> {
        if !noise.iter().all(|v| v.is_finite() && *v > 0.0) {
            return Err(Error::InvalidInput(format!(
                "noise_var must be two positive variances, got {noise:?}"
            )));
        }
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

    /// The prior's log density of the current noise pair (0 when the noise is fixed).
    pub(super) fn noise_log_prior(&self) -> f64 {
        let Some(prior) = self.settings.noise_prior else {
            return 0.0;
        };
        let b = &self.settings.base;
        (0..2)
            .map(|d| prior.log_density(b.noise_var[d].ln(), b.signal_var[d]))
            .sum()
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

    /// Slice-sample `log σ_n,x²` then `log σ_n,y²` (when the noise prior is set).
    pub(super) fn update_noise(&mut self) -> Result<()> {
        let Some(prior) = self.settings.noise_prior else {
            return Ok(());
        };
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
            let mut last: Option<(f64, Vec<Box<dyn PatternModel>>)> = None;
            let (x, _) = slice_step(x0, f0, width(self.data.xy.len()), &mut rng, |x| {
                let v = x.exp();
                if !(v.is_finite() && v >= MIN_RATIO * scale[d]) {
                    return f64::NEG_INFINITY;
                }
                let mut noise = noise0;
                noise[d] = v;
                match self.with_noise(&slots, noise) {
                    Ok(ps) => {
                        let lm: f64 = ps.iter().map(|p| p.log_marginal()).sum();
                        last = Some((x, ps));
                        prior.log_density(x, scale[d]) + lm
                    }
                    Err(_) => f64::NEG_INFINITY,
                }
            });
            if x == x0 {
                continue;
            }
            let ps = match last {
                Some((lx, ps)) if lx == x => ps,
                // The accepted point was not the last evaluated: rebuild there.
                _ => {
                    let mut noise = noise0;
                    noise[d] = x.exp();
                    self.with_noise(&slots, noise)?
                }
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
mod tests;
