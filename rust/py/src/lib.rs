//! `dpgp._core`: the thin binding of dpgp-core. Arrays come in as zero-copy views, the GIL is
//! released around the numerics, and core errors become typed Python exceptions.

// Numeric code indexes parallel arrays by one loop variable (clippy::needless_range_loop), and
// `!(x > 0.0)` is how a check also refuses NaN (clippy::neg_cmp_op_on_partial_ord); tuples of
// result arrays are clearer than one-use type aliases (clippy::type_complexity).
#![allow(
    clippy::needless_range_loop,
    clippy::neg_cmp_op_on_partial_ord,
    clippy::type_complexity
)]

mod convert;
mod criticality;
mod errors;
mod gp;
mod hsgp;
mod sampler;
mod settings;
mod shard;
mod simulate;

#[pyo3::pymodule(gil_used = false)]
mod _core {
    use pyo3::prelude::*;

    #[pymodule_export]
    use super::criticality::criticality;
    #[pymodule_export]
    use super::gp::{
        check_params, log_marginal_likelihood, log_predictive, log_predictive_frames,
        nearest_neighbour_sq, posterior,
    };
    #[pymodule_export]
    use super::hsgp::{
        heading_harmonics, hsgp_basis, hsgp_log_marginal_likelihood, hsgp_log_predictive,
        hsgp_posterior,
    };
    #[pymodule_export]
    use super::sampler::PySampler;
    #[pymodule_export]
    use super::settings::{check_length_scale_prior, check_settings};
    #[pymodule_export]
    use super::shard::PyShard;
    #[pymodule_export]
    use super::simulate::{
        field_means, integrate_affine, motion_rollouts, rollouts, scene_rollouts,
    };

    #[pymodule_init]
    fn init(m: &Bound<'_, PyModule>) -> PyResult<()> {
        use dpgp_core::gibbs;
        // The settings' limits, for Python to show (it checks none: the core does).
        m.add("MAX_THREADS", gibbs::MAX_THREADS)?;
        m.add("MAX_NEW_PATTERN_SAMPLES", gibbs::MAX_NEW_PATTERN_SAMPLES)?;
        m.add("MAX_SPLIT_MERGE_MOVES", gibbs::MAX_SPLIT_MERGE_MOVES)?;
        m.add("ALPHA_RANGE", gibbs::ALPHA_RANGE)?;
        m.add("LENGTH_SCALE_MEAN_RANGE", gibbs::LENGTH_SCALE_MEAN_RANGE)?;
        m.add("__version__", env!("CARGO_PKG_VERSION"))
    }
}
