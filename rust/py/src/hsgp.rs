//! Bindings of the reduced-rank (HSGP) GP layer (`dpgp.hsgp` wraps these): the basis sizing rule
//! and the densities of one pattern, computed through the additive M x M statistics.

use std::sync::Arc;

use numpy::{PyArray2, PyReadonlyArray2};
use pyo3::prelude::*;

use crate::convert::{pairs, to_numpy};
use crate::errors::CoreResult;
use crate::gp::{ParamTuple, params};
use dpgp_core::hsgp::{Basis, HsgpPattern};
use dpgp_core::kernel::{LengthScales, Point};
use dpgp_core::pattern::FrameRef;
use dpgp_core::{Error, error::check_finite};

/// `((centre x, y), (half-width x, y), (count x, y))`.
pub type BasisTuple = ((f64, f64), (f64, f64), (usize, usize));

pub fn basis(t: BasisTuple) -> CoreResult<Basis> {
    let ((cx, cy), (hx, hy), (mx, my)) = t;
    Ok(Basis::new([cx, cy], [hx, hy], [mx, my])?)
}

fn as_tuple(b: &Basis) -> BasisTuple {
    let (c, h, m) = (b.center(), b.half_widths(), b.counts());
    ((c[0], c[1]), (h[0], h[1]), (m[0], m[1]))
}

/// The basis for training positions `xy` by the documented rule (see `Basis::for_data`).
#[pyfunction]
#[pyo3(signature = (xy, length_scale_prior, length_scales=None, n_basis=None))]
pub fn hsgp_basis(
    xy: PyReadonlyArray2<'_, f64>,
    length_scale_prior: (f64, f64),
    length_scales: Option<(f64, f64)>,
    n_basis: Option<(usize, usize)>,
) -> CoreResult<BasisTuple> {
    let xy = pairs("xy", &xy)?;
    check_finite("xy", xy.as_flattened())?;
    let fixed = length_scales
        .map(|(wx, wy)| LengthScales::new(wx, wy))
        .transpose()?;
    let b = Basis::for_prior(xy, length_scale_prior, fixed, n_basis.map(|(x, y)| [x, y]))?;
    Ok(as_tuple(&b))
}

fn pattern(xy: &[Point], v: &[[f64; 2]], p: ParamTuple, b: BasisTuple) -> CoreResult<HsgpPattern> {
    if xy.is_empty() || xy.len() != v.len() {
        return Err(Error::Shape(format!(
            "train_xy has {} points and train_v {} velocities; need at least one, row for row",
            xy.len(),
            v.len()
        ))
        .into());
    }
    check_finite("train_xy", xy.as_flattened())?;
    check_finite("train_v", v.as_flattened())?;
    Ok(HsgpPattern::new(
        Arc::new(basis(b)?),
        params(p)?,
        &[(0, FrameRef { xy, v })],
    )?)
}

#[pyfunction]
pub fn hsgp_log_marginal_likelihood(
    py: Python<'_>,
    xy: PyReadonlyArray2<'_, f64>,
    v: PyReadonlyArray2<'_, f64>,
    p: ParamTuple,
    b: BasisTuple,
) -> CoreResult<f64> {
    let (xy, v) = (pairs("xy", &xy)?, pairs("v", &v)?);
    py.detach(|| Ok(pattern(xy, v, p, b)?.log_marginal()))
}

#[pyfunction]
pub fn hsgp_log_predictive(
    py: Python<'_>,
    train_xy: PyReadonlyArray2<'_, f64>,
    train_v: PyReadonlyArray2<'_, f64>,
    test_xy: PyReadonlyArray2<'_, f64>,
    test_v: PyReadonlyArray2<'_, f64>,
    p: ParamTuple,
    b: BasisTuple,
) -> CoreResult<f64> {
    let (txy, tv) = (pairs("train_xy", &train_xy)?, pairs("train_v", &train_v)?);
    let (sxy, sv) = (pairs("test_xy", &test_xy)?, pairs("test_v", &test_v)?);
    if sxy.is_empty() || sxy.len() != sv.len() {
        return Err(
            Error::Shape("test_xy and test_v must be non-empty, row for row".into()).into(),
        );
    }
    check_finite("test_xy", sxy.as_flattened())?;
    check_finite("test_v", sv.as_flattened())?;
    py.detach(|| {
        let pat = pattern(txy, tv, p, b)?;
        Ok(pat.score(&[FrameRef { xy: sxy, v: sv }])?[0])
    })
}

#[pyfunction]
#[allow(clippy::type_complexity)]
pub fn hsgp_posterior<'py>(
    py: Python<'py>,
    train_xy: PyReadonlyArray2<'py, f64>,
    train_v: PyReadonlyArray2<'py, f64>,
    query_xy: PyReadonlyArray2<'py, f64>,
    p: ParamTuple,
    b: BasisTuple,
) -> CoreResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>)> {
    let (txy, tv) = (pairs("train_xy", &train_xy)?, pairs("train_v", &train_v)?);
    let q = pairs("query_xy", &query_xy)?;
    check_finite("query_xy", q.as_flattened())?;
    let (mean, var) =
        py.detach(|| -> CoreResult<_> { Ok(pattern(txy, tv, p, b)?.posterior(q)) })?;
    Ok((to_numpy(py, mean), to_numpy(py, var)))
}
