//! Criticality measures of many scenes at once ([`dpgp_core::criticality`]), in parallel.

use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use rayon::prelude::*;

use crate::convert::{offsets_of, pairs};
use crate::errors::CoreError;
use dpgp_core::Error;
use dpgp_core::criticality::{Measures, Scene};

/// Scenes measured between two checks for Ctrl-C.
const CHUNK: usize = 2048;

type Out<'py> = (
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray1<f64>>,
);

/// Measure scene `i`: rows `offsets[i]..offsets[i+1]` of `positions`, `velocities` and
/// `present` (time-major, `vehicles[i]` a time), its vehicles' sizes (length, width) the next
/// `vehicles[i]` rows of `sizes`. Returns the pairs' scene, `a`, `b`, time to collision, gap,
/// post-encroachment time and collision flag, then every vehicle's hardest deceleration.
/// `headings` (per row, NaN: not known): the heading a vehicle slower than `min_speed` faces.
#[pyfunction]
#[pyo3(signature = (positions, velocities, present, offsets, vehicles, sizes, dt, min_speed, headings=None))]
#[allow(clippy::too_many_arguments)]
pub fn criticality<'py>(
    py: Python<'py>,
    positions: PyReadonlyArray2<'py, f64>,
    velocities: PyReadonlyArray2<'py, f64>,
    present: PyReadonlyArray1<'py, bool>,
    offsets: PyReadonlyArray1<'py, i64>,
    vehicles: Vec<usize>,
    sizes: PyReadonlyArray2<'py, f64>,
    dt: f64,
    min_speed: f64,
    headings: Option<PyReadonlyArray1<'py, f64>>,
) -> PyResult<Out<'py>> {
    let headings = headings
        .as_ref()
        .map(|h| {
            h.as_slice().map_err(|_| {
                CoreError(Error::Shape(
                    "headings must be a C-contiguous float array".into(),
                ))
            })
        })
        .transpose()?;
    let positions = pairs("positions", &positions)?;
    let velocities = pairs("velocities", &velocities)?;
    let sizes = pairs("sizes", &sizes)?;
    let present = present.as_slice().map_err(|_| {
        CoreError(Error::Shape(
            "present must be a C-contiguous bool array".into(),
        ))
    })?;
    let rows = present.len();
    let offsets = offsets_of(&offsets, vehicles.len(), rows)?;
    if positions.len() != rows
        || velocities.len() != rows
        || headings.is_some_and(|h| h.len() != rows)
        || vehicles.iter().sum::<usize>() != sizes.len()
    {
        return Err(CoreError(Error::Shape(
            "scenes: positions, velocities, present (and headings) need the same rows, and sizes one row per vehicle of every scene".into(),
        ))
        .into());
    }
    let mut first = vec![0; vehicles.len() + 1];
    for (i, l) in vehicles.iter().enumerate() {
        first[i + 1] = first[i] + l;
    }
    let scene = |i: usize| Scene {
        vehicles: vehicles[i],
        positions: &positions[offsets[i]..offsets[i + 1]],
        velocities: &velocities[offsets[i]..offsets[i + 1]],
        present: &present[offsets[i]..offsets[i + 1]],
        sizes: &sizes[first[i]..first[i + 1]],
        dt,
        min_speed,
        headings: headings.map(|h| &h[offsets[i]..offsets[i + 1]]),
    };
    let mut all: Vec<Measures> = Vec::with_capacity(vehicles.len());
    for chunk in (0..vehicles.len()).collect::<Vec<_>>().chunks(CHUNK) {
        let done = py
            .detach(|| {
                chunk
                    .par_iter()
                    .map(|&i| {
                        scene(i).measures().map_err(|e| match e {
                            Error::InvalidInput(m) => {
                                Error::InvalidInput(format!("scene {i}: {m}"))
                            }
                            other => other,
                        })
                    })
                    .collect::<dpgp_core::Result<Vec<_>>>()
            })
            .map_err(CoreError)?;
        all.extend(done);
        py.check_signals()?;
    }
    let (mut scene_of, mut a, mut b) = (Vec::new(), Vec::new(), Vec::new());
    let (mut ttc, mut gap, mut pet, mut hit) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut decel = Vec::with_capacity(sizes.len());
    for (i, m) in all.into_iter().enumerate() {
        for p in m.pairs {
            scene_of.push(i as i64);
            a.push(p.a as i64);
            b.push(p.b as i64);
            ttc.push(p.ttc);
            gap.push(p.gap);
            pet.push(p.pet);
            hit.push(p.collision);
        }
        decel.extend(m.deceleration);
    }
    Ok((
        scene_of.into_pyarray(py),
        a.into_pyarray(py),
        b.into_pyarray(py),
        ttc.into_pyarray(py),
        gap.into_pyarray(py),
        pet.into_pyarray(py),
        hit.into_pyarray(py),
        decel.into_pyarray(py),
    ))
}
