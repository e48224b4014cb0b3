//! numpy <-> core views, without copies.

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use crate::errors::{CoreError, CoreResult};
use dpgp_core::Error;

/// Borrow a C-contiguous float64 `(n, 2)` array as `n` pairs.
pub fn pairs<'a>(name: &str, a: &'a PyReadonlyArray2<'_, f64>) -> CoreResult<&'a [[f64; 2]]> {
    let shape = a.shape();
    if shape[1] != 2 {
        return Err(CoreError(Error::Shape(format!(
            "{name} must have shape (n, 2), got ({}, {})",
            shape[0], shape[1]
        ))));
    }
    let flat = a.as_slice().map_err(|_| {
        CoreError(Error::Shape(format!(
            "{name} must be C-contiguous (use numpy.ascontiguousarray)"
        )))
    })?;
    Ok(flat.as_chunks::<2>().0)
}

/// Move `n` pairs into a new `(n, 2)` numpy array.
pub fn to_numpy<'py>(py: Python<'py>, v: Vec<[f64; 2]>) -> Bound<'py, PyArray2<f64>> {
    let n = v.len();
    let flat: Vec<f64> = v.into_flattened();
    Array2::from_shape_vec((n, 2), flat)
        .expect("length is 2n by construction")
        .into_pyarray(py)
}

/// Borrow an optional float64 array of headings (radians, `NaN` where unknown); `None` gives
/// the empty slice (no headings).
pub fn headings<'a>(name: &str, a: &'a Option<PyReadonlyArray1<'_, f64>>) -> CoreResult<&'a [f64]> {
    match a {
        None => Ok(&[]),
        Some(a) => a.as_slice().map_err(|_| {
            CoreError(Error::Shape(format!(
                "{name} must be a C-contiguous float64 array (use numpy.ascontiguousarray)"
            )))
        }),
    }
}

/// `offsets` as indices: rising from 0 to `rows`, one more entry than `groups` (group `i` is rows
/// `offsets[i]..offsets[i + 1]`).
pub fn offsets_of(
    offsets: &PyReadonlyArray1<'_, i64>,
    groups: usize,
    rows: usize,
) -> CoreResult<Vec<usize>> {
    let offsets: Vec<usize> = offsets
        .as_array()
        .iter()
        .map(|&o| {
            usize::try_from(o)
                .map_err(|_| CoreError(Error::Shape("offsets must be non-negative".into())))
        })
        .collect::<CoreResult<_>>()?;
    if offsets.len() != groups + 1
        || offsets.first() != Some(&0)
        || offsets.last() != Some(&rows)
        || offsets.windows(2).any(|w| w[1] < w[0])
    {
        return Err(CoreError(Error::Shape(
            "offsets must rise from 0 to the number of rows, one more entry than groups".into(),
        )));
    }
    Ok(offsets)
}
