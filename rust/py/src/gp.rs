//! Bindings of the exact GP layer (`dpgp.gp` wraps these): the densities and posterior of one
//! standalone GP, computed by the core's pattern type (`Pattern::single`), as the HSGP bindings
//! go through `HsgpPattern`.

use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;

use crate::convert::{headings, pairs, to_numpy};
use crate::errors::CoreResult;
use crate::sampler::{frame_refs, offsets_vec};
use dpgp_core::frame::{FrameRef, Inputs, Point};
use dpgp_core::gp::GpParams;
use dpgp_core::linalg::par_for;
use dpgp_core::pattern::{Pattern, check_headings, check_pair, check_points};

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

/// [`params`] with the heading length scale `wh` (radians; `inf`: position only).
pub fn params_headed(t: ParamTuple, wh: f64) -> CoreResult<GpParams> {
    let p = params(t)?;
    Ok(p.with_length_scales(p.length_scales.with_heading(wh)?))
}

/// Validate a parameter tuple; raises InvalidInputError naming the bad value.
#[pyfunction]
pub fn check_params(p: ParamTuple) -> CoreResult<()> {
    params(p).map(|_| ())
}

/// A standalone GP over the training points, with faer's parallelism chosen by its size.
fn single(xy: &[Point], v: &[[f64; 2]], p: ParamTuple) -> CoreResult<Pattern> {
    Ok(Pattern::single(params(p)?, xy, v, par_for(xy.len()))?)
}

/// [`single`] over positions and previous headings, heading length scale `wh`.
fn single_at(f: FrameRef<'_>, p: ParamTuple, wh: f64) -> CoreResult<Pattern> {
    Ok(Pattern::single_at(
        params_headed(p, wh)?,
        f,
        par_for(f.xy.len()),
    )?)
}

#[pyfunction]
#[pyo3(signature = (xy, v, p, h=None, wh=f64::INFINITY))]
pub fn log_marginal_likelihood(
    py: Python<'_>,
    xy: PyReadonlyArray2<'_, f64>,
    v: PyReadonlyArray2<'_, f64>,
    p: ParamTuple,
    h: Option<PyReadonlyArray1<'_, f64>>,
    wh: f64,
) -> CoreResult<f64> {
    let (xy, v, h) = (pairs("xy", &xy)?, pairs("v", &v)?, headings("h", &h)?);
    check_pair("xy", xy, "v", v)?;
    py.detach(|| Ok(single_at(FrameRef { xy, v, h }, p, wh)?.log_marginal()))
}

#[pyfunction]
#[pyo3(signature = (train_xy, train_v, test_xy, test_v, p, train_h=None, test_h=None, wh=f64::INFINITY))]
#[allow(clippy::too_many_arguments)]
pub fn log_predictive(
    py: Python<'_>,
    train_xy: PyReadonlyArray2<'_, f64>,
    train_v: PyReadonlyArray2<'_, f64>,
    test_xy: PyReadonlyArray2<'_, f64>,
    test_v: PyReadonlyArray2<'_, f64>,
    p: ParamTuple,
    train_h: Option<PyReadonlyArray1<'_, f64>>,
    test_h: Option<PyReadonlyArray1<'_, f64>>,
    wh: f64,
) -> CoreResult<f64> {
    let (txy, tv) = (pairs("train_xy", &train_xy)?, pairs("train_v", &train_v)?);
    let (sxy, sv) = (pairs("test_xy", &test_xy)?, pairs("test_v", &test_v)?);
    let (th, sh) = (headings("train_h", &train_h)?, headings("test_h", &test_h)?);
    check_pair("test_xy", sxy, "test_v", sv)?;
    check_headings("test_h", sh, sxy.len())?;
    py.detach(|| {
        let train = FrameRef {
            xy: txy,
            v: tv,
            h: th,
        };
        let test = FrameRef {
            xy: sxy,
            v: sv,
            h: sh,
        };
        Ok(single_at(train, p, wh)?.score(&[test])?[0])
    })
}

/// The predictive density of each test frame (rows `offsets[i]..offsets[i + 1]`) given the
/// training data, from one factorisation: the single-GP baseline's scores.
#[pyfunction]
pub fn log_predictive_frames<'py>(
    py: Python<'py>,
    train_xy: PyReadonlyArray2<'py, f64>,
    train_v: PyReadonlyArray2<'py, f64>,
    test_xy: PyReadonlyArray2<'py, f64>,
    test_v: PyReadonlyArray2<'py, f64>,
    offsets: PyReadonlyArray1<'py, i64>,
    p: ParamTuple,
) -> CoreResult<Bound<'py, PyArray1<f64>>> {
    let (txy, tv) = (pairs("train_xy", &train_xy)?, pairs("train_v", &train_v)?);
    let (sxy, sv) = (pairs("test_xy", &test_xy)?, pairs("test_v", &test_v)?);
    check_pair("test_xy", sxy, "test_v", sv)?;
    let offsets = offsets_vec("offsets", &offsets)?;
    let frames = frame_refs(sxy, sv, &offsets)?;
    let out = py.detach(|| -> CoreResult<Vec<f64>> {
        let pat = single(txy, tv, p)?;
        // Frames in blocks of about SCORE_POINTS test points bound the cross-correlation buffer.
        let mut out = Vec::with_capacity(frames.len());
        let mut start = 0;
        while start < frames.len() {
            let mut end = start;
            let mut points = 0;
            while end < frames.len()
                && (end == start || points + frames[end].xy.len() <= SCORE_POINTS)
            {
                points += frames[end].xy.len();
                end += 1;
            }
            out.extend(pat.score(&frames[start..end])?);
            start = end;
        }
        Ok(out)
    })?;
    Ok(out.into_pyarray(py))
}

/// Test points scored per call in [`log_predictive_frames`].
const SCORE_POINTS: usize = 1024;

#[pyfunction]
#[pyo3(signature = (train_xy, train_v, query_xy, p, train_h=None, query_h=None, wh=f64::INFINITY))]
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub fn posterior<'py>(
    py: Python<'py>,
    train_xy: PyReadonlyArray2<'py, f64>,
    train_v: PyReadonlyArray2<'py, f64>,
    query_xy: PyReadonlyArray2<'py, f64>,
    p: ParamTuple,
    train_h: Option<PyReadonlyArray1<'py, f64>>,
    query_h: Option<PyReadonlyArray1<'py, f64>>,
    wh: f64,
) -> CoreResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>)> {
    let (txy, tv) = (pairs("train_xy", &train_xy)?, pairs("train_v", &train_v)?);
    let q = pairs("query_xy", &query_xy)?;
    let (th, qh) = (
        headings("train_h", &train_h)?,
        headings("query_h", &query_h)?,
    );
    check_points("query_xy", q)?;
    check_headings("query_h", qh, q.len())?;
    let (mean, var) = py.detach(|| -> CoreResult<_> {
        let train = FrameRef {
            xy: txy,
            v: tv,
            h: th,
        };
        Ok(single_at(train, p, wh)?.posterior_at(Inputs { xy: q, h: qh }))
    })?;
    Ok((to_numpy(py, mean), to_numpy(py, var)))
}

/// For every vehicle of a frame of two or more, the squared distance to its nearest neighbour in
/// the same frame (row order): the length-scale prior's data spacing.
#[pyfunction]
pub fn nearest_neighbour_sq<'py>(
    py: Python<'py>,
    xy: PyReadonlyArray2<'py, f64>,
    offsets: PyReadonlyArray1<'py, i64>,
) -> CoreResult<Bound<'py, PyArray1<f64>>> {
    let xy = pairs("xy", &xy)?;
    let offsets = offsets_vec("offsets", &offsets)?;
    frame_refs(xy, xy, &offsets)?;
    let d2 = py.detach(|| dpgp_core::frame::nearest_neighbour_sq(xy, &offsets));
    Ok(d2.into_pyarray(py))
}
