//! Rollouts of vehicles through a fitted pattern (`dpgp.simulation` wraps these), and through an
//! affine field with a known solution (for checking the integrator from Python).

use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use rayon::prelude::*;

use crate::convert::{pairs, to_numpy};
use crate::errors::{CoreError, CoreResult};
use crate::sampler::PySampler;
use dpgp_core::Error;
use dpgp_core::kernel::Point;
use dpgp_core::simulate::{Method, Options, Roi, Rollout, integrate, rollout};

/// Rollouts run in parallel in chunks of this many, with a Ctrl-C check between chunks.
const CHUNK: usize = 64;

type Arrays<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray1<bool>>,
);

fn options(
    dt: f64,
    steps: usize,
    method: &str,
    roi: Option<(f64, f64, f64, f64)>,
) -> CoreResult<Options> {
    let roi = match roi {
        Some((a, b, c, d)) => Roi::new(a, b, c, d)?,
        None => Roi::everywhere(),
    };
    Ok(Options {
        dt,
        steps,
        method: Method::parse(method)?,
        roi,
    })
}

/// Rollouts concatenated in order, each time-major, as numpy arrays.
fn arrays(py: Python<'_>, rollouts: Vec<Rollout>) -> Arrays<'_> {
    let (mut pos, mut vel, mut inside, mut low) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for r in rollouts {
        pos.extend(r.positions);
        vel.extend(r.velocities);
        inside.extend(r.in_roi);
        low.extend(r.low_data);
    }
    (
        to_numpy(py, pos),
        to_numpy(py, vel),
        inside.into_pyarray(py),
        low.into_pyarray(py),
    )
}

/// Roll out groups of vehicles, group `i` (rows `offsets[i]..offsets[i+1]` of `start`) through
/// the pattern in `slots[i]`, stochastic with `seeds[i]` if given. Returns positions, velocities
/// (rows: group, then time, then vehicle), in-ROI and low-data flags.
#[pyfunction]
#[pyo3(signature = (sampler, slots, start, offsets, dt, steps, method, roi=None, seeds=None, low_data=None))]
#[allow(clippy::too_many_arguments)]
pub fn rollouts<'py>(
    py: Python<'py>,
    sampler: PyRef<'py, PySampler>,
    slots: Vec<usize>,
    start: PyReadonlyArray2<'py, f64>,
    offsets: PyReadonlyArray1<'py, i64>,
    dt: f64,
    steps: usize,
    method: &str,
    roi: Option<(f64, f64, f64, f64)>,
    seeds: Option<Vec<u64>>,
    low_data: Option<f64>,
) -> PyResult<Arrays<'py>> {
    let opts = options(dt, steps, method, roi)?;
    let start: &[Point] = pairs("start", &start)?;
    let offsets: Vec<usize> = offsets
        .as_array()
        .iter()
        .map(|&o| {
            usize::try_from(o)
                .map_err(|_| CoreError(Error::Shape("offsets must be non-negative".into())))
        })
        .collect::<CoreResult<_>>()?;
    if offsets.len() != slots.len() + 1
        || offsets.first() != Some(&0)
        || offsets.last() != Some(&start.len())
        || offsets.windows(2).any(|w| w[1] < w[0])
    {
        return Err(CoreError(Error::Shape(
            "offsets must rise from 0 to the number of start positions, one more entry than slots"
                .into(),
        ))
        .into());
    }
    if let Some(s) = &seeds {
        if s.len() != slots.len() {
            return Err(CoreError(Error::Shape(format!(
                "{} seeds for {} rollouts",
                s.len(),
                slots.len()
            )))
            .into());
        }
    }
    let rollouts = sampler.run(py, |s, stop| {
        let mut out = Vec::with_capacity(slots.len());
        for chunk in (0..slots.len()).collect::<Vec<_>>().chunks(CHUNK) {
            if stop() {
                return Err(Error::Interrupted);
            }
            let done: Vec<Rollout> = chunk
                .par_iter()
                .map(|&i| {
                    let p = s.pattern(slots[i]).ok_or_else(|| {
                        Error::InvalidInput(format!("no pattern in slot {}", slots[i]))
                    })?;
                    let seed = seeds.as_ref().map(|v| v[i]);
                    rollout(p, &start[offsets[i]..offsets[i + 1]], &opts, seed, low_data)
                })
                .collect::<dpgp_core::Result<_>>()?;
            out.extend(done);
        }
        Ok(out)
    })?;
    Ok(arrays(py, rollouts))
}

/// Roll vehicles through the affine field `v(p) = a p + b` (`a` row-major): constant for
/// `a = 0`, a rigid rotation for `a = [[0, -ω], [ω, 0]]`. For checking the integrator.
#[pyfunction]
#[pyo3(signature = (start, a, b, dt, steps, method, roi=None))]
#[allow(clippy::too_many_arguments)]
pub fn integrate_affine<'py>(
    py: Python<'py>,
    start: PyReadonlyArray2<'py, f64>,
    a: [[f64; 2]; 2],
    b: [f64; 2],
    dt: f64,
    steps: usize,
    method: &str,
    roi: Option<(f64, f64, f64, f64)>,
) -> PyResult<Arrays<'py>> {
    let opts = options(dt, steps, method, roi)?;
    let start: &[Point] = pairs("start", &start)?;
    let mut field = |q: &[Point]| -> dpgp_core::Result<Vec<[f64; 2]>> {
        Ok(q.iter()
            .map(|p| {
                [
                    a[0][0] * p[0] + a[0][1] * p[1] + b[0],
                    a[1][0] * p[0] + a[1][1] * p[1] + b[1],
                ]
            })
            .collect())
    };
    let r = py
        .detach(|| integrate(start, &opts, &mut field))
        .map_err(CoreError)?;
    Ok(arrays(py, vec![r]))
}
