//! Interactive rollouts (docs/generation.md): the field gives each vehicle
//! its *desired* velocity; its actual velocity deviates from it by a temporally correlated
//! residual, and vehicles keep their distance from one another.
//!
//! One step, from recorded time `t` to `t + 1` (forward Euler, as the paper's rollout):
//!
//! 1. positions move with the current actual velocities: `x ← x + dt v`;
//! 2. each agent's desired velocity `w` relaxes toward the field's mean `m(x)` at its new
//!    position as an Ornstein–Uhlenbeck process, exactly discretised:
//!    `w ← m(x) + ρ (w − m(x)) + σ √(1 − ρ²) z` with `ρ = exp(−dt / τ)` (`z = 0` in mean
//!    mode): the residual `w − m` decays with time constant `τ` and has stationary spread `σ`
//!    per component. The deviation is measured at the new position, so a field that changes
//!    along the path is followed with the lag `τ` (a first-order lag of the velocity), and a
//!    large `τ` keeps an agent close to constant velocity;
//! 3. interaction turns desired into actual velocities ([`Rule`]): vehicles follow the leader
//!    in a corridor ahead by the Intelligent Driver Model (IDM, Treiber et al. 2000), the
//!    desired speed being `|w|`; every agent then keeps a personal distance from its
//!    neighbours (the part of a pair's approach that would bring it closer than the distance is
//!    removed, half from each).
//!
//! The desired velocity is the driver's own; braking behind a leader does not change it, so a
//! vehicle resumes its preferred speed (at IDM's acceleration) once free.
//!
//! Random numbers come from counter-based streams keyed by (seed, step, vehicle order), so a
//! rollout is the same whichever thread runs it.

use rand_distr::{Distribution, StandardNormal};

use crate::error::{Error, Result};
use crate::frame::Point;
use crate::rng::{Phase, stream};
use crate::simulate::{Field, Method, Options, Rollout};

/// Stream entity of the residual's innovations (entity 0 is the GP draw at step 0).
const NOISE_ENTITY: u64 = 1;
/// Speeds below this fraction of the desired one count as standing (no heading from them).
const TINY: f64 = 1e-12;

/// Car-following by the Intelligent Driver Model, distances centre to centre.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Idm {
    /// Jam distance `s0`: centre-to-centre distance of stopped vehicles in a queue.
    pub jam: f64,
    /// Desired time headway `T` (s).
    pub headway: f64,
    /// Maximum acceleration `a` (length/s²).
    pub accel: f64,
    /// Comfortable deceleration `b` (length/s²).
    pub decel: f64,
    /// Half-width of the corridor ahead in which another vehicle counts as a leader.
    pub lateral: f64,
}

/// How agents interact.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Rule {
    /// No interaction: each agent follows its desired velocity.
    Free,
    /// IDM behind a leader, then a personal distance (a last guard).
    Vehicles { idm: Idm, personal: f64 },
    /// A personal distance only.
    Pedestrians { personal: f64 },
}

/// The residual model and the interaction rule of one pattern.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motion {
    /// OU time constant (s); `f64::INFINITY` holds the residual (constant-velocity deviation).
    pub tau: f64,
    /// Stationary standard deviation of the residual per component.
    pub sigma: [f64; 2],
    pub rule: Rule,
}

/// Numbers in a flat [`Motion`] record: `tau, sigma_x, sigma_y, kind (0 free, 1 vehicles,
/// 2 pedestrians), personal, jam, headway, accel, decel, lateral`.
pub const MOTION_FIELDS: usize = 10;

impl Motion {
    /// From the flat record of [`MOTION_FIELDS`] numbers (what the binding passes).
    pub fn from_slice(v: &[f64]) -> Result<Self> {
        if v.len() != MOTION_FIELDS {
            return Err(Error::Shape(format!(
                "a motion record has {MOTION_FIELDS} numbers, got {}",
                v.len()
            )));
        }
        let rule = match v[3] as i64 {
            0 => Rule::Free,
            1 => Rule::Vehicles {
                personal: v[4],
                idm: Idm {
                    jam: v[5],
                    headway: v[6],
                    accel: v[7],
                    decel: v[8],
                    lateral: v[9],
                },
            },
            2 => Rule::Pedestrians { personal: v[4] },
            k => {
                return Err(Error::InvalidInput(format!(
                    "interaction kind must be 0 (free), 1 (vehicles) or 2 (pedestrians), got {k}"
                )));
            }
        };
        let m = Self {
            tau: v[0],
            sigma: [v[1], v[2]],
            rule,
        };
        m.validate()?;
        Ok(m)
    }

    pub fn validate(&self) -> Result<()> {
        let bad = |what: &str, x: f64| {
            Err(Error::InvalidInput(format!(
                "motion parameter {what} must be a positive finite number, got {x}"
            )))
        };
        if !(self.tau > 0.0) || self.tau.is_nan() {
            return bad("tau (s; inf holds the residual)", self.tau);
        }
        for s in self.sigma {
            if !(s.is_finite() && s >= 0.0) {
                return Err(Error::InvalidInput(format!(
                    "motion parameter sigma must be finite and >= 0, got {s}"
                )));
            }
        }
        let positive = |what: &str, x: f64| {
            if x.is_finite() && x > 0.0 {
                Ok(())
            } else {
                bad(what, x)
            }
        };
        match self.rule {
            Rule::Free => {}
            Rule::Pedestrians { personal } => positive("personal distance", personal)?,
            Rule::Vehicles { idm, personal } => {
                positive("personal distance", personal)?;
                positive("jam distance", idm.jam)?;
                positive("headway", idm.headway)?;
                positive("accel", idm.accel)?;
                positive("decel", idm.decel)?;
                positive("lateral", idm.lateral)?;
            }
        }
        Ok(())
    }
}

/// IDM acceleration of a follower at speed `u` with desired speed `u0`, `gap` (centre to
/// centre) behind a leader moving at `leader` along the follower's heading; `gap = None` for a
/// free road.
pub fn idm_accel(u: f64, u0: f64, gap: Option<(f64, f64)>, p: &Idm) -> f64 {
    let free = if u0 > TINY {
        1.0 - (u / u0).powi(4)
    } else {
        -1.0
    };
    let inter = match gap {
        None => 0.0,
        Some((g, leader)) => {
            let s_star = p.jam
                + (u * p.headway + u * (u - leader) / (2.0 * (p.accel * p.decel).sqrt())).max(0.0);
            (s_star / g.max(TINY)).powi(2)
        }
    };
    p.accel * (free - inter)
}

/// The nearest agent ahead of `i` (along `heading`, a unit vector) whose lateral offset is
/// within `lateral`: (its index, gap along the heading).
fn leader(i: usize, x: &[Point], heading: [f64; 2], lateral: f64) -> Option<(usize, f64)> {
    let mut best: Option<(usize, f64)> = None;
    for (j, q) in x.iter().enumerate() {
        if j == i {
            continue;
        }
        let d = [q[0] - x[i][0], q[1] - x[i][1]];
        let along = d[0] * heading[0] + d[1] * heading[1];
        let side = (d[0] * heading[1] - d[1] * heading[0]).abs();
        if along > 0.0 && side <= lateral && best.is_none_or(|(_, g)| along < g) {
            best = Some((j, along));
        }
    }
    best
}

/// Actual velocities of agents at `x` that move at `current` and want `desired` (see the
/// module docs). Deterministic; O(m²).
pub fn interact(
    x: &[Point],
    current: &[[f64; 2]],
    desired: &[[f64; 2]],
    rule: &Rule,
    dt: f64,
) -> Vec<[f64; 2]> {
    let mut v = desired.to_vec();
    let personal = match *rule {
        Rule::Free => return v,
        Rule::Pedestrians { personal } => personal,
        Rule::Vehicles { idm, personal } => {
            for i in 0..x.len() {
                let u0 = desired[i][0].hypot(desired[i][1]);
                if u0 <= TINY {
                    continue;
                }
                let e = [desired[i][0] / u0, desired[i][1] / u0];
                let Some((j, g)) = leader(i, x, e, idm.lateral) else {
                    continue;
                };
                let u = current[i][0].hypot(current[i][1]);
                let lead = current[j][0] * e[0] + current[j][1] * e[1];
                let next = u + dt * idm_accel(u, u0, Some((g, lead)), &idm);
                // Euler can overshoot a hard stop: never close more than half the jam distance.
                let guard = (g - 0.5 * idm.jam) / dt + lead.max(0.0);
                let speed = next.min(guard).clamp(0.0, u0);
                v[i] = [e[0] * speed, e[1] * speed];
            }
            personal
        }
    };
    keep_distance(x, &mut v, personal, dt);
    v
}

/// Remove, from every pair closer than `2 d` after the step, the part of its approach that
/// would bring it within `d`: half from each (computed from the velocities before any change,
/// so the result does not depend on the order of the agents).
fn keep_distance(x: &[Point], v: &mut [[f64; 2]], d: f64, dt: f64) {
    let before = v.to_vec();
    for i in 0..x.len() {
        for j in 0..x.len() {
            if i == j {
                continue;
            }
            let n = [x[i][0] - x[j][0], x[i][1] - x[j][1]];
            let dist = n[0].hypot(n[1]);
            if dist >= 2.0 * d + dt * speed_bound(&before[i], &before[j]) || dist <= TINY {
                continue;
            }
            let n = [n[0] / dist, n[1] / dist];
            // rate at which the distance grows, and the least rate that keeps it at d or more
            let grow = (before[i][0] - before[j][0]) * n[0] + (before[i][1] - before[j][1]) * n[1];
            let need = (d - dist) / dt;
            if grow < need {
                let push = 0.5 * (need - grow);
                v[i][0] += push * n[0];
                v[i][1] += push * n[1];
            }
        }
    }
}

fn speed_bound(a: &[f64; 2], b: &[f64; 2]) -> f64 {
    a[0].hypot(a[1]) + b[0].hypot(b[1])
}

/// Roll the agents at `start` forward: with their own velocities `v0`, or (`None`) with a joint
/// draw from `field` at step 0 (its `step_start` offset) plus a stationary residual draw.
/// `field.velocity` is the mean field; `field.step_start` also flags low-data points.
/// `seed`: the residual's innovations (`None`: mean mode, the residual only relaxes).
pub fn drive(
    start: &[Point],
    v0: Option<&[[f64; 2]]>,
    opts: &Options,
    motion: &Motion,
    seed: Option<u64>,
    field: &mut dyn Field,
) -> Result<Rollout> {
    motion.validate()?;
    if opts.method != Method::Euler {
        return Err(Error::InvalidInput(
            "interactive dynamics integrate by forward Euler (method='euler'); RK4 applies to the pure field (dynamics='field')".into(),
        ));
    }
    if let Some(v) = v0 {
        if v.len() != start.len() {
            return Err(Error::Shape(format!(
                "{} start velocities for {} start positions",
                v.len(),
                start.len()
            )));
        }
        crate::error::check_finite("start velocities", v.as_flattened())?;
    }
    let mut out = Rollout::begin(start, opts)?;
    let (l, dt) = (start.len(), opts.dt);
    let rho = (-dt / motion.tau).exp();
    let kick = (1.0 - rho * rho).max(0.0).sqrt();
    let mut want = vec![[0.0; 2]; l]; // desired velocities
    let mut vel = vec![[0.0; 2]; l]; // actual velocities
    for t in 0..=opts.steps {
        let row = t * l;
        let active: Vec<usize> = (0..l).filter(|&j| out.in_roi[row + j]).collect();
        let x: Vec<Point> = active.iter().map(|&j| out.positions[row + j]).collect();
        if !active.is_empty() {
            let info = field.step_start(t, &x)?;
            let mean = field.velocity(&x)?;
            if mean.len() != x.len()
                || info.low_data.len() != x.len()
                || info.offset.len() != x.len()
            {
                return Err(Error::Shape(
                    "the field answered for a different number of vehicles".into(),
                ));
            }
            if t == 0 {
                let mut rng = seed.map(|s| stream(s, 0, Phase::Simulate, NOISE_ENTITY));
                for (a, &j) in active.iter().enumerate() {
                    // own velocities exactly; else the GP draw plus a stationary residual
                    want[j] = match v0 {
                        Some(v) => v[j],
                        None => {
                            let mut w = [
                                mean[a][0] + info.offset[a][0],
                                mean[a][1] + info.offset[a][1],
                            ];
                            if let Some(rng) = rng.as_mut() {
                                for (d, wd) in w.iter_mut().enumerate() {
                                    let z: f64 = StandardNormal.sample(rng);
                                    *wd += motion.sigma[d] * z;
                                }
                            }
                            w
                        }
                    };
                    vel[j] = want[j];
                }
            } else {
                let mut rng = seed.map(|s| stream(s, t as u64, Phase::Simulate, NOISE_ENTITY));
                let mut desired = Vec::with_capacity(x.len());
                let mut current = Vec::with_capacity(x.len());
                for (a, &j) in active.iter().enumerate() {
                    for d in 0..2 {
                        let z: f64 = match rng.as_mut() {
                            Some(rng) => StandardNormal.sample(rng),
                            None => 0.0,
                        };
                        want[j][d] = mean[a][d]
                            + rho * (want[j][d] - mean[a][d])
                            + motion.sigma[d] * kick * z;
                    }
                    desired.push(want[j]);
                    current.push(vel[j]);
                }
                let actual = interact(&x, &current, &desired, &motion.rule, dt);
                for (a, &j) in active.iter().enumerate() {
                    vel[j] = actual[a];
                }
            }
            for (a, &j) in active.iter().enumerate() {
                out.velocities[row + j] = vel[j];
                out.low_data[row + j] = info.low_data[a];
            }
        }
        if t == opts.steps {
            break;
        }
        let mut next = out.positions[row..row + l].to_vec();
        for &j in &active {
            next[j] = [next[j][0] + dt * vel[j][0], next[j][1] + dt * vel[j][1]];
        }
        for (j, p) in next.iter().enumerate() {
            let moving = out.in_roi[row + j];
            out.in_roi
                .push(moving && p[0].is_finite() && p[1].is_finite() && opts.roi.contains(*p));
        }
        out.positions.extend_from_slice(&next);
    }
    Ok(out)
}

#[cfg(test)]
#[path = "tests/motion.rs"]
mod tests;
