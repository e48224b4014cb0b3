//! A vehicle's turning limit for pure-field rollouts over heading: a vehicle turns by at most
//! `κ_max` radians per unit of path (a minimum turning radius `1/κ_max`), as the recordings'
//! vehicles do, and it does not drive backward.
//!
//! Why: a pure-field rollout feeds each step's direction back into the field as the next step's
//! heading. At walking pace a small lateral answer of the field turns a vehicle by tens of
//! degrees in one step, and two such steps reverse it (docs/heading.md: the pure field reversed
//! a fifth of the SUMO junction's vehicles within 20 s, where no recorded vehicle reversed).
//! A car's heading changes with the path it drives, not with time: over `dt` it turns at most
//! `κ_max s dt`, `s` the speed the field asks for (the path it would drive; the component it
//! then drives along the turned heading is shorter, so this is the looser of the two readings:
//! with the shorter one a vehicle the field sends sideways could never start to turn).

/// The velocity a vehicle heading `h` (radians; `NaN`: unknown, no limit) moves with when the
/// field asks for `v`, under the turning limit `kappa` (per unit length) over `dt` seconds: `v`
/// itself when its direction lies within `kappa |v| dt` of `h`; else the heading turned by that
/// much toward `v`'s direction, with `v`'s component along it (0 when that points backward: the
/// vehicle stops rather than reverse).
pub fn turn_limited(h: f64, v: [f64; 2], kappa: f64, dt: f64) -> [f64; 2] {
    let speed = v[0].hypot(v[1]);
    if !h.is_finite() || speed == 0.0 {
        return v;
    }
    let d = v[1].atan2(v[0]) - h;
    let want = d.sin().atan2(d.cos()); // wrapped to [−π, π]
    let reach = kappa * speed * dt;
    if want.abs() <= reach {
        return v;
    }
    let turn = reach.copysign(want);
    let along = (speed * (want - turn).cos()).max(0.0);
    let (s, c) = (h + turn).sin_cos();
    [along * c, along * s]
}

#[cfg(test)]
#[path = "tests/turning.rs"]
mod tests;
