//! Bindings of the exact GP layer (`dpgp.gp` wraps these).

use numpy::{PyArray2, PyReadonlyArray2};
use pyo3::prelude::*;

use crate::convert::{pairs, to_numpy};
use crate::errors::CoreResult;
use dpgp_core::gp::{self, GpParams};
use dpgp_core::linalg::par_for;

/// `(w_x, w_y, σ_x², σ_y², σ_n,x², σ_n,y², μ_x, μ_y)` as passed from Python.
pub type ParamTuple = (f64, f64, f64, f64, f64, f64, f64, f64);

pub fn params(t: ParamTuple) -> CoreResult<GpParams> {
    Ok(GpParams::new(
        (t.0, t.1),
        (t.2, t.3),
        (t.4, t.5),
        (t.6, t.7),
    )?)
}

/// Validate a parameter tuple; raises InvalidInputError naming the bad value.
#[pyfunction]
pub fn check_params(p: ParamTuple) -> CoreResult<()> {
    params(p).map(|_| ())
}

#[pyfunction]
pub fn log_marginal_likelihood(
    py: Python<'_>,
    xy: PyReadonlyArray2<'_, f64>,
    v: PyReadonlyArray2<'_, f64>,
    p: ParamTuple,
) -> CoreResult<f64> {
    let (xy, v, p) = (pairs("xy", &xy)?, pairs("v", &v)?, params(p)?);
    py.detach(|| Ok(gp::log_marginal_likelihood(xy, v, &p, par_for(xy.len()))?))
}

#[pyfunction]
pub fn log_predictive(
    py: Python<'_>,
    train_xy: PyReadonlyArray2<'_, f64>,
    train_v: PyReadonlyArray2<'_, f64>,
    test_xy: PyReadonlyArray2<'_, f64>,
    test_v: PyReadonlyArray2<'_, f64>,
    p: ParamTuple,
) -> CoreResult<f64> {
    let (txy, tv) = (pairs("train_xy", &train_xy)?, pairs("train_v", &train_v)?);
    let (sxy, sv) = (pairs("test_xy", &test_xy)?, pairs("test_v", &test_v)?);
    let p = params(p)?;
    py.detach(|| {
        Ok(gp::log_predictive(
            txy,
            tv,
            sxy,
            sv,
            &p,
            par_for(txy.len().max(sxy.len())),
        )?)
    })
}

#[pyfunction]
#[allow(clippy::type_complexity)]
pub fn posterior<'py>(
    py: Python<'py>,
    train_xy: PyReadonlyArray2<'py, f64>,
    train_v: PyReadonlyArray2<'py, f64>,
    query_xy: PyReadonlyArray2<'py, f64>,
    p: ParamTuple,
) -> CoreResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>)> {
    let (txy, tv) = (pairs("train_xy", &train_xy)?, pairs("train_v", &train_v)?);
    let q = pairs("query_xy", &query_xy)?;
    let p = params(p)?;
    let (mean, var) = py.detach(|| gp::posterior(txy, tv, q, &p, par_for(txy.len())))?;
    Ok((to_numpy(py, mean), to_numpy(py, var)))
}
