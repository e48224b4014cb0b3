//! Rollouts of vehicles through a fitted pattern (`dpgp.simulation` wraps these), and through an
//! affine field with a known solution (for checking the integrator from Python).

use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3,
};
use pyo3::prelude::*;
use rayon::prelude::*;

use crate::convert::{offsets_of, pairs, to_numpy};
use crate::errors::{CoreError, CoreResult};
use crate::sampler::{PySampler, pattern_at};
use dpgp_core::Error;
use dpgp_core::frame::Inputs;
use dpgp_core::free_speed::{AtFreeSpeed, FreeSpeeds, SECTORS};
use dpgp_core::gibbs::Sampler;
use dpgp_core::kernel::Point;
use dpgp_core::motion::{
    Carried, MOTION_FIELDS, Motion, Shift, Stop, drive, drive_on, drive_shifted,
};
use dpgp_core::pattern_model::PatternModel;
use dpgp_core::placement::{Grid, place, thin_kept};
use dpgp_core::rng::{Phase, stream};
use dpgp_core::simulate::{
    Field, Method, MixtureField, Options, PatternField, Roi, Rollout, integrate,
};

/// Rollouts run in parallel in chunks of this many, with a Ctrl-C check between chunks.
const CHUNK: usize = 64;
/// Stream entity of a generated scene's placement (0: its GP draw, 1: the residual's noise).
const PLACEMENT_ENTITY: u64 = 2;

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
    max_curvature: Option<f64>,
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
        max_curvature,
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
/// (rows: group, then time, then vehicle), in-ROI and low-data flags. `max_curvature`: the
/// turning limit of fields over heading (`dpgp_core::turning`).
#[pyfunction]
#[pyo3(signature = (sampler, slots, start, offsets, dt, steps, method, roi=None, seeds=None, low_data=None, headings=None, max_curvature=None))]
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
    headings: Headings<'py>,
    max_curvature: Option<f64>,
) -> PyResult<Arrays<'py>> {
    let opts = options(dt, steps, method, roi, max_curvature)?;
    let start: &[Point] = pairs("start", &start)?;
    let offsets = offsets_of(&offsets, slots.len(), start.len())?;
    check_seeds(&seeds, slots.len())?;
    let h = headings_of(&headings, start.len())?;
    let rollouts = in_parallel(py, &sampler, &slots, |_, p, i| {
        let seed = seeds.as_ref().map(|v| v[i]);
        let (a, b) = (offsets[i], offsets[i + 1]);
        let mut field = headed(PatternField::new(p, seed, low_data)?, h, a, b);
        integrate(&start[a..b], &opts, &mut field)
    })?;
    Ok(arrays(py, rollouts))
}

/// `one(pattern of slots[i], i)` for every `i`, in parallel on the sampler's pool in chunks of
/// [`CHUNK`] (a Ctrl-C check between chunks); results in order, whatever the thread count.
fn in_parallel<T: Send>(
    py: Python<'_>,
    sampler: &PySampler,
    slots: &[usize],
    one: impl Fn(&Sampler, &dyn PatternModel, usize) -> dpgp_core::Result<T> + Sync,
) -> PyResult<Vec<T>> {
    sampler.run(py, |s, stop| {
        let mut out = Vec::with_capacity(slots.len());
        for chunk in (0..slots.len()).collect::<Vec<_>>().chunks(CHUNK) {
            if stop() {
                return Err(Error::Interrupted);
            }
            let done: Vec<T> = chunk
                .par_iter()
                .map(|&i| one(s, pattern_at(s, slots[i])?, i))
                .collect::<dpgp_core::Result<_>>()?;
            out.extend(done);
        }
        Ok(out)
    })
}

/// Start headings `(h, min speed)` for fields over heading ([`PatternField::with_headings`]):
/// one heading per start row (`NaN`: unknown), checked.
type Headings<'py> = Option<(PyReadonlyArray1<'py, f64>, f64)>;

fn headings_of<'a>(h: &'a Headings<'_>, rows: usize) -> CoreResult<Option<(&'a [f64], f64)>> {
    let Some((h, speed)) = h else {
        return Ok(None);
    };
    let h = h.as_slice().map_err(|_| {
        CoreError(Error::Shape(
            "headings must be a contiguous float64 array".into(),
        ))
    })?;
    if h.len() != rows {
        return Err(CoreError(Error::Shape(format!(
            "{} headings for {rows} start positions",
            h.len()
        ))));
    }
    Ok(Some((h, *speed)))
}

/// `field` at the headings `h[a..b]` when given.
fn headed<'p>(
    field: PatternField<'p>,
    h: Option<(&[f64], f64)>,
    a: usize,
    b: usize,
) -> PatternField<'p> {
    match h {
        Some((h, speed)) => field.with_headings(h[a..b].to_vec(), speed),
        None => field,
    }
}

/// One [`Motion`] per rollout from a `(rollouts, MOTION_FIELDS)` array.
fn motions(m: &PyReadonlyArray2<'_, f64>, n: usize) -> CoreResult<Vec<Motion>> {
    let a = m.as_array();
    if a.nrows() != n || a.ncols() != MOTION_FIELDS {
        return Err(CoreError(Error::Shape(format!(
            "motion must have shape ({n}, {MOTION_FIELDS}), got ({}, {})",
            a.nrows(),
            a.ncols()
        ))));
    }
    a.rows()
        .into_iter()
        .map(|r| Motion::from_slice(&r.to_vec()).map_err(CoreError))
        .collect()
}

fn check_seeds(seeds: &Option<Vec<u64>>, n: usize) -> CoreResult<()> {
    match seeds {
        Some(s) if s.len() != n => Err(CoreError(Error::Shape(format!(
            "{} seeds for {n} rollouts",
            s.len()
        )))),
        _ => Ok(()),
    }
}

/// Interactive rollouts of recorded frames (`dpgp.simulation`, `dynamics != "field"`): group `i`
/// (rows `offsets[i]..offsets[i+1]` of `start`, with their own `velocities`) through the
/// pattern in `slots[i]` by `motion[i]`; the residual's innovations drawn with `seeds[i]` if
/// given; `drivers` (one row per start) continues each driver's state from an earlier rollout
/// (long scenarios); `support`: drivers follow the field only as far as it knows (its posterior
/// variance against the prior's, a triangular solve per vehicle and step); `mixtures[i]`:
/// (slot, weight) pairs whose fields together ([`MixtureField`], with support) replace
/// `slots[i]`'s (whose motion row still applies); `renew`: the continued drivers take up the
/// field at the start ([`Carried`]); `stops[i]`: the red stop lines `(x, y, heading x, heading y)`
/// in force in rollout `i` ([`Stop`]); `free_speeds`: `(origin x, origin y, cell, speeds)`, the
/// speeds `(nx, ny, 8)` by cell and heading sector (NaN: none), to which each field is raised
/// ([`AtFreeSpeed`]). Returns what [`rollouts`] returns and each vehicle's driver
/// state after the last step (rows as `start`).
#[pyfunction]
#[pyo3(signature = (sampler, slots, start, velocities, offsets, motion, dt, steps, roi=None, seeds=None, low_data=None, drivers=None, support=false, mixtures=None, renew=false, stops=None, free_speeds=None, headings=None))]
#[allow(clippy::too_many_arguments)]
pub fn motion_rollouts<'py>(
    py: Python<'py>,
    sampler: PyRef<'py, PySampler>,
    slots: Vec<usize>,
    start: PyReadonlyArray2<'py, f64>,
    velocities: PyReadonlyArray2<'py, f64>,
    offsets: PyReadonlyArray1<'py, i64>,
    motion: PyReadonlyArray2<'py, f64>,
    dt: f64,
    steps: usize,
    roi: Option<(f64, f64, f64, f64)>,
    seeds: Option<Vec<u64>>,
    low_data: Option<f64>,
    drivers: Option<PyReadonlyArray2<'py, f64>>,
    support: bool,
    mixtures: Option<Vec<Vec<(usize, f64)>>>,
    renew: bool,
    stops: Option<Vec<Vec<(f64, f64, f64, f64)>>>,
    free_speeds: Option<(f64, f64, f64, PyReadonlyArray3<'py, f64>)>,
    headings: Headings<'py>,
) -> PyResult<(
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray2<f64>>,
)> {
    let opts = options(dt, steps, "euler", roi, None)?;
    let start: &[Point] = pairs("start", &start)?;
    let vel: &[[f64; 2]] = pairs("velocities", &velocities)?;
    if vel.len() != start.len() {
        return Err(CoreError(Error::Shape("one start velocity per start position".into())).into());
    }
    let drivers: Option<&[[f64; 2]]> = match &drivers {
        Some(d) => Some(pairs("drivers", d)?),
        None => None,
    };
    if drivers.is_some_and(|d| d.len() != start.len()) {
        return Err(CoreError(Error::Shape("one driver state per start position".into())).into());
    }
    let offsets = offsets_of(&offsets, slots.len(), start.len())?;
    let motion = motions(&motion, slots.len())?;
    check_seeds(&seeds, slots.len())?;
    if mixtures.as_ref().is_some_and(|m| m.len() != slots.len()) {
        return Err(CoreError(Error::Shape("one mixture per rollout".into())).into());
    }
    if stops.as_ref().is_some_and(|s| s.len() != slots.len()) {
        return Err(CoreError(Error::Shape("one list of stop lines per rollout".into())).into());
    }
    let stops: Vec<Vec<Stop>> = match stops {
        Some(all) => all
            .iter()
            .map(|lines| {
                lines
                    .iter()
                    .map(|&(x, y, hx, hy)| Stop::new([x, y], [hx, hy]))
                    .collect()
            })
            .collect::<dpgp_core::Result<_>>()
            .map_err(CoreError)?,
        None => vec![Vec::new(); slots.len()],
    };
    let free = match &free_speeds {
        Some((x, y, cell, speeds)) => {
            let view = speeds.as_array();
            let (nx, ny, sectors) = view.dim();
            if sectors != SECTORS {
                return Err(CoreError(Error::Shape(format!(
                    "free speeds need {SECTORS} heading sectors, got {sectors}"
                )))
                .into());
            }
            let values = view.iter().copied().collect();
            Some(FreeSpeeds::new([*x, *y], *cell, nx, ny, values).map_err(CoreError)?)
        }
        None => None,
    };
    let h = headings_of(&headings, start.len())?;
    let rollouts = in_parallel(py, &sampler, &slots, |s, p, i| {
        let (a, b) = (offsets[i], offsets[i + 1]);
        let seed = seeds.as_ref().map(|v| v[i]);
        // one pattern's field, or (long scenarios by phase) its phase's patterns' together
        let mut field: Box<dyn Field> = match mixtures.as_ref().map(|m| &m[i]) {
            Some(parts) => {
                let parts = parts
                    .iter()
                    .map(|&(slot, w)| Ok((pattern_at(s, slot)?, w)))
                    .collect::<dpgp_core::Result<Vec<_>>>()?;
                let field = MixtureField::new(parts)?;
                Box::new(match h {
                    Some((h, speed)) => field.with_headings(h[a..b].to_vec(), speed),
                    None => field,
                })
            }
            None => Box::new(headed(
                PatternField::new(p, None, low_data)?.with_support(support),
                h,
                a,
                b,
            )),
        };
        if let Some(speeds) = free.as_ref() {
            field = Box::new(AtFreeSpeed {
                inner: field,
                speeds,
            });
        }
        drive_on(
            &start[a..b],
            Some(&vel[a..b]),
            drivers.map(|d| Carried {
                states: &d[a..b],
                renew,
            }),
            &stops[i],
            &opts,
            &motion[i],
            seed,
            None,
            field.as_mut(),
        )
    })?;
    let states: Vec<[f64; 2]> = rollouts
        .iter()
        .flat_map(|r| r.drivers.iter().copied())
        .collect();
    let (pos, vel, inside, low) = arrays(py, rollouts);
    Ok((pos, vel, inside, low, to_numpy(py, states)))
}

/// Generated scenes (`dpgp.scenarios`, `dynamics != "field"`): scenario `i` places up to
/// `counts[i]` vehicles from position grid `grids[grid[i]]` (rows of bin weights, `bins`
/// `(nx, ny)` over `grid_roi`) no closer than `spacing[i]`, draws their velocities jointly from
/// the pattern in `slots[i]` (the mean if not `stochastic`), and rolls them out by `motion[i]`.
/// Every draw comes from `seeds[i]`. `shift`: the residual's innovations tilted by a
/// [`Shift`] of that mean (stochastic only). Returns the arrays of [`rollouts`], each scene's
/// vehicle count, and with a shift each scene's log likelihood ratio and picked innovation
/// ([`drive_shifted`]; zeros and NaN without).
#[pyfunction]
#[pyo3(signature = (sampler, slots, counts, grid, grids, bins, grid_roi, spacing, motion, seeds, stochastic, dt, steps, roi=None, low_data=None, starts=None, start_offsets=None, headings=None, shift=None))]
#[allow(clippy::too_many_arguments)]
pub fn scene_rollouts<'py>(
    py: Python<'py>,
    sampler: PyRef<'py, PySampler>,
    slots: Vec<usize>,
    counts: Vec<usize>,
    grid: Vec<usize>,
    grids: PyReadonlyArray2<'py, f64>,
    bins: (usize, usize),
    grid_roi: (f64, f64, f64, f64),
    spacing: Vec<f64>,
    motion: PyReadonlyArray2<'py, f64>,
    seeds: Vec<u64>,
    stochastic: bool,
    dt: f64,
    steps: usize,
    roi: Option<(f64, f64, f64, f64)>,
    low_data: Option<f64>,
    starts: Option<PyReadonlyArray2<'py, f64>>,
    start_offsets: Option<PyReadonlyArray1<'py, i64>>,
    headings: Headings<'py>,
    shift: Option<(f64, f64)>,
) -> PyResult<(
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray1<bool>>,
    Vec<usize>,
    Vec<f64>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<f64>>,
)> {
    let n = slots.len();
    let shift = shift.map(|(a, b)| Shift { mean: [a, b] });
    if shift.is_some() && !stochastic {
        return Err(CoreError(Error::InvalidInput(
            "a shift of the innovations needs drawn innovations (stochastic)".into(),
        ))
        .into());
    }
    // recorded configurations, one per scenario (thinned to the spacing), instead of placement
    let configs: Option<(&[Point], Vec<usize>)> = match (&starts, &start_offsets) {
        (Some(s), Some(o)) => {
            let xy: &[Point] = pairs("starts", s)?;
            dpgp_core::error::check_finite("starts", xy.as_flattened()).map_err(CoreError)?;
            Some((xy, offsets_of(o, n, xy.len())?))
        }
        (None, None) => None,
        _ => {
            return Err(CoreError(Error::InvalidInput(
                "starts and start_offsets go together".into(),
            ))
            .into());
        }
    };
    let opts = options(dt, steps, "euler", roi, None)?;
    if [counts.len(), grid.len(), spacing.len(), seeds.len()] != [n; 4] {
        return Err(CoreError(Error::Shape(format!(
            "counts, grid, spacing and seeds need one entry per scenario ({n})"
        )))
        .into());
    }
    let motion = motions(&motion, n)?;
    let g_roi = Roi::new(grid_roi.0, grid_roi.1, grid_roi.2, grid_roi.3).map_err(CoreError)?;
    let grids: Vec<Grid> = grids
        .as_array()
        .rows()
        .into_iter()
        .map(|w| Grid::new(g_roi, bins.0, bins.1, &w.to_vec()))
        .collect::<dpgp_core::Result<_>>()
        .map_err(CoreError)?;
    if let Some(&g) = grid.iter().find(|&&g| g >= grids.len()) {
        return Err(CoreError(Error::Shape(format!("grid {g} of {} grids", grids.len()))).into());
    }
    if let Some(s) = spacing.iter().find(|s| !(s.is_finite() && **s >= 0.0)) {
        return Err(CoreError(Error::InvalidInput(format!(
            "spacing must be finite and >= 0, got {s}"
        )))
        .into());
    }
    // the recorded vehicles' previous headings go with their configurations
    let h = match &configs {
        Some((xy, _)) => headings_of(&headings, xy.len())?,
        None if headings.is_some() => {
            return Err(CoreError(Error::InvalidInput(
                "start headings go with recorded configurations (starts)".into(),
            ))
            .into());
        }
        None => None,
    };
    let mut rollouts = in_parallel(py, &sampler, &slots, |_, p, i| {
        let seed = stochastic.then_some(seeds[i]);
        let field = PatternField::drawn_once(p, seed, low_data)?;
        let (start, mut field) = match &configs {
            Some((xy, off)) => {
                let kept: Vec<usize> = thin_kept(&xy[off[i]..off[i + 1]], spacing[i])
                    .into_iter()
                    .map(|k| off[i] + k)
                    .collect();
                // the kept vehicles' recorded headings: a field over heading's inputs, and every
                // steering vehicle's start where the field is too slow to have a heading
                let field = match h {
                    Some((h, speed)) => {
                        let kept_h: Vec<f64> = kept.iter().map(|&k| h[k]).collect();
                        field
                            .with_recorded_headings(kept_h.clone())
                            .with_headings(kept_h, speed)
                    }
                    None => field,
                };
                (kept.iter().map(|&k| xy[k]).collect::<Vec<Point>>(), field)
            }
            None => {
                let mut rng = stream(seeds[i], 0, Phase::Simulate, PLACEMENT_ENTITY);
                (
                    place(&grids[grid[i]], counts[i], spacing[i], &mut rng),
                    field,
                )
            }
        };
        match (shift, seed) {
            (Some(s), Some(seed)) => drive_shifted(&start, &opts, &motion[i], seed, s, &mut field),
            _ => drive(&start, None, &opts, &motion[i], seed, &mut field),
        }
    })?;
    let sizes = rollouts.iter().map(|r| r.vehicles).collect();
    let ratios = rollouts.iter().map(|r| r.log_ratio).collect();
    // steering vehicles' headings (NaN: not steering), row for row with the positions
    let headings: Vec<f64> = rollouts
        .iter_mut()
        .flat_map(|r| {
            if r.headings.is_empty() {
                vec![f64::NAN; r.positions.len()]
            } else {
                std::mem::take(&mut r.headings)
            }
        })
        .collect();
    let headings = PyArray1::from_vec(py, headings);
    let picks = to_numpy(
        py,
        rollouts
            .iter()
            .map(|r| r.pick.unwrap_or([f64::NAN; 2]))
            .collect(),
    );
    let (pos, vel, inside, low) = arrays(py, rollouts);
    Ok((pos, vel, inside, low, sizes, ratios, picks, headings))
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
    let opts = options(dt, steps, method, roi, None)?;
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

/// The posterior mean field of the pattern in `slots[i]` at rows `offsets[i]..offsets[i+1]` of
/// `xy` (no variances: `n m` per group), groups in parallel. For learning the residual model.
/// `h` (fields over heading): each row's previous heading (`NaN`: unknown, the field averaged
/// over heading).
#[pyfunction]
#[pyo3(signature = (sampler, slots, xy, offsets, h=None))]
pub fn field_means<'py>(
    py: Python<'py>,
    sampler: PyRef<'py, PySampler>,
    slots: Vec<usize>,
    xy: PyReadonlyArray2<'py, f64>,
    offsets: PyReadonlyArray1<'py, i64>,
    h: Option<PyReadonlyArray1<'py, f64>>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let xy: &[Point] = pairs("xy", &xy)?;
    let offsets = offsets_of(&offsets, slots.len(), xy.len())?;
    dpgp_core::error::check_finite("xy", xy.as_flattened()).map_err(CoreError)?;
    let h = h.map(|h| (h, 0.0));
    let h = headings_of(&h, xy.len())?.map(|(h, _)| h);
    if h.is_some_and(|h| h.iter().any(|x| x.is_infinite())) {
        return Err(CoreError(Error::InvalidInput(
            "headings must be finite radians or NaN (unknown)".into(),
        ))
        .into());
    }
    let means = in_parallel(py, &sampler, &slots, |_, p, i| {
        let (a, b) = (offsets[i], offsets[i + 1]);
        Ok(p.predict_mean_at(Inputs {
            xy: &xy[a..b],
            h: h.map_or(&[][..], |h| &h[a..b]),
        }))
    })?;
    Ok(to_numpy(py, means.into_iter().flatten().collect()))
}
