//! Rollouts: many vehicles moved together through a velocity field by forward Euler or
//! classical RK4 (docs/guide/generating.md).
//!
//! A vehicle moves while it is inside the region of interest; the step that carries it out
//! records the first position outside, and from then on it stands still (velocity 0,
//! `in_roi` false). A [`Field`] gives velocities in batches (one call per stage for all moving
//! vehicles) and, once per step, a velocity offset held over the step and low-data flags.
//! [`PatternField`] is a fitted pattern's GP: its posterior mean, or in stochastic mode a joint
//! draw from the latent posterior of all moving vehicles, and flags where the posterior
//! variance exceeds a fraction of the prior variance (the field there is mostly the prior).

use rand_distr::{Distribution, StandardNormal};

use crate::error::{Error, Result};
use crate::frame::{Inputs, Point};
use crate::pattern_model::PatternModel;
use crate::rng::{Phase, stream};
use crate::small;

/// Rollout rows (steps + 1 times vehicles) above which we refuse rather than risk running out
/// of memory on a typo (2^28 rows is 4 GiB of positions).
const MAX_ROWS: usize = 1 << 28;

/// The integration scheme.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Forward Euler (the paper's): global error O(dt).
    Euler,
    /// Classical fourth-order Runge-Kutta: global error O(dt⁴) in a smooth field.
    Rk4,
}

impl Method {
    pub fn parse(name: &str) -> Result<Self> {
        match name.to_ascii_lowercase().as_str() {
            "euler" => Ok(Self::Euler),
            "rk4" => Ok(Self::Rk4),
            _ => Err(Error::InvalidInput(format!(
                "method must be 'euler' or 'rk4', got {name:?}"
            ))),
        }
    }
}

/// The rectangle `[x_min, x_max] x [y_min, y_max]` (edges inside).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Roi {
    pub x_min: f64,
    pub x_max: f64,
    pub y_min: f64,
    pub y_max: f64,
}

impl Roi {
    pub fn new(x_min: f64, x_max: f64, y_min: f64, y_max: f64) -> Result<Self> {
        let ok = [x_min, x_max, y_min, y_max].iter().all(|v| v.is_finite())
            && x_min < x_max
            && y_min < y_max;
        if !ok {
            return Err(Error::InvalidInput(format!(
                "roi must be (x_min, x_max, y_min, y_max) with finite min < max, got ({x_min}, {x_max}, {y_min}, {y_max})"
            )));
        }
        Ok(Self {
            x_min,
            x_max,
            y_min,
            y_max,
        })
    }

    /// A rectangle that holds every finite point.
    pub fn everywhere() -> Self {
        Self {
            x_min: f64::MIN,
            x_max: f64::MAX,
            y_min: f64::MIN,
            y_max: f64::MAX,
        }
    }

    pub fn contains(&self, p: Point) -> bool {
        p[0] >= self.x_min && p[0] <= self.x_max && p[1] >= self.y_min && p[1] <= self.y_max
    }
}

/// How to integrate.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    /// Time step (seconds).
    pub dt: f64,
    pub steps: usize,
    pub method: Method,
    pub roi: Roi,
    /// Fields over heading: the turning limit `κ_max` (per unit length) of each step
    /// ([`crate::turning`]); `None`: the pure field.
    pub max_curvature: Option<f64>,
}

impl Options {
    fn validate(&self, vehicles: usize) -> Result<()> {
        if let Some(k) = self.max_curvature
            && !(k.is_finite() && k > 0.0)
        {
            return Err(Error::InvalidInput(format!(
                "max_curvature must be a positive number per unit length, got {k}"
            )));
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(Error::InvalidInput(format!(
                "dt must be a positive number of seconds, got {}",
                self.dt
            )));
        }
        if (self.steps.saturating_add(1)).saturating_mul(vehicles.max(1)) > MAX_ROWS {
            return Err(Error::InvalidInput(format!(
                "{} steps of {vehicles} vehicles is more than {MAX_ROWS} rows; simulate fewer steps",
                self.steps
            )));
        }
        Ok(())
    }
}

/// What a field says about the moving vehicles at the start of one step.
#[derive(Clone, Debug, Default)]
pub struct StepInfo {
    /// Added to every stage's velocity during the step (a stochastic draw's deviation from the mean).
    pub offset: Vec<[f64; 2]>,
    /// The vehicle is where the field has little data (all `false` when `deferred`).
    pub low_data: Vec<bool>,
    /// The field puts this step's flags off to the end of the rollout, where it answers every
    /// step's at once ([`Field::deferred_low_data`]): one batched solve instead of one per step.
    pub deferred: bool,
}

/// A velocity field the integrator queries in batches.
pub trait Field {
    /// Velocities at the points `q`, one per point.
    fn velocity(&mut self, q: &[Point]) -> Result<Vec<[f64; 2]>>;

    /// Called once per recorded time `step` with the moving vehicles' positions. Default: no
    /// offset and nothing flagged (a deterministic, everywhere-supported field).
    fn step_start(&mut self, _step: usize, q: &[Point]) -> Result<StepInfo> {
        Ok(StepInfo {
            offset: vec![[0.0; 2]; q.len()],
            low_data: vec![false; q.len()],
            deferred: false,
        })
    }

    /// The flags of every step whose [`StepInfo::deferred`] was set, in the order they were
    /// asked (step by step, vehicle by vehicle); called once, after the last step.
    fn deferred_low_data(&mut self) -> Result<Vec<bool>> {
        Ok(Vec::new())
    }

    /// How much the field knows at each point of `q`, from 0 (its prior: no data) to 1, or
    /// `None`: everywhere known (the default). Drivers follow a field only as far as it knows
    /// ([`crate::motion::drive`]).
    fn support(&mut self, _q: &[Point]) -> Result<Option<Vec<f64>>> {
        Ok(None)
    }

    /// A field over heading ([`crate::heading`]): every vehicle's previous heading at the start
    /// (`NaN`: unknown) and the speed from which a velocity gives one. The integrator then keeps
    /// each vehicle's heading as frames carry it (the last velocity at least that fast) and
    /// hands the moving vehicles' to [`Field::set_headings`] before each step's queries.
    /// Default `None`: a field over position.
    fn start_headings(&self) -> Option<(&[f64], f64)> {
        None
    }

    /// The previous headings of the vehicles the next queries are about (`NaN`: unknown).
    fn set_headings(&mut self, _h: &[f64]) {}

    /// Every vehicle's recorded heading at the start (`NaN`: unknown), whatever the field's
    /// inputs: a generated steering vehicle starts along it where the field is too slow to have
    /// a heading ([`crate::motion::drive`]). Default `None`.
    fn recorded_headings(&self) -> Option<&[f64]> {
        None
    }
}

/// The previous heading of every vehicle of a rollout, kept as frames carry it
/// (`dpgp.data._previous`): the heading of its last velocity at least `min_speed` fast, else the
/// one it started with.
pub struct HeadingTrack {
    h: Vec<f64>,
    min_speed: f64,
}

impl HeadingTrack {
    /// The track `field` asks for ([`Field::start_headings`]), `None` for a field over position.
    pub fn of(field: &dyn Field, vehicles: usize) -> Result<Option<Self>> {
        let Some((h, min_speed)) = field.start_headings() else {
            return Ok(None);
        };
        if h.len() != vehicles {
            return Err(Error::Shape(format!(
                "{} start headings for {vehicles} vehicles",
                h.len()
            )));
        }
        if h.iter().any(|x| x.is_infinite()) || !(min_speed.is_finite() && min_speed >= 0.0) {
            return Err(Error::InvalidInput(
                "start headings must be finite radians or NaN (unknown), with a finite heading speed >= 0".into(),
            ));
        }
        Ok(Some(Self {
            h: h.to_vec(),
            min_speed,
        }))
    }

    /// Tell `field` the headings of the vehicles `active`.
    pub fn tell(&self, field: &mut dyn Field, active: &[usize]) {
        let h: Vec<f64> = active.iter().map(|&j| self.h[j]).collect();
        field.set_headings(&h);
    }

    /// Vehicle `j`'s previous heading (`NaN`: unknown).
    pub fn heading(&self, j: usize) -> f64 {
        self.h[j]
    }

    /// Vehicle `j` moved with velocity `v`.
    pub fn moved(&mut self, j: usize, v: [f64; 2]) {
        if v[0].hypot(v[1]) >= self.min_speed.max(f64::MIN_POSITIVE) {
            self.h[j] = v[1].atan2(v[0]);
        }
    }
}

/// The headings a field over heading is queried with: the start ones and the current ones.
#[derive(Clone, Debug, Default)]
pub struct HeadingInput {
    start: Vec<f64>,
    min_speed: f64,
    now: Vec<f64>,
}

impl HeadingInput {
    pub fn new(start: Vec<f64>, min_speed: f64) -> Self {
        Self {
            start,
            min_speed,
            now: Vec::new(),
        }
    }

    fn inputs<'q>(&'q self, q: &'q [Point]) -> Inputs<'q> {
        Inputs {
            xy: q,
            h: if self.now.len() == q.len() {
                &self.now
            } else {
                &[]
            },
        }
    }
}

/// Any closure from positions to velocities is a deterministic field.
impl<F: FnMut(&[Point]) -> Result<Vec<[f64; 2]>>> Field for F {
    fn velocity(&mut self, q: &[Point]) -> Result<Vec<[f64; 2]>> {
        self(q)
    }
}

/// Positions and velocities of every vehicle at every recorded time (`steps + 1` times,
/// time-major: row `t * vehicles + j`).
#[derive(Clone, Debug, PartialEq)]
pub struct Rollout {
    pub vehicles: usize,
    pub steps: usize,
    pub positions: Vec<Point>,
    /// The velocity each vehicle moves with at that time (for RK4, the first stage's); 0 once stopped.
    pub velocities: Vec<[f64; 2]>,
    pub in_roi: Vec<bool>,
    pub low_data: Vec<bool>,
    /// Interactive rollouts only ([`crate::motion::drive_on`]): each vehicle's driver state after
    /// the last step, to continue it in another rollout (empty otherwise).
    pub drivers: Vec<[f64; 2]>,
    /// Interactive rollouts with a [`crate::motion::Shift`] of the residual's innovations: the
    /// log likelihood ratio of the rollout's random draws, natural against shifted, and the
    /// shifted innovation (`None` where its slot was never drawn; 0 and `None` without a shift).
    pub log_ratio: f64,
    pub pick: Option<[f64; 2]>,
    /// Interactive rollouts of steering vehicles: each vehicle's heading at each time (rows, as
    /// `positions`; NaN where it is not there), which a standing vehicle's zero velocity does
    /// not give; empty otherwise.
    pub headings: Vec<f64>,
}

impl Rollout {
    /// A rollout of `start` under `opts` with only its first time recorded (checked: finite
    /// positions, a valid time step, not too many rows).
    pub fn begin(start: &[Point], opts: &Options) -> Result<Self> {
        opts.validate(start.len())?;
        crate::error::check_finite("start positions", start.as_flattened())?;
        let rows = (opts.steps + 1) * start.len();
        let mut out = Self {
            vehicles: start.len(),
            steps: opts.steps,
            positions: Vec::with_capacity(rows),
            velocities: vec![[0.0; 2]; rows],
            in_roi: Vec::with_capacity(rows),
            low_data: vec![false; rows],
            drivers: Vec::new(),
            log_ratio: 0.0,
            pick: None,
            headings: Vec::new(),
        };
        out.positions.extend_from_slice(start);
        out.in_roi
            .extend(start.iter().map(|&p| opts.roi.contains(p)));
        Ok(out)
    }
}

/// Move the vehicles starting at `start` through `field`.
pub fn integrate(start: &[Point], opts: &Options, field: &mut dyn Field) -> Result<Rollout> {
    let mut out = Rollout::begin(start, opts)?;
    let (l, dt) = (start.len(), opts.dt);
    let rows = (opts.steps + 1) * l;
    let mut track = HeadingTrack::of(field, l)?;
    if opts.max_curvature.is_some() && track.is_none() {
        return Err(Error::InvalidInput(
            "a turning limit (max_curvature) needs a field over heading: the vehicles' headings"
                .into(),
        ));
    }
    // With a turning limit, what a vehicle moves with (and is recorded with) is the limited step.
    let limit =
        |track: &Option<HeadingTrack>, j: usize, v: [f64; 2]| match (opts.max_curvature, track) {
            (Some(k), Some(track)) => crate::turning::turn_limited(track.heading(j), v, k, dt),
            _ => v,
        };
    let mut late = LateFlags::default();
    for t in 0..=opts.steps {
        let row = t * l;
        let active: Vec<usize> = (0..l).filter(|&j| out.in_roi[row + j]).collect();
        let x: Vec<Point> = active.iter().map(|&j| out.positions[row + j]).collect();
        let mut next = out.positions[row..row + l].to_vec();
        if !active.is_empty() {
            // the heading is held over the step (RK4's stages too): the previous step's
            if let Some(track) = &track {
                track.tell(field, &active);
            }
            let info = field.step_start(t, &x)?;
            check_len("step offset", info.offset.len(), x.len())?;
            check_len("low-data flags", info.low_data.len(), x.len())?;
            late.note(&info, row, &active);
            let off = info.offset;
            let eval = |field: &mut dyn Field, q: &[Point]| -> Result<Vec<[f64; 2]>> {
                let v = field.velocity(q)?;
                check_len("field velocities", v.len(), q.len())?;
                Ok(v.iter()
                    .zip(&off)
                    .map(|(v, o)| [v[0] + o[0], v[1] + o[1]])
                    .collect())
            };
            let k1 = eval(field, &x)?;
            for (a, &j) in active.iter().enumerate() {
                out.velocities[row + j] = limit(&track, j, k1[a]);
                out.low_data[row + j] = info.low_data[a];
            }
            if t == opts.steps {
                break;
            }
            let step: Vec<[f64; 2]> = match opts.method {
                Method::Euler => k1,
                Method::Rk4 => {
                    let k2 = eval(field, &shifted(&x, &k1, 0.5 * dt))?;
                    let k3 = eval(field, &shifted(&x, &k2, 0.5 * dt))?;
                    let k4 = eval(field, &shifted(&x, &k3, dt))?;
                    (0..x.len())
                        .map(|a| {
                            let f = |d: usize| {
                                (k1[a][d] + 2.0 * k2[a][d] + 2.0 * k3[a][d] + k4[a][d]) / 6.0
                            };
                            [f(0), f(1)]
                        })
                        .collect()
                }
            };
            for (a, &j) in active.iter().enumerate() {
                let v = limit(&track, j, step[a]);
                if opts.max_curvature.is_some() {
                    out.velocities[row + j] = v; // RK4: the limited step, not its first stage
                }
                next[j] = [x[a][0] + dt * v[0], x[a][1] + dt * v[1]];
                if let Some(track) = track.as_mut() {
                    track.moved(j, v);
                }
            }
        } else if t == opts.steps {
            break;
        }
        for (j, p) in next.iter().enumerate() {
            let moving = out.in_roi[row + j];
            out.in_roi
                .push(moving && p[0].is_finite() && p[1].is_finite() && opts.roi.contains(*p));
        }
        out.positions.extend_from_slice(&next);
    }
    // Every vehicle had left: the remaining times repeat the last positions, standing still.
    while out.positions.len() < rows {
        let last = out.positions.len() - l;
        out.positions.extend_from_within(last..last + l);
        out.in_roi.extend(std::iter::repeat_n(false, l));
    }
    late.fill(field, &mut out.low_data)?;
    Ok(out)
}

fn shifted(x: &[Point], k: &[[f64; 2]], h: f64) -> Vec<Point> {
    x.iter()
        .zip(k)
        .map(|(p, v)| [p[0] + h * v[0], p[1] + h * v[1]])
        .collect()
}

/// The rows whose low-data flags a field put off ([`StepInfo::deferred`]), filled from
/// [`Field::deferred_low_data`] once the rollout has run.
#[derive(Default)]
pub(crate) struct LateFlags {
    rows: Vec<usize>,
}

impl LateFlags {
    /// Note the step at `row` whose moving vehicles are `active`.
    pub(crate) fn note(&mut self, info: &StepInfo, row: usize, active: &[usize]) {
        if info.deferred {
            self.rows.extend(active.iter().map(|&j| row + j));
        }
    }

    pub(crate) fn fill(self, field: &mut dyn Field, flags: &mut [bool]) -> Result<()> {
        if self.rows.is_empty() {
            return Ok(());
        }
        let late = field.deferred_low_data()?;
        check_len("deferred low-data flags", late.len(), self.rows.len())?;
        for (r, f) in self.rows.into_iter().zip(late) {
            flags[r] = f;
        }
        Ok(())
    }
}

fn check_len(what: &str, got: usize, want: usize) -> Result<()> {
    if got != want {
        return Err(Error::Shape(format!(
            "{what}: {got} values for {want} vehicles"
        )));
    }
    Ok(())
}

/// A fitted pattern's GP as a field.
pub struct PatternField<'a> {
    pattern: &'a dyn PatternModel,
    /// `Some(seed)`: stochastic mode.
    seed: Option<u64>,
    /// Flag a point when its latent posterior variance exceeds this fraction of the prior
    /// signal variance in either output; `None` computes no flags.
    low_data: Option<f64>,
    /// Draw at step 0 only (the start velocities of a generated scene), the mean after that.
    draw_once: bool,
    /// Answer [`Field::support`] (a triangular solve per point and step); else `None`.
    support: bool,
    /// A field over heading: the vehicles' headings ([`Field::start_headings`]).
    headings: Option<HeadingInput>,
    /// The vehicles' recorded headings at the start ([`Field::recorded_headings`]).
    recorded: Option<Vec<f64>>,
    /// The points (and, over heading, headings) of the flags put off so far
    /// ([`StepInfo::deferred`]).
    late: Vec<Point>,
    late_h: Vec<f64>,
}

impl<'a> PatternField<'a> {
    pub fn new(
        pattern: &'a dyn PatternModel,
        seed: Option<u64>,
        low_data: Option<f64>,
    ) -> Result<Self> {
        if let Some(f) = low_data
            && !(f.is_finite() && f >= 0.0)
        {
            return Err(Error::InvalidInput(format!(
                "the low-data threshold is a fraction of the prior variance (>= 0), got {f}"
            )));
        }
        Ok(Self {
            pattern,
            seed,
            low_data,
            draw_once: false,
            support: false,
            headings: None,
            recorded: None,
            late: Vec::new(),
            late_h: Vec::new(),
        })
    }

    /// The vehicles' recorded headings at the start (`NaN`: unknown; [`Field::recorded_headings`]).
    pub fn with_recorded_headings(mut self, h: Vec<f64>) -> Self {
        self.recorded = Some(h);
        self
    }

    /// The field queried at each vehicle's previous heading too, `start` at the start (`NaN`:
    /// unknown), then as [`HeadingTrack`] keeps them; a field over position ignores them.
    pub fn with_headings(mut self, start: Vec<f64>, min_speed: f64) -> Self {
        self.headings = self
            .pattern
            .headed()
            .then(|| HeadingInput::new(start, min_speed));
        self
    }

    fn inputs<'q>(&'q self, q: &'q [Point]) -> Inputs<'q> {
        match &self.headings {
            Some(h) => h.inputs(q),
            None => Inputs::positions(q),
        }
    }

    /// The field answering [`Field::support`]: `1 − v / s²` of its latent posterior variance `v`
    /// against the prior's `s²`, in the output that knows less.
    pub fn with_support(mut self, support: bool) -> Self {
        self.support = support;
        self
    }

    /// A field that draws jointly at step 0 only (with `seed`), then gives its mean: the start
    /// velocities of a generated scene, for [`crate::motion::drive`].
    pub fn drawn_once(
        pattern: &'a dyn PatternModel,
        seed: Option<u64>,
        low_data: Option<f64>,
    ) -> Result<Self> {
        let mut f = Self::new(pattern, seed, low_data)?;
        f.draw_once = true;
        Ok(f)
    }
}

impl Field for PatternField<'_> {
    fn velocity(&mut self, q: &[Point]) -> Result<Vec<[f64; 2]>> {
        Ok(self.pattern.predict_mean_at(self.inputs(q)))
    }

    fn deferred_low_data(&mut self) -> Result<Vec<bool>> {
        let (xy, h) = (
            std::mem::take(&mut self.late),
            std::mem::take(&mut self.late_h),
        );
        Ok(match self.low_data {
            Some(f) if !xy.is_empty() => self.pattern.low_data_at(Inputs { xy: &xy, h: &h }, f),
            _ => Vec::new(),
        })
    }

    fn support(&mut self, q: &[Point]) -> Result<Option<Vec<f64>>> {
        if !self.support {
            return Ok(None);
        }
        let (_, var) = self.pattern.posterior_at(self.inputs(q));
        Ok(Some(support_of(self.pattern, &var)))
    }

    fn start_headings(&self) -> Option<(&[f64], f64)> {
        self.headings.as_ref().map(|h| (&h.start[..], h.min_speed))
    }

    fn set_headings(&mut self, h: &[f64]) {
        if let Some(own) = self.headings.as_mut() {
            own.now = h.to_vec();
        }
    }

    fn recorded_headings(&self) -> Option<&[f64]> {
        self.recorded.as_deref()
    }

    fn step_start(&mut self, step: usize, q: &[Point]) -> Result<StepInfo> {
        let m = q.len();
        let mut info = StepInfo {
            offset: vec![[0.0; 2]; m],
            low_data: vec![false; m],
            deferred: false,
        };
        let seed = if self.draw_once && step > 0 {
            None
        } else {
            self.seed
        };
        if seed.is_none() && self.low_data.is_none() {
            return Ok(info);
        }
        if seed.is_none() {
            // Flags only (they move no vehicle): put off to the end of the rollout, where every
            // step's points take the nearest training points' bound and, where it cannot decide,
            // one batched solve (per step, each solve read the pattern's whole factor for a few
            // points). No m x m matrix either.
            if self.headings.is_some() {
                let input = self.inputs(q);
                let h: Vec<f64> = (0..m).map(|j| input.heading(j)).collect();
                self.late_h.extend(h);
            }
            self.late.extend_from_slice(q);
            info.deferred = true;
            return Ok(info);
        }
        // The latent covariance costs n² m (a triangular solve per vehicle); it gives both the
        // variances for the flags and the matrix to draw from.
        let (_, mut cov) = self.pattern.predict_joint_at(self.inputs(q));
        let s2 = self.pattern.params().signal_var;
        if let Some(f) = self.low_data {
            for (j, flag) in info.low_data.iter_mut().enumerate() {
                *flag = crate::low_data::is_low([cov[0][j * m + j], cov[1][j * m + j]], s2, f);
            }
        }
        if let Some(seed) = seed {
            // A floor of 1e-10 of the prior variance on the diagonal: the exact posterior is PSD,
            // but with rounding a variance near a dense cluster of data can come out ≤ 0.
            for (d, c) in cov.iter_mut().enumerate() {
                for j in 0..m {
                    c[j * m + j] += 1e-10 * s2[d];
                }
            }
            let mut rng = stream(seed, step as u64, Phase::Simulate, 0);
            let shared = cov[0] == cov[1];
            for d in 0..2 {
                if d == 0 || !shared {
                    // Rounding can leave the exact PSD posterior slightly indefinite, and
                    // vehicles on top of each other make it singular: the jittered Cholesky copes.
                    small::cholesky(&mut cov[d], m)?;
                } else {
                    cov[1] = cov[0].clone();
                }
                let z: Vec<f64> = (0..m).map(|_| StandardNormal.sample(&mut rng)).collect();
                let l = &cov[d];
                for i in 0..m {
                    info.offset[i][d] = (0..=i).map(|c| l[c * m + i] * z[c]).sum();
                }
            }
        }
        Ok(info)
    }
}

/// The share of a pattern's prior variance its data explain at each point, `1 − v / s²` in the
/// output that knows less, in [0, 1]: what [`Field::support`] answers for one pattern.
fn support_of(pattern: &dyn PatternModel, var: &[[f64; 2]]) -> Vec<f64> {
    let s2 = pattern.params().signal_var;
    var.iter()
        .map(|v| {
            (0..2)
                .map(|d| 1.0 - v[d] / s2[d])
                .fold(1.0, f64::min)
                .clamp(0.0, 1.0)
        })
        .collect()
}

/// Several patterns' fields as one (a phase of a long scenario, whose patterns each know a
/// different part of the scene): at a point, each pattern's posterior mean counts by its weight
/// and by its support there, `s_k` ([`PatternField::with_support`]): `Σ w_k s_k μ_k / Σ w_k s_k`,
/// and where none knows anything, `Σ w_k μ_k / Σ w_k` (the prior's mean). Its support is the
/// same weights' mean support, `Σ w_k s_k² / Σ w_k s_k`: the patterns that know a point speak
/// for it, as much as they know it. One pattern of weight 1 is [`PatternField`] with support.
pub struct MixtureField<'a> {
    parts: Vec<(&'a dyn PatternModel, f64)>,
    /// The last points asked about and the answers (velocity then support ask for the same).
    last: Option<(Vec<Point>, Vec<[f64; 2]>, Vec<f64>)>,
    /// Fields over heading: the vehicles' headings, as [`PatternField::with_headings`].
    headings: Option<HeadingInput>,
}

impl<'a> MixtureField<'a> {
    pub fn new(parts: Vec<(&'a dyn PatternModel, f64)>) -> Result<Self> {
        if parts.is_empty() || parts.iter().any(|p| !(p.1.is_finite() && p.1 >= 0.0)) {
            return Err(Error::InvalidInput(
                "a mixture field needs at least one pattern and finite non-negative weights".into(),
            ));
        }
        if parts.iter().map(|p| p.1).sum::<f64>() <= 0.0 {
            return Err(Error::InvalidInput(
                "a mixture field's weights sum to 0".into(),
            ));
        }
        Ok(Self {
            parts,
            last: None,
            headings: None,
        })
    }

    /// As [`PatternField::with_headings`] (patterns over position ignore the headings).
    pub fn with_headings(mut self, start: Vec<f64>, min_speed: f64) -> Self {
        self.headings = self
            .parts
            .iter()
            .any(|p| p.0.headed())
            .then(|| HeadingInput::new(start, min_speed));
        self
    }

    fn answer(&mut self, q: &[Point]) -> &(Vec<Point>, Vec<[f64; 2]>, Vec<f64>) {
        if self.last.as_ref().is_none_or(|l| l.0 != q) {
            let input = match &self.headings {
                Some(h) => h.inputs(q),
                None => Inputs::positions(q),
            };
            let m = q.len();
            let (mut num, mut den, mut sq) = (vec![[0.0; 2]; m], vec![0.0; m], vec![0.0; m]);
            let (mut prior, mut total) = (vec![[0.0; 2]; m], 0.0);
            for &(pattern, w) in &self.parts {
                let (mean, var) = pattern.posterior_at(input);
                let s = support_of(pattern, &var);
                total += w;
                for j in 0..m {
                    for d in 0..2 {
                        num[j][d] += w * s[j] * mean[j][d];
                        prior[j][d] += w * mean[j][d];
                    }
                    den[j] += w * s[j];
                    sq[j] += w * s[j] * s[j];
                }
            }
            let mut vel = vec![[0.0; 2]; m];
            let mut sup = vec![0.0; m];
            for j in 0..m {
                if den[j] > 1e-12 * total {
                    vel[j] = [num[j][0] / den[j], num[j][1] / den[j]];
                    sup[j] = (sq[j] / den[j]).clamp(0.0, 1.0);
                } else {
                    vel[j] = [prior[j][0] / total, prior[j][1] / total];
                }
            }
            self.last = Some((q.to_vec(), vel, sup));
        }
        self.last.as_ref().expect("set above")
    }
}

impl Field for MixtureField<'_> {
    fn velocity(&mut self, q: &[Point]) -> Result<Vec<[f64; 2]>> {
        Ok(self.answer(q).1.clone())
    }

    fn support(&mut self, q: &[Point]) -> Result<Option<Vec<f64>>> {
        Ok(Some(self.answer(q).2.clone()))
    }

    fn start_headings(&self) -> Option<(&[f64], f64)> {
        self.headings.as_ref().map(|h| (&h.start[..], h.min_speed))
    }

    fn set_headings(&mut self, h: &[f64]) {
        if let Some(own) = self.headings.as_mut() {
            own.now = h.to_vec();
            self.last = None; // the cache is keyed by position alone
        }
    }
}

/// Roll the vehicles at `start` through `pattern`: its posterior mean, or with `seed` joint
/// posterior draws at every step; flags per [`PatternField`].
pub fn rollout(
    pattern: &dyn PatternModel,
    start: &[Point],
    opts: &Options,
    seed: Option<u64>,
    low_data: Option<f64>,
) -> Result<Rollout> {
    integrate(
        start,
        opts,
        &mut PatternField::new(pattern, seed, low_data)?,
    )
}

#[cfg(test)]
#[path = "tests/simulate.rs"]
mod tests;
