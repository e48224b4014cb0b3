//! The turning limit by hand: within reach unchanged, beyond it turned by the reach with the
//! field's component along the new heading, backward answers stopped, unknown headings free.

use super::*;
use std::f64::consts::{FRAC_PI_2, PI};

fn close(a: [f64; 2], b: [f64; 2]) {
    assert!(
        (a[0] - b[0]).abs() < 1e-12 && (a[1] - b[1]).abs() < 1e-12,
        "{a:?} != {b:?}"
    );
}

#[test]
fn within_reach_the_field_is_followed() {
    // heading east, the field 0.1 rad to the left at 10 m/s; reach 0.2 * 10 * 0.5 = 1 rad
    let v = [10.0 * 0.1f64.cos(), 10.0 * 0.1f64.sin()];
    close(turn_limited(0.0, v, 0.2, 0.5), v);
    // across the ±π seam: heading just below π, the field just past it
    let v = [-(3.0f64.cos()).abs(), -0.05];
    close(turn_limited(PI - 0.02, v, 1.0, 0.5), v);
}

#[test]
fn beyond_reach_the_heading_turns_by_the_reach() {
    // heading east, the field north at 2 m/s: reach 0.1 * 2 * 0.5 = 0.1 rad; the component of
    // the field along the turned heading is 2 sin(0.1)
    let got = turn_limited(0.0, [0.0, 2.0], 0.1, 0.5);
    let along = 2.0 * (FRAC_PI_2 - 0.1).cos();
    close(got, [along * 0.1f64.cos(), along * 0.1f64.sin()]);
    // to the right the same, mirrored
    let got = turn_limited(0.0, [0.0, -2.0], 0.1, 0.5);
    close(got, [along * 0.1f64.cos(), -along * 0.1f64.sin()]);
}

#[test]
fn a_backward_answer_stops_the_vehicle() {
    // heading east, the field west (and a little north): it does not reverse
    close(turn_limited(0.0, [-3.0, 0.2], 0.18, 0.5), [0.0, 0.0]);
    // heading north-east, the field south-west
    close(turn_limited(PI / 4.0, [-1.0, -1.0], 0.5, 0.5), [0.0, 0.0]);
}

#[test]
fn unknown_heading_or_standing_field_is_left_alone() {
    close(turn_limited(f64::NAN, [-3.0, 0.2], 0.18, 0.5), [-3.0, 0.2]);
    close(turn_limited(1.0, [0.0, 0.0], 0.18, 0.5), [0.0, 0.0]);
}
