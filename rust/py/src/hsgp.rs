//! Bindings of the reduced-rank (HSGP) GP layer (`dpgp.hsgp` wraps these): the basis sizing rule
//! and the densities of one pattern, computed through the additive M x M statistics.

use std::sync::Arc;

use numpy::{PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;

use crate::convert::{headings, pairs, to_numpy};
use crate::errors::CoreResult;
use crate::gp::{ParamTuple, params_headed};
use dpgp_core::frame::Inputs;
use dpgp_core::hsgp::{Basis, HsgpPattern};
use dpgp_core::kernel::LengthScales;
use dpgp_core::pattern::{FrameRef, check_headings};
use dpgp_core::{Error, error::check_finite};

/// `((centre x, y), (half-width x, y), (count x, y))`.
pub type BasisTuple = ((f64, f64), (f64, f64), (usize, usize));

pub fn basis(t: BasisTuple) -> CoreResult<Basis> {
    let ((cx, cy), (hx, hy), (mx, my)) = t;
    Ok(Basis::new([cx, cy], [hx, hy], [mx, my])?)
}

/// The basis `t` with `harmonics` heading harmonics, each heading block on `heading_counts`
/// position functions per axis (`None`: all of them).
pub fn headed_basis(
    t: BasisTuple,
    harmonics: usize,
    heading_counts: Option<(usize, usize)>,
) -> CoreResult<Basis> {
    let b = basis(t)?;
    let hm = heading_counts.map_or(b.counts(), |(x, y)| [x, y]);
    Ok(b.with_heading(harmonics, hm)?)
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

/// Heading harmonics of a basis and its heading blocks' position counts (`None`: all).
type Heading = (usize, Option<(usize, usize)>);

/// A standalone reduced-rank GP over the training frame `f` (headings optional), heading length
/// scale `wh`, on the basis `b` with heading functions `heading`.
fn pattern(
    f: FrameRef<'_>,
    p: ParamTuple,
    b: BasisTuple,
    wh: f64,
    heading: Heading,
) -> CoreResult<HsgpPattern> {
    let (xy, v) = (f.xy, f.v);
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
    check_headings("train_h", f.h, xy.len())?;
    Ok(HsgpPattern::new(
        Arc::new(headed_basis(b, heading.0, heading.1)?),
        params_headed(p, wh)?,
        &[(0, f)],
    )?)
}

#[pyfunction]
#[pyo3(signature = (xy, v, p, b, h=None, wh=f64::INFINITY, harmonics=0, heading_counts=None))]
#[allow(clippy::too_many_arguments)]
pub fn hsgp_log_marginal_likelihood(
    py: Python<'_>,
    xy: PyReadonlyArray2<'_, f64>,
    v: PyReadonlyArray2<'_, f64>,
    p: ParamTuple,
    b: BasisTuple,
    h: Option<PyReadonlyArray1<'_, f64>>,
    wh: f64,
    harmonics: usize,
    heading_counts: Option<(usize, usize)>,
) -> CoreResult<f64> {
    let (xy, v, h) = (pairs("xy", &xy)?, pairs("v", &v)?, headings("h", &h)?);
    py.detach(|| {
        Ok(pattern(FrameRef { xy, v, h }, p, b, wh, (harmonics, heading_counts))?.log_marginal())
    })
}

#[pyfunction]
#[pyo3(signature = (train_xy, train_v, test_xy, test_v, p, b, train_h=None, test_h=None, wh=f64::INFINITY, harmonics=0, heading_counts=None))]
#[allow(clippy::too_many_arguments)]
pub fn hsgp_log_predictive(
    py: Python<'_>,
    train_xy: PyReadonlyArray2<'_, f64>,
    train_v: PyReadonlyArray2<'_, f64>,
    test_xy: PyReadonlyArray2<'_, f64>,
    test_v: PyReadonlyArray2<'_, f64>,
    p: ParamTuple,
    b: BasisTuple,
    train_h: Option<PyReadonlyArray1<'_, f64>>,
    test_h: Option<PyReadonlyArray1<'_, f64>>,
    wh: f64,
    harmonics: usize,
    heading_counts: Option<(usize, usize)>,
) -> CoreResult<f64> {
    let (txy, tv) = (pairs("train_xy", &train_xy)?, pairs("train_v", &train_v)?);
    let (sxy, sv) = (pairs("test_xy", &test_xy)?, pairs("test_v", &test_v)?);
    let (th, sh) = (headings("train_h", &train_h)?, headings("test_h", &test_h)?);
    check_headings("test_h", sh, sxy.len())?;
    if sxy.is_empty() || sxy.len() != sv.len() {
        return Err(
            Error::Shape("test_xy and test_v must be non-empty, row for row".into()).into(),
        );
    }
    check_finite("test_xy", sxy.as_flattened())?;
    check_finite("test_v", sv.as_flattened())?;
    py.detach(|| {
        let train = FrameRef {
            xy: txy,
            v: tv,
            h: th,
        };
        let pat = pattern(train, p, b, wh, (harmonics, heading_counts))?;
        let test = FrameRef {
            xy: sxy,
            v: sv,
            h: sh,
        };
        Ok(pat.score(&[test])?[0])
    })
}

#[pyfunction]
#[pyo3(signature = (train_xy, train_v, query_xy, p, b, train_h=None, query_h=None, wh=f64::INFINITY, harmonics=0, heading_counts=None))]
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub fn hsgp_posterior<'py>(
    py: Python<'py>,
    train_xy: PyReadonlyArray2<'py, f64>,
    train_v: PyReadonlyArray2<'py, f64>,
    query_xy: PyReadonlyArray2<'py, f64>,
    p: ParamTuple,
    b: BasisTuple,
    train_h: Option<PyReadonlyArray1<'py, f64>>,
    query_h: Option<PyReadonlyArray1<'py, f64>>,
    wh: f64,
    harmonics: usize,
    heading_counts: Option<(usize, usize)>,
) -> CoreResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>)> {
    let (txy, tv) = (pairs("train_xy", &train_xy)?, pairs("train_v", &train_v)?);
    let q = pairs("query_xy", &query_xy)?;
    let (th, qh) = (
        headings("train_h", &train_h)?,
        headings("query_h", &query_h)?,
    );
    check_finite("query_xy", q.as_flattened())?;
    check_headings("query_h", qh, q.len())?;
    let (mean, var) = py.detach(|| -> CoreResult<_> {
        let train = FrameRef {
            xy: txy,
            v: tv,
            h: th,
        };
        Ok(pattern(train, p, b, wh, (harmonics, heading_counts))?
            .posterior_at(Inputs { xy: q, h: qh }))
    })?;
    Ok((to_numpy(py, mean), to_numpy(py, var)))
}

/// Heading harmonics an hsgp basis needs under the Gamma(shape, scale) prior of the heading
/// length scale: the fewest that keep 99% of the periodic kernel's variance at the prior's 5%
/// quantile (`heading::harmonics_for`; the position basis is sized the same way).
#[pyfunction]
pub fn heading_harmonics(prior: (f64, f64)) -> CoreResult<usize> {
    let (a, b) = prior;
    if !(a.is_finite() && a > 0.0 && b.is_finite() && b > 0.0) {
        return Err(Error::InvalidInput(format!(
            "a heading prior is a Gamma (shape, scale) with both positive, got {prior:?}"
        ))
        .into());
    }
    let wh_lo = dpgp_core::special::gamma_quantile(0.05, a, b);
    Ok(dpgp_core::heading::harmonics_for(wh_lo))
}
