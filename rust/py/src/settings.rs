//! The sampler's settings as they cross the binding: one Python dict, extracted into
//! [`SamplerSettings`] and converted into the core's `gibbs::Settings`. The binding only converts
//! types; names are parsed and every rule and limit is checked by the core (`FromStr` of its
//! enums, `Settings::validate`, `gibbs::check_threads`), so Python validates none of them.

use std::sync::Arc;

use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict};

use crate::errors::{CoreError, InvalidInputError};
use crate::gp::{ParamTuple, params};
use crate::hsgp::BasisTuple;
use dpgp_core::gibbs::{
    NoisePrior, SamplerKind, Settings, SplitMerge, StickyPrior,
    check_length_scale_prior as core_check_prior, check_threads,
};
use dpgp_core::hsgp::Basis;
use dpgp_core::pattern_model::{Likelihood, LikelihoodKind};

/// The keys a user sets are required; those the estimator resolves from the data (`params`,
/// `length_scale_prior`, `likelihood` and its `basis`, `memory_budget`, `noise_prior`) may be
/// missing and then take `Settings::default()`'s values, so that the settings a user gave can be
/// checked (`check_settings`) before the data-driven defaults and pilots run.
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
pub struct SamplerSettings {
    assignment: String,
    proposal: String,
    split_merge_pairs: String,
    fixed_length_scales: bool,
    /// `None` samples α.
    alpha: Option<f64>,
    new_pattern_samples: usize,
    /// Any integer: its low 64 bits key the random streams.
    #[pyo3(from_py_with = seed_bits)]
    seed: u64,
    /// `None`: one thread per core.
    n_threads: Option<usize>,
    length_scale_fraction: f64,
    pattern_moments: bool,
    /// Moves per sweep.
    split_merge: usize,
    #[pyo3(default)]
    likelihood: Option<String>,
    #[pyo3(default)]
    basis: Option<BasisTuple>,
    #[pyo3(default)]
    params: Option<ParamTuple>,
    #[pyo3(default)]
    length_scale_prior: Option<(f64, f64)>,
    /// Bytes; `None`: no limit.
    #[pyo3(default)]
    memory_budget: Option<usize>,
    /// `(log mean, sd)`; `None` keeps the noise fixed.
    #[pyo3(default)]
    noise_prior: Option<(f64, f64)>,
    /// "global" or "per_pattern" (parsed by the core); `None`: global.
    #[pyo3(default)]
    noise_scope: Option<String>,
    /// The sticky prior: each frame's predecessor (-1: a run's first frame), the Beta prior of ρ,
    /// and a fixed ρ or `None`; `None` for the independent DP.
    #[pyo3(default)]
    dynamics: Option<(Vec<i64>, (f64, f64), Option<f64>)>,
    /// "collapsed" or "subcluster" (parsed by the core); `None`: collapsed.
    #[pyo3(default)]
    sampler: Option<String>,
    /// Gamma(shape, scale) prior of the heading length scale (radians): fields over position
    /// and previous heading. `None`: over position only.
    #[pyo3(default)]
    heading_prior: Option<(f64, f64)>,
    /// Heading harmonics of the reduced-rank basis (with `heading_prior`); `None`: 0.
    #[pyo3(default)]
    heading_harmonics: Option<usize>,
    /// Position functions per axis of the basis's heading blocks; `None`: the position counts.
    #[pyo3(default)]
    heading_counts: Option<(usize, usize)>,
}

/// Keys whose value is a bool; anywhere else a bool is a mistake, though Python counts it as 1.
const BOOL_KEYS: [&str; 2] = ["fixed_length_scales", "pattern_moments"];
/// The struct's fields: the dict may hold no other key (a misspelt one would silently take its
/// default), and a field missing here is refused at once as unknown, so the two cannot drift.
const KEYS: [&str; 23] = [
    "assignment",
    "likelihood",
    "proposal",
    "split_merge_pairs",
    "params",
    "fixed_length_scales",
    "length_scale_prior",
    "alpha",
    "new_pattern_samples",
    "seed",
    "n_threads",
    "length_scale_fraction",
    "pattern_moments",
    "basis",
    "memory_budget",
    "split_merge",
    "noise_prior",
    "noise_scope",
    "dynamics",
    "sampler",
    "heading_prior",
    "heading_harmonics",
    "heading_counts",
];

/// A value's repr cut to 40 characters (a 300-digit integer says nothing more).
fn short(repr: &str) -> String {
    match repr.char_indices().nth(40) {
        Some((i, _)) => format!("{}...", &repr[..i]),
        None => repr.to_string(),
    }
}

fn seed_bits(obj: &Bound<'_, PyAny>) -> PyResult<u64> {
    // operator.index takes Python and numpy integers and refuses floats, strings and None.
    let i = obj.py().import("operator")?.call_method1("index", (obj,))?;
    i.call_method1("__and__", (u64::MAX,))?.extract()
}

impl SamplerSettings {
    /// Extract a dict of settings; a value of the wrong type (a string for a count, a negative
    /// or too large integer, an unknown key) is an `InvalidInputError` naming the setting.
    pub fn extract(obj: &Bound<'_, PyAny>) -> PyResult<Self> {
        let dict = obj
            .cast::<PyDict>()
            .map_err(|_| InvalidInputError::new_err("the sampler settings must be a dict"))?;
        for (k, v) in dict.iter() {
            let key: String = k.extract()?;
            if !KEYS.contains(&key.as_str()) {
                return Err(InvalidInputError::new_err(format!(
                    "unknown sampler setting {key:?}; known: {KEYS:?}"
                )));
            }
            if v.is_instance_of::<PyBool>() && !BOOL_KEYS.contains(&key.as_str()) {
                return Err(InvalidInputError::new_err(format!(
                    "{key} must not be a bool, got {}",
                    v.repr()?
                )));
            }
        }
        obj.extract().map_err(|e: PyErr| {
            let py = obj.py();
            // pyo3 says which field failed ("failed to extract field SamplerSettings.alpha") and
            // puts the reason in the cause; name the setting and the value as a user wrote them.
            let field = KEYS
                .iter()
                .find(|k| e.to_string().ends_with(&format!("SamplerSettings.{k}")))
                .copied()
                .unwrap_or("a sampler setting");
            let value = dict
                .get_item(field)
                .ok()
                .flatten()
                .and_then(|v| v.repr().ok().map(|r| short(&r.to_string())))
                .unwrap_or_default();
            let why = e.cause(py).map(|c| c.to_string()).unwrap_or(e.to_string());
            InvalidInputError::new_err(format!("{field} has the wrong type: got {value} ({why})"))
        })
    }

    /// The core's settings, validated, and the thread count (0: one per core). Without a basis,
    /// likelihood "hsgp" is only checked by name (`partial`: an early check, before the data
    /// have sized the basis).
    pub fn into_core(self, partial: bool) -> PyResult<(Settings, usize)> {
        let d = Settings::default();
        let likelihood_given = self.likelihood.is_some();
        let kind = match self.likelihood {
            Some(name) => name.parse().map_err(CoreError)?,
            None => LikelihoodKind::Exact,
        };
        let harmonics = self.heading_harmonics.unwrap_or(0);
        let heading_counts = self.heading_counts;
        let basis = self
            .basis
            .map(|b| -> PyResult<Arc<Basis>> {
                Ok(Arc::new(crate::hsgp::headed_basis(
                    b,
                    harmonics,
                    heading_counts,
                )?))
            })
            .transpose()?;
        let sampler: SamplerKind = match self.sampler {
            Some(name) => name.parse().map_err(CoreError)?,
            None => SamplerKind::Collapsed,
        };
        // An early check has no basis yet: a stand-in box for likelihood "hsgp", and for an
        // undecided likelihood ("auto") of the sub-cluster sampler, which needs hsgp.
        let stand_in = || Basis::new([0.0, 0.0], [1.0, 1.0], [1, 1]).map(Arc::new);
        let likelihood = match (kind, basis, partial) {
            (LikelihoodKind::Hsgp, None, true) => Likelihood::Hsgp(stand_in().map_err(CoreError)?),
            (LikelihoodKind::Exact, _, true)
                if !likelihood_given && sampler == SamplerKind::Subcluster =>
            {
                Likelihood::Hsgp(stand_in().map_err(CoreError)?)
            }
            (k, b, _) => Likelihood::new(k, b).map_err(CoreError)?,
        };
        let settings = Settings {
            assignment: self.assignment.parse().map_err(CoreError)?,
            base: self.params.map(params).transpose()?.unwrap_or(d.base),
            fixed_length_scales: self.fixed_length_scales,
            length_scale_prior: self.length_scale_prior.unwrap_or(d.length_scale_prior),
            heading_prior: self.heading_prior,
            alpha: self.alpha,
            new_pattern_samples: self.new_pattern_samples,
            pattern_moments: self.pattern_moments,
            length_scale_fraction: self.length_scale_fraction,
            seed: self.seed,
            likelihood,
            proposal: self.proposal.parse().map_err(CoreError)?,
            memory_budget: self.memory_budget,
            split_merge: SplitMerge {
                moves_per_sweep: self.split_merge,
                pairs: self.split_merge_pairs.parse().map_err(CoreError)?,
            },
            noise_prior: self
                .noise_prior
                .map(|(log_mean, sd)| NoisePrior { log_mean, sd }),
            noise_scope: match self.noise_scope {
                Some(name) => name.parse().map_err(CoreError)?,
                None => d.noise_scope,
            },
            dynamics: self.dynamics.map(sticky).transpose()?,
            sampler,
        };
        settings.validate().map_err(CoreError)?;
        let threads = check_threads(self.n_threads).map_err(CoreError)?;
        Ok((settings, threads))
    }
}

/// The core's sticky prior from the predecessors (-1 for none) as Python gives them.
fn sticky((prev, rho_prior, rho): (Vec<i64>, (f64, f64), Option<f64>)) -> PyResult<StickyPrior> {
    let prev = prev
        .into_iter()
        .map(|p| match p {
            -1 => Ok(usize::MAX),
            p => usize::try_from(p).map_err(|_| {
                InvalidInputError::new_err(format!(
                    "a predecessor must be a frame index or -1, got {p}"
                ))
            }),
        })
        .collect::<PyResult<Vec<usize>>>()?;
    Ok(StickyPrior {
        prev: prev.into(),
        rho,
        rho_prior,
    })
}

/// Check sampler settings without data: every rule the core applies when a sampler is built,
/// for the settings given (`dpgp.DPGP.fit` calls it before any pilot or data-driven default).
#[pyfunction]
pub fn check_settings(settings: &Bound<'_, PyAny>) -> PyResult<()> {
    SamplerSettings::extract(settings)?
        .into_core(true)
        .map(|_| ())
}

/// The core's rule of a Gamma(shape, scale) length-scale prior, for a prior Python has before any
/// sampler exists (given by the user, or read from a model file).
#[pyfunction]
pub fn check_length_scale_prior(prior: (f64, f64)) -> PyResult<()> {
    core_check_prior(prior).map_err(|e| CoreError(e).into())
}
