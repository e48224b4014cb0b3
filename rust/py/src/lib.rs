//! `dpgp._core`: the thin binding of dpgp-core. Arrays come in as zero-copy views, the GIL is
//! released around the numerics, and core errors become typed Python exceptions.

mod convert;
mod errors;
mod gp;
mod hsgp;
mod sampler;
mod simulate;

#[pyo3::pymodule(gil_used = false)]
mod _core {
    use pyo3::prelude::*;

    #[pymodule_export]
    use super::gp::{check_params, log_marginal_likelihood, log_predictive, posterior};
    #[pymodule_export]
    use super::hsgp::{
        hsgp_basis, hsgp_log_marginal_likelihood, hsgp_log_predictive, hsgp_posterior,
    };
    #[pymodule_export]
    use super::sampler::PySampler;
    #[pymodule_export]
    use super::simulate::{
        field_means, integrate_affine, motion_rollouts, rollouts, scene_rollouts,
    };

    #[pymodule_init]
    fn init(m: &Bound<'_, PyModule>) -> PyResult<()> {
        m.add("__version__", env!("CARGO_PKG_VERSION"))
    }
}
