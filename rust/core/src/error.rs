//! Errors a caller can cause. The binding crate maps each variant to a typed Python exception.

use thiserror::Error;

/// Everything that can go wrong in the core, as data (no panics on user input).
#[derive(Debug, Error, Clone, PartialEq)]
pub enum Error {
    /// A value is out of range: a non-positive length scale, a NaN, an unknown option.
    #[error("{0}")]
    InvalidInput(String),
    /// Arrays whose shapes do not fit together.
    #[error("{0}")]
    Shape(String),
    /// A covariance matrix stayed indefinite even after adding jitter to its diagonal.
    #[error(
        "the {what} covariance matrix ({n}x{n}) is not positive definite even with jitter {jitter:.3e} \
         added to its diagonal; check for duplicated points with zero noise or extreme length scales"
    )]
    NotPositiveDefinite {
        what: &'static str,
        n: usize,
        jitter: f64,
    },
    /// The fit would grow past its memory budget; nothing was allocated.
    #[error(
        "the fit needs about {:.1} MB for its patterns, over the memory budget of {:.1} MB \
         ({likelihood} likelihood); {}", *needed as f64 / 1e6, *budget as f64 / 1e6,
        if *likelihood == "exact" {
            "use likelihood=\"hsgp\" (its memory does not grow with the patterns' sizes) or raise memory_budget"
        } else {
            "use fewer basis functions (n_basis) or raise memory_budget"
        }
    )]
    MemoryBudget {
        needed: usize,
        budget: usize,
        likelihood: &'static str,
    },
    /// The caller asked the computation to stop (Ctrl-C).
    #[error("interrupted")]
    Interrupted,
    /// Shards served elsewhere could not answer (a worker or the scheduler failed).
    #[error("the frames' shards could not be reached: {0}")]
    Link(String),
    /// A shard does not hold a chain's labels (a worker that replaced a lost one): the leader
    /// sets them again and redoes the sweeps since its copy.
    #[error("{0}")]
    LabelsLost(String),
}

pub type Result<T> = std::result::Result<T, Error>;

/// Fail with `InvalidInput` unless every value is finite.
pub fn check_finite(name: &str, values: &[f64]) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(Error::InvalidInput(format!(
            "{name} contains a non-finite value ({}) at flat index {i}; remove or impute NaN/inf values",
            values[i]
        ))),
    }
}

/// The error for a setting given a name it does not know, listing the names it knows.
pub fn unknown_option(setting: &str, allowed: &[&str], got: &str) -> Error {
    let allowed: Vec<String> = allowed.iter().map(|a| format!("'{a}'")).collect();
    Error::InvalidInput(format!(
        "{setting} must be one of {}; got {got:?}",
        allowed.join(", ")
    ))
}
