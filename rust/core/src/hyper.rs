//! One pattern's hyperparameter steps, written once for every sampler: slice sampling of its
//! `(log w_x, log w_y)` and of its own noise pair, given whatever the pattern holds of its frames
//! (the collapsed sampler's factor, the sub-cluster sampler's sums). Each candidate is a refitted
//! copy of the pattern; the copy at the accepted point becomes the pattern.

use rand::RngExt;

use super::noise::{MIN_RATIO, NoisePrior, width};
use crate::error::Result;
use crate::gp::GpParams;
use crate::slice::slice_step;
use crate::special::ln_gamma_pdf;

/// A pattern that can be scored under other hyperparameters: what the slice steps need.
pub(crate) trait Refit: Sized {
    fn params(&self) -> &GpParams;
    /// `log p(D_k | θ)`.
    fn log_marginal(&self) -> f64;
    fn n_points(&self) -> usize;
    /// The same frames under `params`.
    fn refit(&self, params: GpParams) -> Result<Self>;
}

/// Log density of a pattern's length scales (with the log-scale Jacobian) and data, under the
/// Gamma `priors` of the sampled coordinates `(w_x, w_y[, w_h])`.
pub(crate) fn ls_log_target<P: Refit>(p: &P, priors: &[(f64, f64)]) -> f64 {
    let ls = p.params().length_scales;
    priors
        .iter()
        .enumerate()
        .map(|(i, &(a, b))| ln_gamma_pdf(ls.coord(i), a, b) + ls.coord(i).ln())
        .sum::<f64>()
        + p.log_marginal()
}

/// Slice-sample `log w_x`, `log w_y` (and `log w_h` when `priors` has a third entry) of
/// `current` in turn under their Gamma `priors`, slices of `width` on the log scale; with
/// `fraction` below 1, only that share of calls updates (a uniform drawn first decides).
pub(crate) fn length_scale_step<P: Refit>(
    mut current: P,
    priors: &[(f64, f64)],
    fraction: f64,
    width: f64,
    rng: &mut impl rand::Rng,
) -> P {
    if fraction < 1.0 && rng.random::<f64>() >= fraction {
        return current;
    }
    let mut f0 = ls_log_target(&current, priors);
    for axis in 0..priors.len() {
        let params = *current.params();
        let ls = params.length_scales;
        let x0 = ls.coord(axis).ln();
        let mut last: Option<(f64, P)> = None;
        let (x, fx) = slice_step(x0, f0, width, rng, |x| {
            let w = x.exp();
            if !(w.is_finite() && w > 0.0) {
                return f64::NEG_INFINITY;
            }
            let cand = ls.with_coord(axis, w);
            match current.refit(params.with_length_scales(cand)) {
                Ok(p) => {
                    let f = ls_log_target(&p, priors);
                    last = Some((x, p));
                    f
                }
                Err(_) => f64::NEG_INFINITY,
            }
        });
        if let Some((lx, p)) = last
            && lx == x
            && x != x0
        {
            current = p;
            f0 = fx;
        }
    }
    current
}

/// Slice-sample the pattern's own `log σ_n,x²` then `log σ_n,y²` under `prior` (relative to the
/// velocity variances `scale`); `None` if neither moved.
pub(crate) fn noise_step<P: Refit>(
    p0: &P,
    prior: NoisePrior,
    scale: [f64; 2],
    rng: &mut impl rand::Rng,
) -> Result<Option<P>> {
    let w = width(p0.n_points());
    let mut current: Option<P> = None;
    for d in 0..2 {
        let cur: &P = current.as_ref().unwrap_or(p0);
        let params = *cur.params();
        let x0 = params.noise_var[d].ln();
        let f0 = prior.log_density(x0, scale[d]) + cur.log_marginal();
        let at = |x: f64| {
            let mut noise_var = params.noise_var;
            noise_var[d] = x.exp();
            GpParams {
                noise_var,
                ..params
            }
        };
        let mut last: Option<(f64, P)> = None;
        let (x, _) = slice_step(x0, f0, w, rng, |x| {
            let v = x.exp();
            if !(v.is_finite() && v >= MIN_RATIO * scale[d]) {
                return f64::NEG_INFINITY;
            }
            match cur.refit(at(x)) {
                Ok(p) => {
                    let lm = p.log_marginal();
                    last = Some((x, p));
                    prior.log_density(x, scale[d]) + lm
                }
                Err(_) => f64::NEG_INFINITY,
            }
        });
        if x == x0 {
            continue;
        }
        let p = match last {
            Some((lx, p)) if lx == x => p,
            _ => cur.refit(at(x))?,
        };
        current = Some(p);
    }
    Ok(current)
}

/// Slice width for a pattern's `log w` given its points: the posterior of a length scale narrows
/// like `1 / √points`, so a fixed width spends most evaluations shrinking on large patterns. Set
/// by the pattern's size only (fixed during the step), so the update stays a valid slice step.
pub(crate) fn length_scale_width(points: usize) -> f64 {
    (0.5 * (1000.0 / points.max(1) as f64).sqrt()).clamp(0.02, 0.5)
}

/// One slice step of a noise pair shared by every pattern (`noise_var="global"`), on the log
/// scale of component `d`: `refit(x)` refits every pattern at `log σ_n,d² = x` and gives their
/// summed log marginal with the refits. Returns the accepted `x` and its refits, `None` if it
/// stayed at `x0`. Written once for both samplers (their patterns differ, the step does not).
#[allow(clippy::too_many_arguments)]
pub(crate) fn global_noise_step<T>(
    x0: f64,
    f0: f64,
    points: usize,
    prior: NoisePrior,
    scale: f64,
    rng: &mut impl rand::Rng,
    refit: impl Fn(f64) -> Result<(f64, T)>,
) -> Result<Option<(f64, T)>> {
    let mut last: Option<(f64, T)> = None;
    let (x, _) = slice_step(x0, f0, width(points), rng, |x| {
        let v = x.exp();
        if !(v.is_finite() && v >= MIN_RATIO * scale) {
            return f64::NEG_INFINITY;
        }
        match refit(x) {
            Ok((lm, fits)) => {
                last = Some((x, fits));
                prior.log_density(x, scale) + lm
            }
            Err(_) => f64::NEG_INFINITY,
        }
    });
    if x == x0 {
        return Ok(None);
    }
    // The accepted point was not the last evaluated: refit there.
    let fits = match last {
        Some((lx, fits)) if lx == x => fits,
        _ => refit(x)?.1,
    };
    Ok(Some((x, fits)))
}
