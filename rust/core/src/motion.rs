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
//!    mode): the residual `w − m` decays with time constant `τ` and has stationary spread `σ`.
//!    The spread is given along and across the field's local heading `e = m(x) / |m(x)|`
//!    ([`Spread::Heading`]): the innovation is drawn in that rotated frame, `σ_along z₁ e +
//!    σ_across z₂ e⊥` (and the across part may relax with its own `τ_across`), so a vehicle
//!    keeps its lane while its speed varies; where the field is slower than a threshold (no
//!    heading: pedestrians standing), it is isotropic with `σ² = (σ_along² + σ_across²) / 2`.
//!    Models stored before that give it per x/y component ([`Spread::Components`]). The
//!    spreads are scaled by a [`Profile`] of the field's speed `|m(x)|` (small where the field
//!    is slow: queues). A steering vehicle ([`Motion::tau_heading`]) keeps a heading and a
//!    desired speed instead: the speed relaxes as the along part, the heading turns toward the
//!    field's with its own time constant (by the part of the angle beyond a tolerance), and a
//!    desired speed below a stand speed stands. The deviation is measured at the new position, so a field that changes
//!    along the path is followed with the lag `τ` (a first-order lag of the velocity), and a
//!    large `τ` keeps an agent close to constant velocity;
//! 3. interaction turns desired into actual velocities ([`Rule`]): vehicles follow the leader
//!    in a corridor ahead by the Intelligent Driver Model (IDM, Treiber et al. 2000), the
//!    desired speed being `|w|`, and change speed by its free-road term without a leader
//!    (toward `|w|`, not past it); every agent then keeps a personal distance from its
//!    neighbours (the part of a pair's approach that would bring it closer than the distance is
//!    removed, half from each). A red signal's stop line ([`Stop`]) is, to the vehicles of its
//!    approach, one more standing leader.
//!
//! The desired velocity is the driver's own; braking behind a leader does not change it, so a
//! vehicle resumes its preferred speed (at IDM's acceleration) once free.
//!
//! Random numbers come from counter-based streams keyed by (seed, step, vehicle order), so a
//! rollout is the same whichever thread runs it.

use rand_distr::{Distribution, StandardNormal};

use crate::error::{Error, Result};
use crate::frame::Point;
use crate::rng::{Phase, stream, uniform};
use crate::simulate::{Field, HeadingTrack, LateFlags, Method, Options, Rollout};

/// Stream entity of the residual's innovations (entity 0 is the GP draw at step 0).
const NOISE_ENTITY: u64 = 1;
/// Stream entity of the pedestrians' step jitter ([`Motion::jitter`]): its own stream, so that a
/// model without jitter draws exactly the numbers it drew before.
const JITTER_ENTITY: u64 = 2;
/// Stream entity of a [`Shift`]'s choice of the innovation it moves.
const SHIFT_ENTITY: u64 = 3;
/// Passes that settle a generated queue's first speeds from its front ([`start_behind_leaders`]).
const START_PASSES: usize = 8;
/// Cosine of the widest angle between two vehicles' headings at which one follows the other (60°).
const CROSSING: f64 = 0.5;
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
    /// The hardest a vehicle can brake (length/s²; `f64::INFINITY`: no bound): tyres on a dry
    /// road give about 1 g. IDM asks for far more when a neighbour cuts in at a short gap, and
    /// generated vehicles stopped from 40 ft/s in one 0.5 s step (issue 35).
    pub brake: f64,
    /// The vehicles' length: a leader's bumper is `gap − length` ahead (0: not known, and IDM+
    /// alone, without the cut-in moderation of [`acc_accel`]).
    pub length: f64,
    /// The vehicles' width: a vehicle alongside (centres less than a length apart along) does not
    /// move sideways into one's side ([`keep_sides`]; 0: not known, no such rule).
    pub width: f64,
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

/// In which frame the residual's spreads [`Motion::sigma`] are given.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Spread {
    /// Per x/y component (models stored before the heading frame).
    Components,
    /// `[along, across]` the field's local heading; isotropic where `|m(x)|` is below
    /// `min_speed`. The across part relaxes with time constant `tau_across`.
    Heading { min_speed: f64, tau_across: f64 },
}

/// Knots of a [`Profile`].
pub const PROFILE_KNOTS: usize = 8;

/// The residual's spread as a function of the field's local speed `|m(x)|`: factors on
/// [`Motion::sigma`] (along, across) at increasing field speeds, linear in between and constant
/// beyond the ends. Recorded vehicles deviate from the field by tenths of a m/s where it is slow
/// (a queue) and by metres per second where it is fast; one spread for both made queued
/// vehicles creep.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Profile {
    pub speed: [f64; PROFILE_KNOTS],
    pub factor: [[f64; 2]; PROFILE_KNOTS],
}

impl Profile {
    /// Factor 1 everywhere (the spread does not depend on the field's speed).
    pub const FLAT: Self = Self {
        speed: [0.0; PROFILE_KNOTS],
        factor: [[1.0; 2]; PROFILE_KNOTS],
    };

    /// The (along, across) factors at field speed `s`.
    pub fn at(&self, s: f64) -> [f64; 2] {
        let k = &self.speed;
        if !(s > k[0]) {
            return self.factor[0];
        }
        for i in 1..PROFILE_KNOTS {
            if s < k[i] {
                let w = (s - k[i - 1]) / (k[i] - k[i - 1]);
                let (a, b) = (self.factor[i - 1], self.factor[i]);
                return [a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1])];
            }
        }
        self.factor[PROFILE_KNOTS - 1]
    }
}

/// The residual model and the interaction rule of one pattern.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motion {
    /// OU time constant (s), along the heading in [`Spread::Heading`]; `f64::INFINITY` holds
    /// the residual (constant-velocity deviation).
    pub tau: f64,
    /// Stationary standard deviation of the residual: per component, or along and across the
    /// field's heading ([`Motion::spread`]).
    pub sigma: [f64; 2],
    pub spread: Spread,
    pub rule: Rule,
    /// The spread's dependence on the field's speed ([`Spread::Heading`] only).
    pub profile: Profile,
    /// `Some(τ_h)`: the agent is a vehicle that steers ([`Spread::Heading`] only): it keeps a
    /// heading `θ` and a desired speed `u`; `θ` turns toward the field's heading with time
    /// constant `τ_h` (held where the field has no heading; `∞`: never turns), `u` relaxes
    /// toward the field's speed as the along residual does, and it drives at `max(u, 0)` along
    /// `θ` (a vehicle does not reverse: it stands). `None`: the desired velocity is the field's
    /// mean plus the residual vector.
    pub tau_heading: Option<f64>,
    /// A steering vehicle's tolerance (rad): its heading turns by the part of its angle to the
    /// field's heading beyond this, so within it the vehicle drives straight (0: it always turns
    /// toward the field). The fitted fields' heading is rough at the scale of a lane; recorded
    /// vehicles do not follow that roughness.
    pub heading_tolerance: f64,
    /// A steering vehicle whose desired speed is below this stands (0: only a negative one).
    /// Recorded vehicles stop from and start to about this speed; the field is slow, not at
    /// rest, in a queue, and a wish that small made queued vehicles creep.
    pub stand_speed: f64,
    /// Spread (along, across the field's heading; isotropic `√((a² + c²) / 2)` without one) of
    /// an independent velocity jitter added to the desired velocity at every step of a
    /// stochastic rollout, before interaction: the part of recorded pedestrians' step-to-step
    /// velocity changes that does not persist (`[0, 0]`: none, vehicles). The residual's OU
    /// process carries what persists; its innovations are far too small for a pedestrian's
    /// recorded step changes (ETH: 0.03 m/s per 0.4 s step against 0.3 recorded).
    pub jitter: [f64; 2],
}

/// Numbers in a flat [`Motion`] record: `tau, sigma_0, sigma_1, kind (0 free, 1 vehicles,
/// 2 pedestrians), personal, jam, headway, accel, decel, lateral, min_speed, tau_across,
/// tau_heading`, then the [`Profile`]: [`PROFILE_KNOTS`] field speeds, as many along factors and
/// as many across factors, then `heading_tolerance` (rad), `stand_speed`, the two
/// [`Motion::jitter`] spreads, and the vehicles' [`Idm::brake`], [`Idm::length`] and
/// [`Idm::width`] (0: none). `min_speed < 0`: [`Spread::Components`] (`tau_across`, `tau_heading`
/// and the profile unused), else [`Spread::Heading`]; `tau_heading < 0`: no steering;
/// a first knot speed `< 0`: the flat profile.
pub const MOTION_FIELDS: usize = 20 + 3 * PROFILE_KNOTS;

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
                    brake: if v[17 + 3 * PROFILE_KNOTS] == 0.0 {
                        f64::INFINITY
                    } else {
                        v[17 + 3 * PROFILE_KNOTS]
                    },
                    length: v[18 + 3 * PROFILE_KNOTS],
                    width: v[19 + 3 * PROFILE_KNOTS],
                },
            },
            2 => Rule::Pedestrians { personal: v[4] },
            k => {
                return Err(Error::InvalidInput(format!(
                    "interaction kind must be 0 (free), 1 (vehicles) or 2 (pedestrians), got {k}"
                )));
            }
        };
        let spread = if v[10] < 0.0 {
            Spread::Components
        } else {
            Spread::Heading {
                min_speed: v[10],
                tau_across: v[11],
            }
        };
        let heading = matches!(spread, Spread::Heading { .. });
        let tau_heading = (heading && !(v[12] < 0.0)).then_some(v[12]);
        let mut profile = Profile::FLAT;
        if heading && !(v[13] < 0.0) {
            let p = PROFILE_KNOTS;
            for i in 0..p {
                profile.speed[i] = v[13 + i];
                profile.factor[i] = [v[13 + p + i], v[13 + 2 * p + i]];
            }
        }
        let m = Self {
            tau: v[0],
            sigma: [v[1], v[2]],
            spread,
            rule,
            profile,
            tau_heading,
            heading_tolerance: v[13 + 3 * PROFILE_KNOTS],
            stand_speed: v[14 + 3 * PROFILE_KNOTS],
            jitter: [v[15 + 3 * PROFILE_KNOTS], v[16 + 3 * PROFILE_KNOTS]],
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
        if let Spread::Heading {
            min_speed,
            tau_across,
        } = self.spread
        {
            if !(min_speed.is_finite() && min_speed >= 0.0) {
                return Err(Error::InvalidInput(format!(
                    "motion parameter min_speed must be finite and >= 0, got {min_speed}"
                )));
            }
            if !(tau_across > 0.0) || tau_across.is_nan() {
                return bad("tau_across (s; inf holds the residual)", tau_across);
            }
        }
        if let Some(t) = self.tau_heading
            && (!(t > 0.0) || t.is_nan() || self.spread == Spread::Components)
        {
            return bad(
                "tau_heading (s, with the heading frame; inf holds the heading)",
                t,
            );
        }
        let tol = self.heading_tolerance;
        if !(tol.is_finite() && (0.0..std::f64::consts::PI).contains(&tol)) {
            return Err(Error::InvalidInput(format!(
                "motion parameter heading_tolerance must be in [0, pi) rad, got {tol}"
            )));
        }
        if !(self.stand_speed.is_finite() && self.stand_speed >= 0.0) {
            return Err(Error::InvalidInput(format!(
                "motion parameter stand_speed must be finite and >= 0, got {}",
                self.stand_speed
            )));
        }
        if !self.jitter.iter().all(|s| s.is_finite() && *s >= 0.0) {
            return Err(Error::InvalidInput(format!(
                "motion parameter jitter must be finite and >= 0, got {:?}",
                self.jitter
            )));
        }
        let p = &self.profile;
        let knots_ok = p.speed.iter().all(|s| s.is_finite() && *s >= 0.0)
            && p.speed.windows(2).all(|w| w[1] >= w[0]);
        let factors_ok = p
            .factor
            .as_flattened()
            .iter()
            .all(|f| f.is_finite() && *f >= 0.0);
        if !(knots_ok && factors_ok) {
            return Err(Error::InvalidInput(
                "the spread's profile needs finite rising field speeds >= 0 and finite factors >= 0".into(),
            ));
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
                if !(idm.brake > 0.0) {
                    return bad("brake (length/s²; inf or 0: no bound)", idm.brake);
                }
                for (what, x) in [("length", idm.length), ("width", idm.width)] {
                    if !(x.is_finite() && x >= 0.0) {
                        return Err(Error::InvalidInput(format!(
                            "motion parameter {what} must be finite and >= 0 (0: not known), got {x}"
                        )));
                    }
                }
            }
        }
        Ok(())
    }
}

/// The unit heading and its left normal of the field's mean `m`, when the spread is given in
/// the heading frame and `m` is fast enough to have one.
fn heading(m: [f64; 2], motion: &Motion) -> Option<([f64; 2], [f64; 2])> {
    match motion.spread {
        Spread::Components => None,
        Spread::Heading { min_speed, .. } => {
            let speed = m[0].hypot(m[1]);
            if speed > min_speed && speed > TINY {
                let e = [m[0] / speed, m[1] / speed];
                Some((e, [-e[1], e[0]]))
            } else {
                None
            }
        }
    }
}

/// The residual's spreads (along, across; or per component) where the field's mean is `m`.
fn spread_at(m: [f64; 2], motion: &Motion) -> [f64; 2] {
    let f = motion.profile.at(m[0].hypot(m[1]));
    [motion.sigma[0] * f[0], motion.sigma[1] * f[1]]
}

/// One step of a steering vehicle's `state`, its heading `θ` and desired speed `u`, toward the field's
/// mean `m` ([`Motion::tau_heading`]): `u` as the along residual (`rho`, `kick`, spread at `m`,
/// innovation `z`), `theta` by the share `turn = 1 − exp(−dt / τ_h)` of the part of its angle to
/// the field's heading beyond [`Motion::heading_tolerance`], times `moved`: the share of its
/// desired speed the vehicle actually drove at (a vehicle turns only as it moves: one standing in
/// a queue keeps its lane's heading, however the field turns where it stands).
#[allow(clippy::too_many_arguments)]
fn steer(
    state: &mut [f64; 2],
    m: [f64; 2],
    z: f64,
    rho: f64,
    kick: f64,
    turn: f64,
    moved: f64,
    motion: &Motion,
) {
    let turn = turn * moved;
    let [theta, u] = state;
    let ms = m[0].hypot(m[1]);
    let s = spread_at(m, motion)[0];
    *u = ms + rho * (*u - ms) + s * kick * z;
    if let Some((e, _)) = heading(m, motion) {
        let d = e[1].atan2(e[0]) - *theta;
        let d = d.sin().atan2(d.cos()); // wrapped to (−π, π]
        let excess = d.signum() * (d.abs() - motion.heading_tolerance).max(0.0);
        *theta += turn * excess;
    }
}

/// The residual's persistence, innovation scale and turn share of one step where the field's
/// support is `s` (0: no data, 1: known): the time constants divided by `s`, so that a driver
/// relaxes toward a field only as far as the field knows where it is.
fn slowed(s: f64, rho: [f64; 2], turn: f64) -> ([f64; 2], [f64; 2], f64) {
    // ρ = exp(−dt / τ) → exp(−s dt / τ) = ρ^s; the turn share 1 − exp(−dt / τ_h) likewise
    let r = rho.map(|r| r.powf(s));
    (
        r,
        r.map(|r| (1.0 - r * r).max(0.0).sqrt()),
        1.0 - (1.0 - turn).powf(s),
    )
}

/// The speed at which a steering vehicle with desired speed `u` drives: `u`, or 0 (it stands)
/// below [`Motion::stand_speed`] (a negative wish always stands: vehicles do not reverse).
fn drive_speed(u: f64, motion: &Motion) -> f64 {
    if u >= motion.stand_speed {
        u.max(0.0)
    } else {
        0.0
    }
}

/// A stationary draw of the residual at a point where the field's mean is `m`, from the
/// standard normals `z`.
fn stationary(m: [f64; 2], z: [f64; 2], motion: &Motion) -> [f64; 2] {
    let s = spread_at(m, motion);
    match (motion.spread, heading(m, motion)) {
        (Spread::Components, _) => [s[0] * z[0], s[1] * z[1]],
        (_, Some((e, n))) => {
            let (a, c) = (s[0] * z[0], s[1] * z[1]);
            [a * e[0] + c * n[0], a * e[1] + c * n[1]]
        }
        (_, None) => {
            let iso = (0.5 * (s[0] * s[0] + s[1] * s[1])).sqrt();
            [iso * z[0], iso * z[1]]
        }
    }
}

/// A draw of the step jitter ([`Motion::jitter`]) where the field's mean is `m`, from the
/// standard normals `z`: along and across the field's heading, isotropic without one.
fn jitter_at(m: [f64; 2], z: [f64; 2], motion: &Motion) -> [f64; 2] {
    let [a, c] = motion.jitter;
    match heading(m, motion) {
        Some((e, n)) => {
            let (a, c) = (a * z[0], c * z[1]);
            [a * e[0] + c * n[0], a * e[1] + c * n[1]]
        }
        None => {
            let iso = (0.5 * (a * a + c * c)).sqrt();
            [iso * z[0], iso * z[1]]
        }
    }
}

/// One OU step of the desired velocity `w` toward the field's mean `m`, given the innovations
/// `z` (zero in mean mode) and, per axis (along, across), `rho` and `kick = √(1 − ρ²)`.
fn relax(
    w: [f64; 2],
    m: [f64; 2],
    z: [f64; 2],
    rho: [f64; 2],
    kick: [f64; 2],
    motion: &Motion,
) -> [f64; 2] {
    let s = spread_at(m, motion);
    if let Spread::Components = motion.spread {
        let mut out = [0.0; 2];
        for d in 0..2 {
            out[d] = m[d] + rho[0] * (w[d] - m[d]) + s[d] * kick[0] * z[d];
        }
        return out;
    }
    let r = [w[0] - m[0], w[1] - m[1]];
    match heading(m, motion) {
        Some((e, n)) => {
            let along = rho[0] * (r[0] * e[0] + r[1] * e[1]) + s[0] * kick[0] * z[0];
            let across = rho[1] * (r[0] * n[0] + r[1] * n[1]) + s[1] * kick[1] * z[1];
            [
                m[0] + along * e[0] + across * n[0],
                m[1] + along * e[1] + across * n[1],
            ]
        }
        None => {
            // no heading: isotropic, relaxing with the along axis' time constant
            let iso = (0.5 * (s[0] * s[0] + s[1] * s[1])).sqrt();
            [
                m[0] + rho[0] * r[0] + iso * kick[0] * z[0],
                m[1] + rho[0] * r[1] + iso * kick[0] * z[1],
            ]
        }
    }
}

/// IDM+ acceleration (Schakel, Knoop, van Arem 2012) of a follower at speed `u` with desired
/// speed `u0`, `gap` (centre to centre) behind a leader moving at `leader` along the follower's
/// heading; `gap = None` for a free road: `a min(1 − (u/u0)⁴, 1 − (s*/gap)²)`, the lesser of
/// IDM's free-road and interaction terms where IDM takes their sum. A follower at its desired
/// speed and gap keeps its speed (IDM brakes by `a` there), so the dense traffic of a recorded
/// frame, whose drivers want their own speed, is not braked at once: NGSIM US-101's rollouts at
/// 1 s were 1.79x constant velocity under IDM, 1.20x under IDM+ (s53 notes).
pub fn idm_accel(u: f64, u0: f64, gap: Option<(f64, f64)>, p: &Idm) -> f64 {
    let free = if u0 > TINY {
        1.0 - (u / u0).powi(4)
    } else {
        -1.0
    };
    match gap {
        None => p.accel * free,
        Some((g, leader)) => {
            let s_star = p.jam
                + (u * p.headway + u * (u - leader) / (2.0 * (p.accel * p.decel).sqrt())).max(0.0);
            p.accel * free.min(1.0 - (s_star / g.max(TINY)).powi(2))
        }
    }
}

/// Share of the constant-acceleration heuristic in [`acc_accel`] (Kesting et al.'s `c`).
const COOLNESS: f64 = 0.99;

/// IDM+ moderated where a leader appears at a short gap but is no danger, by the
/// constant-acceleration heuristic (CAH) of the ACC model (Kesting, Treiber, Helbing 2010,
/// Phil. Trans. R. Soc. A 368): `a_CAH = −(u − u_l)² Θ(u − u_l) / (2 s)`, the deceleration that
/// just avoids a collision if the leader keeps its speed (its acceleration taken as 0), `s` the
/// bumper gap; where IDM asks for more braking, `(1 − c) a_IDM + c (a_CAH + b tanh((a_IDM −
/// a_CAH) / b))`. IDM reads a neighbour that drifts into the corridor alongside at one's own
/// speed as a leader far inside the jam distance and stops the follower in one step; the CAH
/// sees no approach and brakes at about the comfortable `b` (issue 35). Plain IDM+ without a
/// [`Idm::length`] or a leader.
pub fn acc_accel(u: f64, u0: f64, gap: Option<(f64, f64)>, p: &Idm) -> f64 {
    let idm = idm_accel(u, u0, gap, p);
    let Some((g, lead)) = gap else {
        return idm;
    };
    if !(p.length > 0.0) {
        return idm;
    }
    let s = (g - p.length).max(TINY);
    let closing = (u - lead).max(0.0);
    let cah = -closing * closing / (2.0 * s);
    if idm >= cah {
        return idm;
    }
    (1.0 - COOLNESS) * idm + COOLNESS * (cah + p.decel * ((idm - cah) / p.decel).tanh())
}

/// A red signal's stop line as the front of its queue sees it (long scenarios by signal stage):
/// a vehicle heading within 60° of `heading` (a unit vector) whose corridor ahead (the IDM
/// `lateral`) holds `at` stops with its centre there, as behind a standing vehicle one jam
/// distance beyond, unless it is too close to stop braking at twice the comfortable
/// deceleration: it clears the amber, as drivers do. The fitted fields cannot say "stand" where
/// a queue stands: at a red light's queue their means mix the standing vehicles with those that
/// discharge there at green, and a generated vehicle crept through.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stop {
    pub at: Point,
    pub heading: [f64; 2],
}

impl Stop {
    /// A stop line at `at` for traffic heading along `heading` (any length but zero).
    pub fn new(at: Point, heading: [f64; 2]) -> Result<Self> {
        let n = heading[0].hypot(heading[1]);
        if !(at.iter().all(|v| v.is_finite()) && n.is_finite() && n > TINY) {
            return Err(Error::InvalidInput(format!(
                "a stop line needs a finite position and a nonzero finite heading, got {at:?} heading {heading:?}"
            )));
        }
        Ok(Self {
            at,
            heading: [heading[0] / n, heading[1] / n],
        })
    }
}

/// The gap (centre to centre, to the standing vehicle a stop line stands for) to the nearest
/// [`Stop`] ahead of a vehicle at `x` heading along `e` at speed `u` that it can still stop at.
fn stop_gap(x: Point, e: [f64; 2], u: f64, stops: &[Stop], p: &Idm) -> Option<f64> {
    let mut best: Option<f64> = None;
    for s in stops {
        if s.heading[0] * e[0] + s.heading[1] * e[1] < CROSSING {
            continue;
        }
        let d = [s.at[0] - x[0], s.at[1] - x[1]];
        let along = d[0] * e[0] + d[1] * e[1];
        let side = (d[0] * e[1] - d[1] * e[0]).abs();
        // the Euler guard lets a stopping vehicle pass the line by up to half the jam distance
        let room = along + 0.5 * p.jam;
        if side > p.lateral || room <= 0.0 || u * u / (4.0 * p.decel) > room {
            continue;
        }
        let gap = along + p.jam;
        if best.is_none_or(|g| gap < g) {
            best = Some(gap);
        }
    }
    best
}

/// Seconds ahead within which a vehicle yields at a crossing path ([`yield_gap`]).
const CONFLICT_HORIZON: f64 = 5.0;
/// Seconds a yielding vehicle leaves between the other clearing the crossing and its own arrival.
const CONFLICT_MARGIN: f64 = 1.0;

/// First come, first served where paths cross (generated vehicles with headings and a size):
/// the gap (centre to centre, to the standing vehicle it stands for) to the crossing point of
/// `i`'s path with that of a vehicle `j` heading across it (more than 60° apart) that reaches the
/// crossing first and would not have cleared it `CONFLICT_MARGIN` before `i` arrives; `i` then
/// stops clear of `j`'s path (half a length and half a width short), unless it cannot stop there
/// any more within its braking bound (it is committed). Arrival and clearing times are at each
/// vehicle's current or desired speed along its heading, whichever is larger (a vehicle waiting
/// to go is not standing for good), within [`CONFLICT_HORIZON`]; ties go to the lower index. The
/// fitted fields know no right of way: generated vehicles from crossing approaches drove through
/// each other (SUMO junction: about a third of generated scenes touching, recorded none).
fn yield_gap(
    i: usize,
    x: &[Point],
    current: &[[f64; 2]],
    desired: &[[f64; 2]],
    heads: &[[f64; 2]],
    idm: &Idm,
) -> Option<f64> {
    if !(idm.length > 0.0 && idm.width > 0.0) {
        return None;
    }
    let clear = 0.5 * (idm.length + idm.width);
    let dot = |a: [f64; 2], b: [f64; 2]| a[0] * b[0] + a[1] * b[1];
    let speed = |k: usize| {
        let h = heads[k];
        dot(current[k], h)
            .max(desired[k][0].hypot(desired[k][1]))
            .max(0.0)
    };
    // seconds to cover `s` at `u` (never, standing)
    let time = |s: f64, u: f64| {
        if u > TINY {
            s.max(0.0) / u
        } else {
            f64::INFINITY
        }
    };
    let ei = heads[i];
    let ui = speed(i);
    let mut best: Option<f64> = None;
    for j in 0..x.len() {
        let ej = heads[j];
        if j == i || dot(ei, ej) >= CROSSING {
            continue;
        }
        let det = ei[0] * ej[1] - ei[1] * ej[0];
        if det.abs() < 0.2 {
            continue; // nearly opposite: no crossing point ahead
        }
        let d = [x[j][0] - x[i][0], x[j][1] - x[i][1]];
        // x_i + s_i e_i = x_j + s_j e_j
        let si = (d[0] * ej[1] - d[1] * ej[0]) / det;
        let sj = (d[0] * ei[1] - d[1] * ei[0]) / det;
        if si <= clear || sj <= -clear {
            continue; // i already on the crossing (it goes on), or j past it
        }
        let uj = speed(j);
        let (arrive_i, arrive_j) = (time(si - clear, ui), time(sj - clear, uj));
        if arrive_i > CONFLICT_HORIZON || arrive_j > arrive_i || (arrive_j == arrive_i && j > i) {
            continue;
        }
        if arrive_i >= time(sj + clear, uj) + CONFLICT_MARGIN {
            continue; // j is gone before i comes
        }
        let room = si - clear;
        let u = dot(current[i], ei).max(0.0);
        if idm.brake.is_finite() && u * u / (2.0 * idm.brake) > room {
            continue; // too close to stop: committed
        }
        let gap = room + idm.jam;
        if best.is_none_or(|g| gap < g) {
            best = Some(gap);
        }
    }
    best
}

/// The nearest agent ahead of `i` (along `heading`, a unit vector) whose lateral offset is
/// within `lateral`: (its index, gap along the heading).
fn leader(
    i: usize,
    x: &[Point],
    heading: [f64; 2],
    lateral: f64,
    heads: Option<&[[f64; 2]]>,
) -> Option<(usize, f64)> {
    let mut best: Option<(usize, f64)> = None;
    for (j, q) in x.iter().enumerate() {
        // with known headings, a vehicle crossing or against one's own is no leader (the
        // personal distance keeps the two apart): two crossing vehicles that each waited for the
        // other would lock the junction for good
        if j == i || heads.is_some_and(|h| h[j][0] * heading[0] + h[j][1] * heading[1] < CROSSING) {
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
    interact_headed(x, current, desired, None, &[], rule, dt)
}

/// [`interact`] with each agent's heading (unit vectors; steering vehicles): only a vehicle
/// heading within 60° of one's own is a leader; and red stop lines `stops`.
pub fn interact_headed(
    x: &[Point],
    current: &[[f64; 2]],
    desired: &[[f64; 2]],
    heads: Option<&[[f64; 2]]>,
    stops: &[Stop],
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
                let u = current[i][0].hypot(current[i][1]);
                // the direction it wants to go, else (standing wish) the one it goes
                let e = if u0 > TINY {
                    [desired[i][0] / u0, desired[i][1] / u0]
                } else if u > TINY {
                    [current[i][0] / u, current[i][1] / u]
                } else {
                    continue;
                };
                let ahead = leader(i, x, e, idm.lateral, heads);
                let gap = ahead.map(|(j, g)| (g, current[j][0] * e[0] + current[j][1] * e[1]));
                // a red stop line, or a crossing another vehicle reaches first, nearer than the
                // leader is the leader, standing
                let crossing = heads.and_then(|h| yield_gap(i, x, current, desired, h, &idm));
                let stop = [stop_gap(x[i], e, u, stops, &idm), crossing]
                    .into_iter()
                    .flatten()
                    .reduce(f64::min);
                let gap = match (gap, stop) {
                    (Some((g, _)), Some(s)) if s < g => Some((s, 0.0)),
                    (None, Some(s)) => Some((s, 0.0)),
                    (gap, _) => gap,
                };
                let mut next = u + dt * acc_accel(u, u0, gap, &idm);
                match gap {
                    // free road: toward the desired speed, not past it
                    None => next = next.max(u.min(u0)),
                    // Euler can overshoot a hard stop: never close more than half the jam distance
                    Some((g, lead)) => next = next.min((g - 0.5 * idm.jam) / dt + lead.max(0.0)),
                }
                // nor brake harder than tyres can, behind a leader (the personal distance then
                // keeps the two apart) or for a wish that fell
                let next = next.max(u - dt * idm.brake);
                let speed = next.clamp(0.0, u0.max(u));
                v[i] = [e[0] * speed, e[1] * speed];
            }
            personal
        }
    };
    if let Rule::Vehicles { idm, .. } = *rule {
        keep_sides(x, &mut v, &idm, dt);
    }
    keep_distance(x, &mut v, personal, dt);
    if let Rule::Vehicles { idm, .. } = *rule
        && idm.brake.is_finite()
    {
        // the personal distance, too, slows a vehicle no faster than its tyres can: it keeps the
        // direction the guard gave it, at the least speed braking reaches
        for (vi, ci) in v.iter_mut().zip(current) {
            let floor = ci[0].hypot(ci[1]) - dt * idm.brake;
            let s = vi[0].hypot(vi[1]);
            if s < floor {
                let e = if s > TINY {
                    [vi[0] / s, vi[1] / s]
                } else {
                    [ci[0], ci[1]].map(|c| c / ci[0].hypot(ci[1]))
                };
                *vi = [e[0] * floor, e[1] * floor];
            }
        }
    }
    v
}

/// Vehicles alongside one another do not move sideways into each other (a lane change waits for
/// its gap): for every pair heading within 60° of each other whose centres are less than a
/// [`Idm::length`] apart along their mean heading `e` and at least a [`Idm::width`] apart across
/// it, the part of their sideways approach (across `e`) that would bring them closer than a width
/// in this step is removed, half from each (from the velocities before any change, so the result
/// does not depend on the order of the vehicles). The fitted field's direction at a vehicle
/// between lanes points into the neighbouring lane, and generated vehicles drove into the side of
/// the one next to them (US-101: boxes touching in 11 % of scenes, recorded none).
fn keep_sides(x: &[Point], v: &mut [[f64; 2]], idm: &Idm, dt: f64) {
    if !(idm.length > 0.0 && idm.width > 0.0) {
        return;
    }
    let before = v.to_vec();
    let unit = |w: [f64; 2]| {
        let s = w[0].hypot(w[1]);
        (s > TINY).then(|| [w[0] / s, w[1] / s])
    };
    for i in 0..x.len() {
        let Some(ei) = unit(before[i]) else { continue };
        for j in i + 1..x.len() {
            let Some(ej) = unit(before[j]) else { continue };
            if ei[0] * ej[0] + ei[1] * ej[1] < CROSSING {
                continue;
            }
            // the pair's mean heading: the same frame whichever of the two comes first
            let Some(e) = unit([ei[0] + ej[0], ei[1] + ej[1]]) else {
                continue;
            };
            let n = [-e[1], e[0]];
            let d = [x[j][0] - x[i][0], x[j][1] - x[i][1]];
            let along = d[0] * e[0] + d[1] * e[1];
            let across = d[0] * n[0] + d[1] * n[1];
            if along.abs() >= idm.length || across.abs() < idm.width {
                continue;
            }
            // j's side of i, and the rate at which the two close across e
            let side = across.signum();
            let rel = [before[j][0] - before[i][0], before[j][1] - before[i][1]];
            let closing = -side * (rel[0] * n[0] + rel[1] * n[1]);
            let excess = closing - (across.abs() - idm.width) / dt;
            if excess > 0.0 {
                let push = 0.5 * excess * side;
                v[i][0] -= push * n[0];
                v[i][1] -= push * n[1];
                v[j][0] += push * n[0];
                v[j][1] += push * n[1];
            }
        }
    }
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

/// An importance-sampling tilt of the residual's innovations (issue 35): one of the rollout's
/// `vehicles × (steps + 1)` innovation slots, chosen uniformly (its own stream), draws its
/// standard normals from `N(mean, I)` instead of `N(0, I)`; every other draw stays natural. The
/// rollout's ratio of natural to tilted density is then exact whatever path it took: with
/// `a_c = mean · z_c − |mean|² / 2` for each slot `c` drawn (its final `z`) and `a_c = 0` for a
/// slot never drawn (its vehicle not there), `p / q = 1 / mean_c exp(a_c)` (the mixture over
/// which slot moved). One shifted innovation at a time is the defensive form of "make one
/// driver's wish jump": its weights stay bounded where shifting every draw degenerates them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shift {
    pub mean: [f64; 2],
}

/// A [`Shift`] at work in one rollout: its slot, the terms `a_c` so far, and the shifted
/// innovation (once its slot is drawn).
struct Shifting {
    mean: [f64; 2],
    slot: usize,
    slots: usize,
    terms: Vec<f64>,
    pick: Option<[f64; 2]>,
}

impl Shifting {
    fn new(shift: Shift, seed: u64, vehicles: usize, steps: usize) -> Result<Self> {
        if !shift.mean.iter().all(|m| m.is_finite()) {
            return Err(Error::InvalidInput(format!(
                "the innovations' shift must be finite, got {:?}",
                shift.mean
            )));
        }
        let slots = (vehicles * (steps + 1)).max(1);
        let u = uniform(seed, 0, Phase::Simulate, SHIFT_ENTITY);
        Ok(Self {
            mean: shift.mean,
            slot: ((u * slots as f64) as usize).min(slots - 1),
            slots,
            terms: Vec::new(),
            pick: None,
        })
    }

    /// Vehicle `j`'s standard normals `z` at step `t`, shifted when theirs is the slot.
    fn draw(&mut self, t: usize, j: usize, vehicles: usize, z: [f64; 2]) -> [f64; 2] {
        let m = self.mean;
        let z = if t * vehicles + j == self.slot {
            let moved = [z[0] + m[0], z[1] + m[1]];
            self.pick = Some(moved);
            moved
        } else {
            z
        };
        self.terms
            .push(m[0] * z[0] + m[1] * z[1] - 0.5 * (m[0] * m[0] + m[1] * m[1]));
        z
    }

    /// `ln(p / q) = −ln(mean_c exp(a_c))`, the slots never drawn counting `exp(0)`.
    fn log_ratio(&self) -> f64 {
        let top = self.terms.iter().copied().fold(0.0, f64::max);
        let rest = (self.slots - self.terms.len().min(self.slots)) as f64;
        let sum: f64 =
            self.terms.iter().map(|a| (a - top).exp()).sum::<f64>() + rest * (-top).exp();
        -(top + (sum / self.slots as f64).ln())
    }
}

/// A generated scene's first velocities where vehicles follow one another: no faster than IDM
/// keeps its desired gap at, `s*(u, Δu) ≤ gap` with `s* = jam + u T + u (u − u_leader) /
/// (2 √(a b))`, so that the first step does not brake behind the leader. The field's draw at a
/// queued vehicle is the pattern's speed there, which mixes queues with free flow; started at it,
/// the vehicle braked at the first step from 18 to 0 m/s (SUMO junction: every scene in the top
/// 0.5 % of hardest decelerations did so at step 1). A queue is settled from its front in up to
/// [`START_PASSES`] passes (each follower against its leader's speed of the pass before). The
/// driver's wish is kept, so it moves on as the queue does.
fn start_behind_leaders(
    x: &[Point],
    active: &[usize],
    vel: &mut [[f64; 2]],
    steering: &[[f64; 2]],
    motion: &Motion,
) {
    let Rule::Vehicles { idm, .. } = motion.rule else {
        return;
    };
    let heads: Option<Vec<[f64; 2]>> = motion.tau_heading.map(|_| {
        active
            .iter()
            .map(|&j| [steering[j][0].cos(), steering[j][0].sin()])
            .collect()
    });
    let c = 1.0 / (2.0 * (idm.accel * idm.decel).sqrt()).max(TINY);
    for _ in 0..START_PASSES {
        let current: Vec<[f64; 2]> = active.iter().map(|&j| vel[j]).collect();
        let mut changed = false;
        for (a, &j) in active.iter().enumerate() {
            let u = current[a][0].hypot(current[a][1]);
            if u <= TINY {
                continue;
            }
            let e = [current[a][0] / u, current[a][1] / u];
            let Some((l, gap)) = leader(a, x, e, idm.lateral, heads.as_deref()) else {
                continue;
            };
            let lead = (current[l][0] * e[0] + current[l][1] * e[1]).max(0.0);
            // the larger root of c u² + (T − c lead) u − (gap − jam) = 0: s* = gap
            let b = idm.headway - c * lead;
            let room = (gap - idm.jam).max(0.0);
            let cap = if c > TINY {
                ((-b + (b * b + 4.0 * c * room).sqrt()) / (2.0 * c)).max(0.0)
            } else {
                room / idm.headway.max(TINY)
            };
            if u > cap + 1e-12 {
                vel[j] = [e[0] * cap, e[1] * cap];
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
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
    drive_on(start, v0, None, &[], opts, motion, seed, None, field)
}

/// [`drive`] of a generated scene (`v0 = None`) whose residual innovations are tilted by
/// `shift` ([`Shift`]; stochastic only: it moves draws). [`Rollout::log_ratio`] is the scene's
/// log likelihood ratio, [`Rollout::pick`] its shifted innovation (`None`: its slot was never drawn).
pub fn drive_shifted(
    start: &[Point],
    opts: &Options,
    motion: &Motion,
    seed: u64,
    shift: Shift,
    field: &mut dyn Field,
) -> Result<Rollout> {
    drive_on(
        start,
        None,
        None,
        &[],
        opts,
        motion,
        Some(seed),
        Some(shift),
        field,
    )
}

/// Driver states carried from an earlier rollout ([`Rollout::drivers`]): each agent's desired
/// velocity, or for a steering model its heading and desired speed. `renew`: the scene's regime
/// has changed since (a long scenario's next signal stage), and each driver takes up the new
/// field where it is, as far as the field knows the point (support `s`): its desired speed
/// becomes `(1 − s) u + s |m|`, the speed toward which steering relaxes it (the heading then
/// turns as the vehicle moves; a standing vehicle's heading may be no lane's), and without
/// steering its desired velocity `(1 − s) w + s m`. Without that a driver meets the change only through the residual's
/// relaxation, and where a pattern's `τ` is long (∞ where its field predicted its tracks no
/// better than constant velocity), a queue that stood at red still wants to stand at green.
#[derive(Clone, Copy, Debug)]
pub struct Carried<'a> {
    pub states: &'a [[f64; 2]],
    pub renew: bool,
}

impl<'a> Carried<'a> {
    /// The drivers as they were.
    pub fn kept(states: &'a [[f64; 2]]) -> Self {
        Self {
            states,
            renew: false,
        }
    }
}

/// [`drive`], continuing drivers where another rollout left them: `drivers` (with `v0`, the
/// actual velocities then) are their [`Carried`] states. Without them a rollout starting from
/// `v0` takes the actual velocity as the driver's wish, which is wrong mid-scene: a vehicle
/// braking behind a leader (or pushed back by the personal distance) would take that as what it
/// wants, keep the heading of a push for `τ_h`, and stand. `stops`: the red stop lines in force
/// (vehicles only).
#[allow(clippy::too_many_arguments)]
pub fn drive_on(
    start: &[Point],
    v0: Option<&[[f64; 2]]>,
    drivers: Option<Carried>,
    stops: &[Stop],
    opts: &Options,
    motion: &Motion,
    seed: Option<u64>,
    shift: Option<Shift>,
    field: &mut dyn Field,
) -> Result<Rollout> {
    let renew = drivers.is_some_and(|d| d.renew);
    let drivers = drivers.map(|d| d.states);
    if let Some(d) = drivers {
        if v0.is_none() || d.len() != start.len() {
            return Err(Error::Shape(format!(
                "{} driver states for {} start positions (and they need the start velocities)",
                d.len(),
                start.len()
            )));
        }
        crate::error::check_finite("driver states", d.as_flattened())?;
    }
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
    if motion.tau_heading.is_some() {
        out.headings = vec![f64::NAN; (opts.steps + 1) * l];
    }
    let mut shifting = match (shift, seed) {
        (Some(s), Some(seed)) => Some(Shifting::new(s, seed, l, opts.steps)?),
        (Some(_), None) => {
            return Err(Error::InvalidInput(
                "a shift of the innovations needs drawn innovations (a stochastic rollout with a seed)".into(),
            ));
        }
        (None, _) => None,
    };
    let tau_across = match motion.spread {
        Spread::Components => motion.tau,
        Spread::Heading { tau_across, .. } => tau_across,
    };
    let rho = [(-dt / motion.tau).exp(), (-dt / tau_across).exp()];
    let kick = rho.map(|r| (1.0 - r * r).max(0.0).sqrt());
    let turn = motion.tau_heading.map_or(0.0, |t| 1.0 - (-dt / t).exp());
    // the step jitter's stream at step `t` (stochastic rollouts of a model with jitter only)
    let jittery = motion.jitter.iter().any(|&s| s > 0.0);
    let jitter_rng = |t: usize| {
        seed.filter(|_| jittery)
            .map(|s| stream(s, t as u64, Phase::Simulate, JITTER_ENTITY))
    };
    let jitter = |rng: &mut Option<rand_chacha::ChaCha8Rng>, m: [f64; 2], w: [f64; 2]| match rng {
        Some(rng) => {
            let z = [StandardNormal.sample(rng), StandardNormal.sample(rng)];
            let e = jitter_at(m, z, motion);
            [w[0] + e[0], w[1] + e[1]]
        }
        None => w,
    };
    // steering vehicles: heading and (signed) desired speed
    let mut steering = vec![[0.0; 2]; l];
    let mut want = vec![[0.0; 2]; l]; // desired velocities
    let mut vel = vec![[0.0; 2]; l]; // actual velocities
    // a field over heading is asked at each vehicle's previous heading (its last actual velocity's)
    let mut track = HeadingTrack::of(field, l)?;
    let mut late = LateFlags::default();
    for t in 0..=opts.steps {
        let row = t * l;
        let active: Vec<usize> = (0..l).filter(|&j| out.in_roi[row + j]).collect();
        let x: Vec<Point> = active.iter().map(|&j| out.positions[row + j]).collect();
        if !active.is_empty() {
            if let Some(track) = &track {
                track.tell(field, &active);
            }
            let info = field.step_start(t, &x)?;
            late.note(&info, row, &active);
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
                let recorded: Option<Vec<f64>> = field
                    .recorded_headings()
                    .filter(|r| r.len() == l)
                    .map(<[f64]>::to_vec);
                let mut rng = seed.map(|s| stream(s, 0, Phase::Simulate, NOISE_ENTITY));
                // a recorded start keeps its own velocities exactly
                let mut jit = if v0.is_none() { jitter_rng(0) } else { None };
                // renewed drivers take up the field as far as it knows where they are
                let known = if renew { field.support(&x)? } else { None };
                let take = |a: usize| {
                    if renew {
                        known.as_ref().map_or(1.0, |s| s[a])
                    } else {
                        0.0
                    }
                };
                for (a, &j) in active.iter().enumerate() {
                    if let (Some(v), Some(d)) = (v0, drivers) {
                        // a continued driver: its own wish (renewed: toward the field), moving
                        // at its actual velocity
                        let s = take(a);
                        if motion.tau_heading.is_some() {
                            let speed = mean[a][0].hypot(mean[a][1]);
                            steering[j] = [d[j][0], (1.0 - s) * d[j][1] + s * speed];
                            let go = drive_speed(steering[j][1], motion);
                            want[j] = [go * d[j][0].cos(), go * d[j][0].sin()];
                        } else {
                            want[j] = [
                                (1.0 - s) * d[j][0] + s * mean[a][0],
                                (1.0 - s) * d[j][1] + s * mean[a][1],
                            ];
                        }
                        vel[j] = v[j];
                        continue;
                    }
                    // own velocities exactly; else the GP draw plus a stationary residual
                    want[j] = match v0 {
                        Some(v) => v[j],
                        None => {
                            let w = [
                                mean[a][0] + info.offset[a][0],
                                mean[a][1] + info.offset[a][1],
                            ];
                            match rng.as_mut() {
                                // the stationary residual, in the spread's frame at the mean
                                Some(rng) => {
                                    let mut z =
                                        [StandardNormal.sample(rng), StandardNormal.sample(rng)];
                                    if let Some(s) = shifting.as_mut() {
                                        z = s.draw(0, j, l, z);
                                    }
                                    let r = stationary(mean[a], z, motion);
                                    [w[0] + r[0], w[1] + r[1]]
                                }
                                None => w,
                            }
                        }
                    };
                    steering[j] = [want[j][1].atan2(want[j][0]), want[j][0].hypot(want[j][1])];
                    // a generated vehicle starts along its lane: the field's heading, else (a
                    // field too slow to have one: a queue) the heading it was recorded with, at
                    // the drawn velocity's speed along it (standing if that is negative). A
                    // queued vehicle started along its slow field's drawn velocity faced any way,
                    // and its rectangle lay across the next lane's (SUMO junction: half the
                    // touching pairs of generated scenes were within a length at the start).
                    let lane = heading(mean[a], motion).map(|(e, _)| e).or_else(|| {
                        let h = recorded.as_ref().map_or(f64::NAN, |r| r[j]);
                        h.is_finite().then(|| [h.cos(), h.sin()])
                    });
                    if let (None, Some(_), Some(e)) = (v0, motion.tau_heading, lane) {
                        let along = want[j][0] * e[0] + want[j][1] * e[1];
                        steering[j] = [e[1].atan2(e[0]), along];
                        let go = drive_speed(along, motion);
                        want[j] = [go * e[0], go * e[1]];
                    }
                    vel[j] = jitter(&mut jit, mean[a], want[j]);
                }
                if v0.is_none() {
                    start_behind_leaders(&x, &active, &mut vel, &steering, motion);
                }
            } else {
                let mut rng = seed.map(|s| stream(s, t as u64, Phase::Simulate, NOISE_ENTITY));
                let mut jit = jitter_rng(t);
                let known = field.support(&x)?;
                let mut desired = Vec::with_capacity(x.len());
                let mut current = Vec::with_capacity(x.len());
                for (a, &j) in active.iter().enumerate() {
                    let mut z: [f64; 2] = match rng.as_mut() {
                        Some(rng) => [StandardNormal.sample(rng), StandardNormal.sample(rng)],
                        None => [0.0; 2],
                    };
                    if let Some(s) = shifting.as_mut() {
                        z = s.draw(t, j, l, z);
                    }
                    // where the field knows less (support < 1), its driver follows it more
                    // slowly: with no data there (the prior's zero mean), it keeps its wish
                    let (rho, kick, turn) = match &known {
                        Some(s) => slowed(s[a], rho, turn),
                        None => (rho, kick, turn),
                    };
                    want[j] = if motion.tau_heading.is_some() {
                        let go = drive_speed(steering[j][1], motion);
                        let moved = if go > TINY {
                            (vel[j][0].hypot(vel[j][1]) / go).min(1.0)
                        } else {
                            0.0
                        };
                        steer(
                            &mut steering[j],
                            mean[a],
                            z[0],
                            rho[0],
                            kick[0],
                            turn,
                            moved,
                            motion,
                        );
                        let [th, u] = steering[j];
                        let go = drive_speed(u, motion);
                        [go * th.cos(), go * th.sin()]
                    } else {
                        relax(want[j], mean[a], z, rho, kick, motion)
                    };
                    desired.push(jitter(&mut jit, mean[a], want[j]));
                    current.push(vel[j]);
                }
                let heads: Option<Vec<[f64; 2]>> = motion.tau_heading.map(|_| {
                    active
                        .iter()
                        .map(|&j| [steering[j][0].cos(), steering[j][0].sin()])
                        .collect()
                });
                let actual = interact_headed(
                    &x,
                    &current,
                    &desired,
                    heads.as_deref(),
                    stops,
                    &motion.rule,
                    dt,
                );
                for (a, &j) in active.iter().enumerate() {
                    vel[j] = actual[a];
                }
            }
            for (a, &j) in active.iter().enumerate() {
                out.velocities[row + j] = vel[j];
                out.low_data[row + j] = info.low_data[a];
                if let Some(h) = out.headings.get_mut(row + j) {
                    *h = steering[j][0];
                }
                if let Some(track) = track.as_mut() {
                    track.moved(j, vel[j]);
                }
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
    late.fill(field, &mut out.low_data)?;
    if let Some(s) = shifting {
        out.log_ratio = s.log_ratio();
        out.pick = s.pick;
    }
    out.drivers = if motion.tau_heading.is_some() {
        steering
    } else {
        want
    };
    Ok(out)
}

#[cfg(test)]
#[path = "tests/motion.rs"]
mod tests;
