use super::*;
use crate::simulate::Roi;

const IDM: Idm = Idm {
    jam: 7.0,
    headway: 1.5,
    accel: 1.0,
    decel: 2.0,
    lateral: 1.5,
    brake: f64::INFINITY,
    length: 0.0,
    width: 0.0,
};

/// A record of the 12 numbers before steering and the profile: no steering, a flat profile.
fn rec(head: &[f64]) -> Vec<f64> {
    let mut v = head.to_vec();
    v.push(-1.0);
    v.push(-1.0);
    v.resize(MOTION_FIELDS, 0.0);
    v
}

fn opts(dt: f64, steps: usize) -> Options {
    Options {
        dt,
        steps,
        method: Method::Euler,
        roi: Roi::everywhere(),
        max_curvature: None,
    }
}

#[test]
fn idm_plus_matches_a_hand_computation() {
    // u = 10, u0 = 15, gap 30 behind a leader at 8:
    // s* = 7 + 10*1.5 + 10*2/(2*sqrt(2)); free term 1 - (10/15)^4 = 0.8024691; IDM+ takes the
    // lesser of it and the interaction term 1 - (s*/30)^2
    let s_star = 22.0 + 10.0 / 2f64.sqrt();
    let want = 1.0 * (1.0 - (10.0f64 / 15.0).powi(4)).min(1.0 - (s_star / 30.0).powi(2));
    let got = idm_accel(10.0, 15.0, Some((30.0, 8.0)), &IDM);
    assert!((got - want).abs() < 1e-12, "{got} vs {want}");
    // by hand: s* = 29.0710678, (s*/30)² = 0.9390300, a = min(0.8024691, 0.0609700)
    assert!((got - 0.060_970_018_1).abs() < 1e-9, "{got}");
    // at its desired speed a follower at the desired gap keeps its speed (plain IDM brakes by
    // a there: it has no equilibrium at the desired speed, and dense traffic braked at once)
    let s_eq = 7.0 + 15.0 * 1.5; // leader as fast: no approach term
    assert!(idm_accel(15.0, 15.0, Some((s_eq, 15.0)), &IDM).abs() < 1e-12);
    // closer than the desired gap: brakes by the interaction term
    let close = idm_accel(15.0, 15.0, Some((0.5 * s_eq, 15.0)), &IDM);
    assert!((close - (1.0 - 4.0)).abs() < 1e-12, "{close}");
    // free road: only the desired-speed term; at the desired speed, no acceleration
    assert!((idm_accel(10.0, 15.0, None, &IDM) - 0.802_469_135_802_469).abs() < 1e-12);
    assert_eq!(idm_accel(15.0, 15.0, None, &IDM), 0.0);
}

#[test]
fn follower_brakes_behind_a_slow_leader_and_the_leader_is_free() {
    let x = [[0.0, 0.0], [20.0, 0.2]];
    let current = [[10.0, 0.0], [2.0, 0.0]];
    let desired = [[15.0, 0.0], [2.0, 0.0]];
    let rule = Rule::Vehicles {
        idm: IDM,
        personal: 2.0,
    };
    let v = interact(&x, &current, &desired, &rule, 0.5);
    // the leader (nobody ahead) keeps its desired velocity
    assert_eq!(v[1], [2.0, 0.0]);
    // the follower: u + dt * idm+, in the desired direction
    let s_star = 7.0 + 10.0 * 1.5 + 10.0 * 8.0 / (2.0 * 2f64.sqrt());
    let acc = (1.0 - (10.0f64 / 15.0).powi(4)).min(1.0 - (s_star / 20.0).powi(2));
    let want = (10.0 + 0.5 * acc).max(0.0);
    assert!(acc < 0.0);
    assert!(
        (v[0][0] - want).abs() < 1e-12 && v[0][1] == 0.0,
        "{:?} vs {want}",
        v[0]
    );
    // a vehicle in the next lane (lateral offset 3.5 > 1.5) is no leader: on a free road the
    // follower speeds up by IDM's free term, not to its desired speed at once
    let x2 = [[0.0, 0.0], [20.0, 3.5]];
    let free = 10.0 + 0.5 * (1.0 - (10.0f64 / 15.0).powi(4));
    let got = interact(&x2, &current, &desired, &rule, 0.5)[0];
    assert!((got[0] - free).abs() < 1e-12 && got[1] == 0.0, "{got:?}");
}

#[test]
fn free_vehicles_change_speed_by_idm_and_stop_without_reversing() {
    let rule = Rule::Vehicles {
        idm: IDM,
        personal: 2.0,
    };
    let x = [[0.0, 0.0]];
    // wants less than it drives: brakes by IDM's free term, but not below the desired speed
    let v = interact(&x, &[[10.0, 0.0]], &[[5.0, 0.0]], &rule, 0.5);
    assert_eq!(v[0], [5.0, 0.0]);
    let v = interact(&x, &[[10.0, 0.0]], &[[9.5, 0.0]], &rule, 0.5);
    let want = 10.0 + 0.5 * (1.0 - (10.0f64 / 9.5).powi(4));
    assert!((v[0][0] - want).abs() < 1e-12 && want > 9.5, "{:?}", v[0]);
    // wants to stand: slows at the acceleration a along its own heading, never backward
    let v = interact(&x, &[[0.0, 3.0]], &[[0.0, 0.0]], &rule, 0.5);
    assert_eq!(v[0], [0.0, 2.5]);
    let v = interact(&x, &[[0.0, 0.3]], &[[0.0, 0.0]], &rule, 0.5);
    assert_eq!(v[0], [0.0, 0.0]);
}

#[test]
fn the_profile_interpolates_and_scales_the_spread() {
    let mut p = Profile::FLAT;
    for i in 0..PROFILE_KNOTS {
        p.speed[i] = 1.0 + i as f64;
        p.factor[i] = [0.1 * (i + 1) as f64, 1.0];
    }
    assert_eq!(p.at(0.0), [0.1, 1.0]);
    assert_eq!(p.at(100.0), [0.8, 1.0]);
    let mid = p.at(2.25);
    assert!((mid[0] - 0.225).abs() < 1e-12 && (mid[1] - 1.0).abs() < 1e-12);
    // a slow field (speed 1: factor 0.1) spreads the stationary residual ten times less along
    // its heading than the factor 1 of the flat profile
    let motion = Motion {
        tau: 1.0,
        sigma: [0.8, 0.2],
        spread: Spread::Heading {
            min_speed: 0.01,
            tau_across: 1.0,
        },
        rule: Rule::Free,
        profile: p,
        tau_heading: None,
        heading_tolerance: 0.0,
        stand_speed: 0.0,
        jitter: [0.0; 2],
    };
    let mut slow = |q: &[Point]| -> Result<Vec<[f64; 2]>> { Ok(vec![[1.0, 0.0]; q.len()]) };
    let start = vec![[0.0, 0.0]; 2000];
    let r = drive(
        &start,
        Some(&vec![[1.0, 0.0]; 2000]),
        &opts(0.5, 20),
        &motion,
        Some(5),
        &mut slow,
    )
    .unwrap();
    let var = r.velocities[20 * 2000..]
        .iter()
        .map(|v| (v[0] - 1.0).powi(2))
        .sum::<f64>()
        / 2000.0;
    assert!((var / 0.0064 - 1.0).abs() < 0.15, "{var}");
}

#[test]
fn steering_vehicles_turn_toward_the_field_at_their_time_constant_and_stand() {
    // a field heading north at 5; a vehicle starting east at 5 turns as 1 - exp(-t / 2) of
    // the remaining angle per step (mean mode), its speed held at 5
    let motion = Motion {
        tau: f64::INFINITY,
        sigma: [0.5, 0.5],
        spread: Spread::Heading {
            min_speed: 0.1,
            tau_across: f64::INFINITY,
        },
        rule: Rule::Free,
        profile: Profile::FLAT,
        tau_heading: Some(2.0),
        heading_tolerance: 0.0,
        stand_speed: 0.0,
        jitter: [0.0; 2],
    };
    let mut north = |q: &[Point]| -> Result<Vec<[f64; 2]>> { Ok(vec![[0.0, 5.0]; q.len()]) };
    let r = drive(
        &[[0.0, 0.0]],
        Some(&[[5.0, 0.0]]),
        &opts(0.5, 10),
        &motion,
        None,
        &mut north,
    )
    .unwrap();
    let half_pi = std::f64::consts::FRAC_PI_2;
    for t in 1..=10 {
        let v = r.velocities[t];
        let want = half_pi * (1.0 - (-(t as f64) * 0.5 / 2.0).exp());
        assert!((v[1].atan2(v[0]) - want).abs() < 1e-12, "{t}: {v:?}");
        assert!((v[0].hypot(v[1]) - 5.0).abs() < 1e-12);
    }
    // a field at rest turns nobody
    let mut rest = |q: &[Point]| -> Result<Vec<[f64; 2]>> { Ok(vec![[0.0, 0.0]; q.len()]) };
    let m = Motion { tau: 0.5, ..motion };
    let r = drive(
        &[[0.0, 0.0]],
        Some(&[[-1.0, 1.0]]),
        &opts(0.5, 4),
        &m,
        None,
        &mut rest,
    )
    .unwrap();
    assert!(r.velocities[1][0] < 0.0 && r.velocities[1][1] > 0.0);
    let h = r.velocities[1][1].atan2(r.velocities[1][0]);
    assert!((h - 0.75 * std::f64::consts::PI).abs() < 1e-12);
    // generated scenes start along the field's heading (speed: the draw's part along it)
    let r = drive(
        &[[0.0, 0.0]],
        None,
        &opts(0.5, 2),
        &motion,
        None,
        &mut north,
    )
    .unwrap();
    assert_eq!(r.velocities[0], [0.0, 5.0]);
    // a drawn velocity against the field's heading (desired speed -3 along it) stands, heading
    // north, and stays (τ = ∞)
    struct Against;
    impl Field for Against {
        fn velocity(&mut self, q: &[Point]) -> Result<Vec<[f64; 2]>> {
            Ok(vec![[0.0, 5.0]; q.len()])
        }
        fn step_start(&mut self, _: usize, q: &[Point]) -> Result<crate::simulate::StepInfo> {
            Ok(crate::simulate::StepInfo {
                offset: vec![[0.0, -8.0]; q.len()],
                low_data: vec![false; q.len()],
                deferred: false,
            })
        }
    }
    let r = drive(
        &[[0.0, 0.0]],
        None,
        &opts(0.5, 3),
        &motion,
        None,
        &mut Against,
    )
    .unwrap();
    assert!(
        r.velocities.iter().all(|v| *v == [0.0, 0.0]),
        "{:?}",
        r.velocities
    );
    assert!(r.positions.iter().all(|p| *p == [0.0, 0.0]));
}

#[test]
fn pedestrians_keep_their_distance() {
    // two walkers heading at each other, 1 m apart, personal distance 0.8
    let x = [[0.0, 0.0], [1.0, 0.0]];
    let desired = [[1.0, 0.0], [-1.0, 0.0]];
    let v = interact(
        &x,
        &desired,
        &desired,
        &Rule::Pedestrians { personal: 0.8 },
        0.4,
    );
    let after = (x[1][0] + 0.4 * v[1][0]) - (x[0][0] + 0.4 * v[0][0]);
    assert!((after - 0.8).abs() < 1e-12, "{after}");
    // far apart: untouched
    let far = [[0.0, 0.0], [10.0, 0.0]];
    assert_eq!(
        interact(
            &far,
            &desired,
            &desired,
            &Rule::Pedestrians { personal: 0.8 },
            0.4
        ),
        desired
    );
}

#[test]
fn the_residual_relaxes_at_the_time_constant() {
    // a field of zero: a vehicle starting at velocity (2, -1) slows as exp(-t / tau)
    let motion = Motion {
        tau: 2.0,
        sigma: [0.5, 0.5],
        spread: Spread::Components,
        rule: Rule::Free,
        profile: Profile::FLAT,
        tau_heading: None,
        heading_tolerance: 0.0,
        stand_speed: 0.0,
        jitter: [0.0; 2],
    };
    let mut zero = |q: &[Point]| -> Result<Vec<[f64; 2]>> { Ok(vec![[0.0; 2]; q.len()]) };
    let r = drive(
        &[[0.0, 0.0]],
        Some(&[[2.0, -1.0]]),
        &opts(0.1, 30),
        &motion,
        None,
        &mut zero,
    )
    .unwrap();
    for t in 0..=30 {
        let f = (-(t as f64) * 0.1 / 2.0).exp();
        let v = r.velocities[t];
        assert!(
            (v[0] - 2.0 * f).abs() < 1e-12 && (v[1] + f).abs() < 1e-12,
            "{t}: {v:?}"
        );
    }
    // positions: forward Euler on those velocities
    let x_end: f64 = (0..30).map(|t| 0.1 * r.velocities[t][0]).sum();
    assert!((r.positions[30][0] - x_end).abs() < 1e-12);
}

#[test]
fn stochastic_residual_has_the_stationary_spread_and_is_seeded() {
    let motion = Motion {
        tau: 1.0,
        sigma: [0.7, 0.3],
        spread: Spread::Components,
        rule: Rule::Free,
        profile: Profile::FLAT,
        tau_heading: None,
        heading_tolerance: 0.0,
        stand_speed: 0.0,
        jitter: [0.0; 2],
    };
    let mut zero = |q: &[Point]| -> Result<Vec<[f64; 2]>> { Ok(vec![[0.0; 2]; q.len()]) };
    let start = vec![[0.0, 0.0]; 400];
    let v0 = vec![[0.0, 0.0]; 400];
    let a = drive(
        &start,
        Some(&v0),
        &opts(0.5, 20),
        &motion,
        Some(9),
        &mut zero,
    )
    .unwrap();
    let b = drive(
        &start,
        Some(&v0),
        &opts(0.5, 20),
        &motion,
        Some(9),
        &mut zero,
    )
    .unwrap();
    assert_eq!(a, b);
    // after 20 steps (10 tau) the residual is stationary: var 0.49 and 0.09
    let last = &a.velocities[20 * 400..];
    for (d, want) in [(0, 0.49), (1, 0.09)] {
        let var = last.iter().map(|v| v[d] * v[d]).sum::<f64>() / 400.0;
        assert!((var / want - 1.0).abs() < 0.25, "{d}: {var} vs {want}");
    }
}

#[test]
fn bad_motion_records_are_errors() {
    assert!(Motion::from_slice(&[1.0; 3]).is_err());
    assert!(
        Motion::from_slice(&rec(&[
            0.0, 1.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, -1.0, 1.0
        ]))
        .is_err()
    );
    assert!(
        Motion::from_slice(&rec(&[
            1.0, 1.0, 1.0, 7.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, -1.0, 1.0
        ]))
        .is_err()
    );
    assert!(
        Motion::from_slice(&rec(&[
            1.0, 1.0, 1.0, 1.0, 1.0, -1.0, 1.0, 1.0, 1.0, 1.0, -1.0, 1.0
        ]))
        .is_err()
    );
    let m = Motion::from_slice(&rec(&[
        f64::INFINITY,
        1.0,
        1.0,
        2.0,
        0.5,
        1.0,
        1.0,
        1.0,
        1.0,
        1.0,
        -1.0,
        1.0,
    ]))
    .unwrap();
    assert_eq!(m.rule, Rule::Pedestrians { personal: 0.5 });
}

#[test]
fn heading_spread_is_along_and_across_the_field() {
    // a uniform field heading at 30°: the stationary residual spreads 0.8 along it and 0.2
    // across; a field at rest gives the isotropic spread
    let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
    let motion = Motion {
        tau: 1.0,
        sigma: [0.8, 0.2],
        spread: Spread::Heading {
            min_speed: 0.1,
            tau_across: 1.0,
        },
        rule: Rule::Free,
        profile: Profile::FLAT,
        tau_heading: None,
        heading_tolerance: 0.0,
        stand_speed: 0.0,
        jitter: [0.0; 2],
    };
    let mut uniform =
        |q: &[Point]| -> Result<Vec<[f64; 2]>> { Ok(vec![[5.0 * c, 5.0 * s]; q.len()]) };
    let start = vec![[0.0, 0.0]; 2000];
    let v0 = vec![[5.0 * c, 5.0 * s]; 2000];
    let a = drive(
        &start,
        Some(&v0),
        &opts(0.5, 20),
        &motion,
        Some(3),
        &mut uniform,
    )
    .unwrap();
    let last = &a.velocities[20 * 2000..];
    let (mut along, mut across) = (0.0, 0.0);
    for v in last {
        let r = [v[0] - 5.0 * c, v[1] - 5.0 * s];
        along += (r[0] * c + r[1] * s).powi(2) / 2000.0;
        across += (-r[0] * s + r[1] * c).powi(2) / 2000.0;
    }
    assert!((along / 0.64 - 1.0).abs() < 0.15, "{along}");
    assert!((across / 0.04 - 1.0).abs() < 0.15, "{across}");
    let mut rest = |q: &[Point]| -> Result<Vec<[f64; 2]>> { Ok(vec![[0.0, 0.0]; q.len()]) };
    let b = drive(
        &start,
        Some(&vec![[0.0; 2]; 2000]),
        &opts(0.5, 20),
        &motion,
        Some(3),
        &mut rest,
    )
    .unwrap();
    let var = b.velocities[20 * 2000..]
        .iter()
        .map(|v| v[0] * v[0])
        .sum::<f64>()
        / 2000.0;
    assert!((var / 0.34 - 1.0).abs() < 0.15, "{var}");
    // the record: min_speed >= 0 selects the heading frame
    let m = Motion::from_slice(&rec(&[
        1.0, 0.8, 0.2, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.1, 0.5,
    ]))
    .unwrap();
    assert_eq!(
        m.spread,
        Spread::Heading {
            min_speed: 0.1,
            tau_across: 0.5
        }
    );
}

#[test]
fn steering_vehicles_drive_straight_within_their_tolerance_and_stand_below_the_stand_speed() {
    // a field heading 0.05 rad north of east at 5: within a tolerance of 0.1 a vehicle going
    // east keeps going east exactly; a field at 0.3 rad turns it by the share of 0.2 rad
    let motion = Motion {
        tau: f64::INFINITY,
        sigma: [0.5, 0.5],
        spread: Spread::Heading {
            min_speed: 0.1,
            tau_across: f64::INFINITY,
        },
        rule: Rule::Free,
        profile: Profile::FLAT,
        tau_heading: Some(2.0),
        heading_tolerance: 0.1,
        stand_speed: 0.0,
        jitter: [0.0; 2],
    };
    let field_at = |a: f64| {
        move |q: &[Point]| -> Result<Vec<[f64; 2]>> {
            Ok(vec![[5.0 * a.cos(), 5.0 * a.sin()]; q.len()])
        }
    };
    let r = drive(
        &[[0.0, 0.0]],
        Some(&[[5.0, 0.0]]),
        &opts(0.5, 6),
        &motion,
        None,
        &mut field_at(0.05),
    )
    .unwrap();
    for t in 1..=6 {
        assert_eq!(r.velocities[t], [5.0, 0.0], "{t}");
    }
    let r = drive(
        &[[0.0, 0.0]],
        Some(&[[5.0, 0.0]]),
        &opts(0.5, 1),
        &motion,
        None,
        &mut field_at(0.3),
    )
    .unwrap();
    let v = r.velocities[1];
    let want = 0.2 * (1.0 - (-0.25f64).exp());
    assert!((v[1].atan2(v[0]) - want).abs() < 1e-12, "{v:?}");
    // without the tolerance the same vehicle turns toward 0.05 rad
    let m0 = Motion {
        heading_tolerance: 0.0,
        ..motion
    };
    let r = drive(
        &[[0.0, 0.0]],
        Some(&[[5.0, 0.0]]),
        &opts(0.5, 1),
        &m0,
        None,
        &mut field_at(0.05),
    )
    .unwrap();
    assert!(r.velocities[1][1] > 0.0);
    // a field at 0.2 (a queue's slow mean): the vehicle wishes 0.2 (τ = 0.25 s) and stands
    // below a stand speed of 0.3, drives at it without one
    let slow = |q: &[Point]| -> Result<Vec<[f64; 2]>> { Ok(vec![[0.2, 0.0]; q.len()]) };
    for (stand, want) in [(0.3, 0.0), (0.0, 0.2)] {
        let m = Motion {
            tau: 0.25,
            stand_speed: stand,
            ..motion
        };
        let r = drive(
            &[[0.0, 0.0]],
            Some(&[[0.0, 0.0]]),
            &opts(0.5, 8),
            &m,
            None,
            &mut { slow },
        )
        .unwrap();
        let v = r.velocities[8];
        assert!((v[0] - want).abs() < 0.01 && v[1] == 0.0, "{stand}: {v:?}");
    }
    // a stand speed must be finite and >= 0
    let m = Motion {
        stand_speed: -1.0,
        ..motion
    };
    assert!(m.validate().is_err());
}

#[test]
fn step_jitter_spreads_along_and_across_and_is_independent_per_step() {
    // τ = ∞, σ = 0: without jitter every agent keeps its start velocity exactly; with jitter
    // (0.3 along the field's heading, 0.1 across) the actual velocity is the held desired one
    // plus an independent draw per step, of those spreads, in the heading frame
    let motion = Motion {
        tau: f64::INFINITY,
        sigma: [0.0, 0.0],
        spread: Spread::Heading {
            min_speed: 0.01,
            tau_across: f64::INFINITY,
        },
        rule: Rule::Free,
        profile: Profile::FLAT,
        tau_heading: None,
        heading_tolerance: 0.0,
        stand_speed: 0.0,
        jitter: [0.0; 2],
    };
    let mut north = |q: &[Point]| -> Result<Vec<[f64; 2]>> { Ok(vec![[0.0, 1.0]; q.len()]) };
    let n = 4000;
    let start = vec![[0.0, 0.0]; n];
    let v0 = vec![[0.0, 1.0]; n];
    let still = drive(
        &start,
        Some(&v0),
        &opts(0.4, 3),
        &motion,
        Some(3),
        &mut north,
    )
    .unwrap();
    assert!(still.velocities.iter().all(|v| *v == [0.0, 1.0]));
    let m = Motion {
        jitter: [0.3, 0.1],
        ..motion
    };
    let r = drive(&start, Some(&v0), &opts(0.4, 3), &m, Some(3), &mut north).unwrap();
    // a recorded start keeps its velocity exactly
    assert!(r.velocities[..n].iter().all(|v| *v == [0.0, 1.0]));
    let (mut sa, mut sc, mut lag) = (0.0, 0.0, 0.0);
    for i in 0..n {
        let (a, b) = (r.velocities[n + i], r.velocities[2 * n + i]);
        sa += (a[1] - 1.0).powi(2); // along the heading (north)
        sc += a[0].powi(2);
        lag += (a[1] - 1.0) * (b[1] - 1.0);
    }
    let (sa, sc, lag) = (
        (sa / n as f64).sqrt(),
        (sc / n as f64).sqrt(),
        lag / n as f64,
    );
    assert!((sa / 0.3 - 1.0).abs() < 0.05, "{sa}");
    assert!((sc / 0.1 - 1.0).abs() < 0.05, "{sc}");
    assert!(lag.abs() < 0.09 * 0.1, "{lag}"); // not carried to the next step
    // mean mode: no jitter; the same seed: the same draws
    let mean = drive(&start, Some(&v0), &opts(0.4, 3), &m, None, &mut north).unwrap();
    assert!(mean.velocities.iter().all(|v| *v == [0.0, 1.0]));
    let again = drive(&start, Some(&v0), &opts(0.4, 3), &m, Some(3), &mut north).unwrap();
    assert_eq!(again.velocities, r.velocities);
    // a negative or non-finite jitter is an error
    for bad in [[-0.1, 0.0], [0.0, f64::NAN]] {
        assert!(
            Motion {
                jitter: bad,
                ..motion
            }
            .validate()
            .is_err()
        );
    }
}

/// A steering vehicle model with IDM interaction (mean mode in the tests below).
fn steering_vehicles(tau_heading: f64) -> Motion {
    Motion {
        tau: 1.0,
        sigma: [0.5, 0.5],
        spread: Spread::Heading {
            min_speed: 0.1,
            tau_across: 1.0,
        },
        rule: Rule::Vehicles {
            idm: IDM,
            personal: 2.0,
        },
        profile: Profile::FLAT,
        tau_heading: Some(tau_heading),
        heading_tolerance: 0.0,
        stand_speed: 0.0,
        jitter: [0.0; 2],
    }
}

#[test]
fn a_rollout_continued_with_its_drivers_is_the_rollout_run_on() {
    // a follower closing on a slow leader under a field that turns north with x: braking and
    // turning, its actual velocity is not its wish. Six steps then six more from where the
    // first run left its drivers must equal twelve steps at once (mean mode); restarting from
    // the actual velocities alone (the old long-scenario blocks) must not.
    let motion = steering_vehicles(2.0);
    let mut field = |q: &[Point]| -> Result<Vec<[f64; 2]>> {
        Ok(q.iter().map(|p| [10.0, 0.3 * p[0]]).collect())
    };
    let start = [[0.0, 0.0], [15.0, 0.3]];
    let v0 = [[10.0, 0.0], [2.0, 0.0]];
    let whole = drive(&start, Some(&v0), &opts(0.5, 12), &motion, None, &mut field).unwrap();
    let first = drive(&start, Some(&v0), &opts(0.5, 6), &motion, None, &mut field).unwrap();
    let (x6, v6) = (&first.positions[12..14], &first.velocities[12..14]);
    let on = drive_on(
        x6,
        Some(v6),
        Some(Carried::kept(&first.drivers)),
        &[],
        &opts(0.5, 6),
        &motion,
        None,
        None,
        &mut field,
    )
    .unwrap();
    for t in 0..=6 {
        for j in 0..2 {
            let (a, b) = (on.positions[2 * t + j], whole.positions[2 * (t + 6) + j]);
            assert!(
                (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9,
                "{t} {j}: {a:?} {b:?}"
            );
        }
    }
    let restarted = drive(x6, Some(v6), &opts(0.5, 6), &motion, None, &mut field).unwrap();
    let gap = (0..2)
        .map(|j| {
            let (a, b) = (restarted.positions[12 + j], whole.positions[24 + j]);
            (a[0] - b[0]).hypot(a[1] - b[1])
        })
        .fold(0.0, f64::max);
    assert!(
        gap > 1e-3,
        "the restart should lose the drivers' wishes: {gap}"
    );
    // driver states must come with the start velocities, one per agent
    assert!(
        drive_on(
            x6,
            None,
            Some(Carried::kept(&first.drivers)),
            &[],
            &opts(0.5, 1),
            &motion,
            None,
            None,
            &mut field
        )
        .is_err()
    );
    assert!(
        drive_on(
            x6,
            Some(v6),
            Some(Carried::kept(&first.drivers[..1])),
            &[],
            &opts(0.5, 1),
            &motion,
            None,
            None,
            &mut field
        )
        .is_err()
    );
}

#[test]
fn a_vehicle_standing_in_a_queue_keeps_its_heading() {
    // a follower heading east, blocked by a standing leader 7.5 ahead (the jam distance), under a
    // field that points north: it stands, and does not turn while it stands (it would have
    // turned by 1 - exp(-20 * 0.5 / 2) = 99% of the way in 20 steps at τ_h = 2 s)
    let motion = steering_vehicles(2.0);
    struct Stop;
    impl Field for Stop {
        fn velocity(&mut self, q: &[Point]) -> Result<Vec<[f64; 2]>> {
            // the leader's own field is at rest (it stands); the follower's points north
            Ok(q.iter()
                .map(|p| if p[0] > 5.0 { [0.0, 0.0] } else { [0.0, 5.0] })
                .collect())
        }
    }
    let r = drive_on(
        &[[0.0, 0.0], [7.0, 0.0]],
        Some(&[[0.0, 0.0], [0.0, 0.0]]),
        Some(Carried::kept(&[[0.0, 5.0], [0.0, 0.0]])),
        &[],
        &opts(0.5, 20),
        &motion,
        None,
        None,
        &mut Stop,
    )
    .unwrap();
    assert_eq!(
        r.drivers[0][0], 0.0,
        "heading of the standing follower: {:?}",
        r.drivers[0]
    );
    assert_eq!(r.positions[40], [0.0, 0.0]);
}

#[test]
fn a_driver_follows_a_field_only_as_far_as_it_knows() {
    // a field at rest (its prior mean: no data): with support 0 a steering vehicle driving east
    // at 5 keeps its wish; with support 1 (the default) it slows toward the field (τ = 1 s); with
    // support 0.5 it relaxes at half the rate: u = 5 exp(-0.5 t / τ) after t seconds (mean mode,
    // no interaction)
    struct Known(Option<f64>);
    impl Field for Known {
        fn velocity(&mut self, q: &[Point]) -> Result<Vec<[f64; 2]>> {
            Ok(vec![[0.0, 0.0]; q.len()])
        }
        fn support(&mut self, q: &[Point]) -> Result<Option<Vec<f64>>> {
            Ok(self.0.map(|s| vec![s; q.len()]))
        }
    }
    let motion = Motion {
        rule: Rule::Free,
        ..steering_vehicles(2.0)
    };
    let run = |s: Option<f64>| {
        drive_on(
            &[[0.0, 0.0]],
            Some(&[[5.0, 0.0]]),
            Some(Carried::kept(&[[0.0, 5.0]])),
            &[],
            &opts(0.5, 4),
            &motion,
            None,
            None,
            &mut Known(s),
        )
        .unwrap()
    };
    assert_eq!(run(Some(0.0)).velocities[4], [5.0, 0.0]);
    let full = run(None).velocities[4][0];
    assert!((full - 5.0 * (-2.0f64).exp()).abs() < 1e-12, "{full}");
    let half = run(Some(0.5)).velocities[4][0];
    assert!((half - 5.0 * (-1.0f64).exp()).abs() < 1e-12, "{half}");
}

#[test]
fn renewed_drivers_take_up_the_new_field_as_far_as_it_knows_them() {
    // a field east at 8, known with support s; a driver heading east that stood (wish 0) and a
    // residual that never relaxes (τ = ∞): kept, it still wants to stand; renewed, it wants
    // s * 8 from the first step on, and holds it (mean mode, no interaction)
    use std::f64::consts::FRAC_PI_2;
    struct East(f64);
    impl Field for East {
        fn velocity(&mut self, q: &[Point]) -> Result<Vec<[f64; 2]>> {
            Ok(vec![[8.0, 0.0]; q.len()])
        }
        fn support(&mut self, q: &[Point]) -> Result<Option<Vec<f64>>> {
            Ok(Some(vec![self.0; q.len()]))
        }
    }
    let steering = Motion {
        tau: f64::INFINITY,
        spread: Spread::Heading {
            min_speed: 0.1,
            tau_across: f64::INFINITY,
        },
        rule: Rule::Free,
        ..steering_vehicles(2.0)
    };
    let plain = Motion {
        tau_heading: None,
        ..steering
    };
    for s in [0.0, 0.5, 1.0] {
        let run = |motion: &Motion, state: [f64; 2], renew: bool| {
            let states = [state];
            drive_on(
                &[[0.0, 0.0]],
                Some(&[[0.0, 0.0]]),
                Some(Carried {
                    states: &states,
                    renew,
                }),
                &[],
                &opts(0.5, 3),
                motion,
                None,
                None,
                &mut East(s),
            )
            .unwrap()
            .drivers[0]
        };
        assert_eq!(run(&steering, [0.0, 0.0], false), [0.0, 0.0]);
        assert_eq!(run(&steering, [0.0, 0.0], true), [0.0, s * 8.0]);
        // a wish of 2 keeps (1 - s) of itself
        assert_eq!(
            run(&steering, [0.0, 2.0], true),
            [0.0, (1.0 - s) * 2.0 + s * 8.0]
        );
        // a heading across the field (a vehicle that stood since it entered): the field's speed,
        // toward which steering relaxes the wish; the heading is kept at the start
        let across = run(&steering, [FRAC_PI_2, 0.0], true);
        assert_eq!(across[1], s * 8.0, "{s}: {across:?}");
        // without steering: the desired velocity itself, toward the field's
        assert_eq!(run(&plain, [0.0, 4.0], false), [0.0, 4.0]);
        let w = run(&plain, [0.0, 4.0], true);
        assert!(
            (w[0] - s * 8.0).abs() < 1e-12 && (w[1] - (1.0 - s) * 4.0).abs() < 1e-12,
            "{s}: {w:?}"
        );
    }
}

#[test]
fn a_red_stop_line_is_a_standing_leader_for_its_approach_only() {
    // a vehicle at 8 heading east, wishing 10, 40 behind a line for eastbound traffic: IDM+
    // behind a standing vehicle one jam distance beyond the line (gap 47). By hand: s* = 7 + 8 *
    // 1.5 + 8 * 8 / (2 √2) = 41.627417, a = min(1 - 0.8^4, 1 - (s* / 47)^2) = 0.2155528 (the gap
    // is still above the desired one: it closes before braking)
    let rule = Rule::Vehicles {
        idm: IDM,
        personal: 2.0,
    };
    let step = |line: &[Stop]| {
        interact_headed(
            &[[0.0, 0.0]],
            &[[8.0, 0.0]],
            &[[10.0, 0.0]],
            None,
            line,
            &rule,
            0.5,
        )[0]
    };
    let line = Stop::new([40.0, 0.5], [2.0, 0.0]).unwrap();
    assert_eq!(line.heading, [1.0, 0.0]);
    let want = 8.0 + 0.5 * idm_accel(8.0, 10.0, Some((47.0, 0.0)), &IDM);
    assert!((want - (8.0 + 0.5 * 0.215_552_8)).abs() < 1e-6, "{want}");
    let got = step(&[line]);
    assert!((got[0] - want).abs() < 1e-12 && got[1] == 0.0, "{got:?}");
    // free road for a line of westbound traffic, beside the corridor, or behind the vehicle
    let free = step(&[]);
    assert!(free[0] > 8.0);
    for other in [
        ([40.0, 0.5], [-1.0, 0.0]),
        ([40.0, 1.6], [1.0, 0.0]),
        ([-4.0, 0.0], [1.0, 0.0]),
    ] {
        let s = Stop::new(other.0, other.1).unwrap();
        assert_eq!(step(&[s]), free, "{s:?}");
    }
    // it stops for a line it can reach braking at 2b (8² / (4 * 2) = 8 m within 5 + 3.5), and
    // clears one nearer (4 + 3.5 < 8); a nearer leader stays the leader
    assert!(step(&[Stop::new([5.0, 0.0], [1.0, 0.0]).unwrap()])[0] < 8.0);
    assert_eq!(step(&[Stop::new([4.0, 0.0], [1.0, 0.0]).unwrap()]), free);
    let x = [[0.0, 0.0], [20.0, 0.0]];
    let with_leader = |line: &[Stop]| {
        interact_headed(
            &x,
            &[[8.0, 0.0], [0.0, 0.0]],
            &[[10.0, 0.0], [0.0, 0.0]],
            None,
            line,
            &rule,
            0.5,
        )[0]
    };
    assert_eq!(with_leader(&[line]), with_leader(&[]));
    // a stop line needs a place and a direction
    assert!(Stop::new([0.0, 0.0], [0.0, 0.0]).is_err());
    assert!(Stop::new([f64::NAN, 0.0], [1.0, 0.0]).is_err());
}

#[test]
fn vehicles_queue_at_a_red_line_and_the_crossing_traffic_passes() {
    // two vehicles heading east at 8 under a field east at 8, a red line at x = 50 for them; a
    // third heading north at x = 70 under a field north (mean mode, steering, IDM)
    let motion = steering_vehicles(2.0);
    let mut field = |q: &[Point]| -> Result<Vec<[f64; 2]>> {
        Ok(q.iter()
            .map(|p| if p[0] > 65.0 { [0.0, 8.0] } else { [8.0, 0.0] })
            .collect())
    };
    let start = [[0.0, 0.0], [-20.0, 0.0], [70.0, -30.0]];
    let v0 = [[8.0, 0.0], [8.0, 0.0], [0.0, 8.0]];
    let red = [Stop::new([50.0, 0.0], [1.0, 0.0]).unwrap()];
    let run = |stops: &[Stop], field: &mut dyn Field| {
        drive_on(
            &start,
            Some(&v0),
            None,
            stops,
            &opts(0.5, 60),
            &motion,
            None,
            None,
            field,
        )
        .unwrap()
    };
    let r = run(&red, &mut field);
    let (last, vel) = (&r.positions[180..183], &r.velocities[180..183]);
    // the first stands at the line (centre at most half a jam distance past it), the second
    // behind it at about the jam distance (Euler's guard lets it close to half), and the crossing
    // vehicle drove on at its speed
    assert!(last[0][0] > 48.0 && last[0][0] <= 53.5, "{:?}", last[0]);
    let gap = last[0][0] - last[1][0];
    assert!(gap > 0.75 * IDM.jam && gap < IDM.jam + 0.5, "{last:?}");
    assert!(
        vel[0][0].hypot(vel[0][1]) < 0.05 && vel[1][0].hypot(vel[1][1]) < 0.05,
        "{vel:?}"
    );
    assert!((last[2][1] - 210.0).abs() < 1.0, "{:?}", last[2]);
    // without the line the first drives through (and turns north with the field past x = 65)
    let green = run(&[], &mut field);
    assert!(green.positions[180][0] > 65.0, "{:?}", green.positions[180]);
}

#[test]
fn a_generated_queue_starts_at_speeds_that_keep_its_gaps() {
    // a standing front vehicle (the field is 0 from x = 35), a queue of three behind it 10 apart,
    // and one free in the next lane; the field wants 15 elsewhere (a pattern's mean mixes the
    // queue with free flow)
    let motion = Motion::from_slice(&rec(&[
        1.0, 0.5, 0.5, 1.0, 2.0, 7.0, 1.5, 1.0, 2.0, 1.5, -1.0, 1.0,
    ]))
    .unwrap();
    let Rule::Vehicles { idm, .. } = motion.rule else {
        panic!("vehicles")
    };
    let mut field = |q: &[Point]| -> Result<Vec<[f64; 2]>> {
        Ok(q.iter()
            .map(|p| {
                if p[0] >= 35.0 {
                    [0.0, 0.0]
                } else {
                    [15.0, 0.0]
                }
            })
            .collect())
    };
    let start = [
        [40.0, 0.0],
        [30.0, 0.0],
        [20.0, 0.0],
        [10.0, 0.0],
        [10.0, 3.5],
    ];
    let r = drive(&start, None, &opts(0.5, 2), &motion, None, &mut field).unwrap();
    let speed = |t: usize, j: usize| r.velocities[t * 5 + j][0];
    let c = 1.0 / (2.0 * (idm.accel * idm.decel).sqrt());
    // each follower no faster than IDM keeps its desired gap at behind its leader's speed
    for j in 1..4 {
        let (u, lead) = (speed(0, j), speed(0, j - 1));
        let s_star = idm.jam + u * idm.headway + u * (u - lead) * c;
        assert!(
            s_star <= 10.0 + 1e-9,
            "vehicle {j}: s* {s_star} at {u} behind {lead}"
        );
        assert!(u > 0.0 && u < 15.0 && r.velocities[j][1] == 0.0, "{u}");
    }
    // settled from the front: the first follower's speed is the root of s* = gap behind a standing leader
    let u1 = (-idm.headway + (idm.headway.powi(2) + 4.0 * c * 3.0).sqrt()) / (2.0 * c);
    assert!((speed(0, 1) - u1).abs() < 1e-12, "{} vs {u1}", speed(0, 1));
    // no hard braking at the first step (it braked from 15 to about 0 before)
    for j in 1..4 {
        assert!(
            speed(0, j) - speed(1, j) < 0.5 * idm.decel,
            "vehicle {j}: {} -> {}",
            speed(0, j),
            speed(1, j)
        );
    }
    // the vehicle in the next lane is nobody's follower: its draw stands
    assert_eq!(r.velocities[4], [15.0, 0.0]);
    // recorded starts keep their own velocities
    let own = vec![[15.0, 0.0]; 5];
    let r = drive(&start, Some(&own), &opts(0.5, 1), &motion, None, &mut field).unwrap();
    assert!(r.velocities[..5].iter().all(|v| *v == [15.0, 0.0]));
}

/// The standard normal density of a pair.
fn phi2(z: [f64; 2]) -> f64 {
    (-(z[0] * z[0] + z[1] * z[1]) / 2.0).exp() / (2.0 * std::f64::consts::PI)
}

#[test]
fn a_shift_weighs_its_draws_by_the_mixture_density() {
    // 3 vehicles x 3 times = 9 slots, 7 of them drawn (two vehicles gone): the ratio against a
    // direct computation of both densities, natural (every draw standard) over the mixture of
    // "slot c drawn from N(mu, I)" (an undrawn slot's component is the natural density)
    let mean = [-1.3, 0.4];
    let mut s = Shifting::new(Shift { mean }, 11, 3, 2).unwrap();
    let drawn = [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (2, 0), (2, 1)];
    let mut zs = Vec::new();
    for (k, &(t, j)) in drawn.iter().enumerate() {
        let raw = [0.3 * k as f64 - 0.7, 0.5 - 0.2 * k as f64];
        let z = s.draw(t, j, 3, raw);
        if t * 3 + j == s.slot {
            assert_eq!(z, [raw[0] + mean[0], raw[1] + mean[1]]);
            assert_eq!(s.pick, Some(z));
        } else {
            assert_eq!(z, raw);
        }
        zs.push(z);
    }
    let p: f64 = zs.iter().map(|&z| phi2(z)).product();
    let mut q = 0.0;
    for c in 0..9 {
        let mut qc = 1.0;
        for (k, &(t, j)) in drawn.iter().enumerate() {
            let z = zs[k];
            qc *= if t * 3 + j == c {
                phi2([z[0] - mean[0], z[1] - mean[1]])
            } else {
                phi2(z)
            };
        }
        q += qc / 9.0;
    }
    let want = (p / q).ln();
    assert!(
        (s.log_ratio() - want).abs() < 1e-12,
        "{} vs {want}",
        s.log_ratio()
    );
    // no shift: every weight 1
    let mut none = Shifting::new(Shift { mean: [0.0; 2] }, 11, 3, 2).unwrap();
    none.draw(0, 0, 3, [2.0, -1.0]);
    assert_eq!(none.log_ratio(), 0.0);
    assert!(
        Shifting::new(
            Shift {
                mean: [f64::NAN, 0.0]
            },
            1,
            1,
            1
        )
        .is_err()
    );
}

#[test]
fn shifted_rollouts_have_mean_weight_one_and_unbiased_expectations() {
    // a free vehicle and a follower on a uniform field; the statistic is the follower's last
    // speed above 16.5 (rare naturally, frequent when its wish is pushed up)
    let motion = Motion::from_slice(&rec(&[
        2.0, 1.0, 0.5, 1.0, 2.0, 7.0, 1.5, 1.0, 2.0, 1.5, 0.1, 1.0,
    ]))
    .unwrap();
    let mut field = |q: &[Point]| -> Result<Vec<[f64; 2]>> { Ok(vec![[15.0, 0.0]; q.len()]) };
    let start = [[0.0, 0.0], [0.0, 20.0]];
    let o = opts(0.5, 4);
    let n = 20_000;
    let stat = |r: &Rollout| f64::from(u8::from(r.velocities[4 * 2 + 1][0] > 16.5));
    let (mut w_sum, mut w2, mut hit, mut hit2, mut natural) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for seed in 0..n as u64 {
        let r = drive_shifted(
            &start,
            &o,
            &motion,
            seed,
            Shift { mean: [2.0, 0.0] },
            &mut field,
        )
        .unwrap();
        let w = r.log_ratio.exp();
        w_sum += w;
        w2 += w * w;
        hit += w * stat(&r);
        hit2 += (w * stat(&r)).powi(2);
        let nat = drive(
            &start,
            None,
            &o,
            &motion,
            Some(seed + 1_000_000),
            &mut field,
        )
        .unwrap();
        natural += stat(&nat);
    }
    let nf = n as f64;
    let (mean_w, se_w) = (w_sum / nf, ((w2 / nf - (w_sum / nf).powi(2)) / nf).sqrt());
    assert!((mean_w - 1.0).abs() < 4.0 * se_w, "{mean_w} ± {se_w}");
    let (est, se) = (hit / nf, ((hit2 / nf - (hit / nf).powi(2)) / nf).sqrt());
    let crude = natural / nf;
    let se_crude = (crude * (1.0 - crude) / nf).sqrt();
    assert!(crude > 0.002 && crude < 0.2, "{crude}");
    assert!(
        (est - crude).abs() < 4.0 * (se * se + se_crude * se_crude).sqrt(),
        "{est} ± {se} vs {crude} ± {se_crude}"
    );
    // without a seed there is nothing to shift
    let err = drive_on(
        &start,
        None,
        None,
        &[],
        &o,
        &motion,
        None,
        Some(Shift { mean: [1.0, 0.0] }),
        &mut field,
    );
    assert!(err.is_err());
}

/// [`IDM`] with the vehicles' length (the cut-in moderation) and a braking bound.
const BOUNDED: Idm = Idm {
    brake: 9.0,
    length: 4.5,
    width: 1.8,
    ..IDM
};

#[test]
fn the_cah_moderates_idm_as_the_acc_model_does() {
    // without a length, or a leader, it is IDM+ itself
    let gap = Some((6.0, 15.0));
    assert_eq!(
        acc_accel(15.0, 15.0, gap, &IDM),
        idm_accel(15.0, 15.0, gap, &IDM)
    );
    assert_eq!(
        acc_accel(10.0, 15.0, None, &BOUNDED),
        idm_accel(10.0, 15.0, None, &BOUNDED)
    );
    // where IDM brakes less than the CAH's collision-free deceleration, IDM
    let easy = Some((60.0, 14.0));
    assert_eq!(
        acc_accel(15.0, 15.0, easy, &BOUNDED),
        idm_accel(15.0, 15.0, easy, &BOUNDED)
    );
    // a neighbour cutting in 6 ahead (bumper gap 1.5) at one's own speed: IDM+ asks for about
    // 18 b; the CAH sees no approach (a_CAH = 0) and the blend brakes at about b. By hand:
    // s* = 7 + 15 * 1.5 = 29.5, a_IDM = 1 - (29.5 / 6)^2 = -23.1736111;
    // (1 - c) a_IDM + c (0 + b tanh(a_IDM / b)) = -0.2317361 + 0.99 * 2 * tanh(-11.5868056)
    let idm = idm_accel(15.0, 15.0, gap, &BOUNDED);
    assert!(
        (idm - (1.0 - (29.5f64 / 6.0).powi(2))).abs() < 1e-12,
        "{idm}"
    );
    let want = 0.01 * idm + 0.99 * 2.0 * (idm / 2.0).tanh();
    let got = acc_accel(15.0, 15.0, gap, &BOUNDED);
    assert!((got - want).abs() < 1e-12, "{got} vs {want}");
    assert!(
        (got - (-2.211_736_1)).abs() < 1e-6 && got < -BOUNDED.decel,
        "{got}"
    );
    // closing at 5 on a bumper gap of 10: a_CAH = -25 / 20 = -1.25; IDM+ brakes harder, and the
    // blend lies between them, no softer than the CAH minus b
    let closing = Some((14.5, 10.0));
    let idm = idm_accel(15.0, 15.0, closing, &BOUNDED);
    let cah = -1.25;
    let want = 0.01 * idm + 0.99 * (cah + 2.0 * ((idm - cah) / 2.0).tanh());
    let got = acc_accel(15.0, 15.0, closing, &BOUNDED);
    assert!(idm < cah && (got - want).abs() < 1e-12, "{got} vs {want}");
    assert!(got > idm && got < cah, "{idm} < {got} < {cah}");
}

#[test]
fn vehicles_brake_no_harder_than_their_bound() {
    let rule = |idm| Rule::Vehicles { idm, personal: 2.0 };
    let dt = 0.5;
    // a neighbour alongside drifts into the corridor 3 ahead at the follower's speed: IDM+ (and
    // the Euler guard) stop the follower in one step; bounded, it loses dt * brake at most
    let x = [[0.0, 0.0], [3.0, 1.2]];
    let current = [[15.0, 0.0], [15.0, 0.0]];
    let desired = current;
    let plain = interact(&x, &current, &desired, &rule(IDM), dt);
    assert_eq!(plain[0], [0.0, 0.0]);
    let bounded = interact(&x, &current, &desired, &rule(BOUNDED), dt);
    let u = bounded[0][0].hypot(bounded[0][1]);
    assert!(u >= 15.0 - dt * 9.0 - 1e-12 && u < 15.0, "{:?}", bounded[0]);
    // a wish that falls at once, and the personal distance pushing two vehicles apart, also
    // slow a vehicle by dt * brake at most
    let free = interact(
        &[[0.0, 0.0]],
        &[[15.0, 0.0]],
        &[[0.5, 0.0]],
        &rule(BOUNDED),
        dt,
    );
    assert!((free[0][0] - (15.0 - dt * 9.0)).abs() < 1e-12, "{free:?}");
    let head_on = [[0.0, 0.0], [1.0, 0.0]];
    let v = interact(
        &head_on,
        &[[15.0, 0.0], [-15.0, 0.0]],
        &[[15.0, 0.0], [-15.0, 0.0]],
        &rule(BOUNDED),
        dt,
    );
    for (vi, ci) in v.iter().zip([15.0, 15.0]) {
        assert!(vi[0].hypot(vi[1]) >= ci - dt * 9.0 - 1e-12, "{v:?}");
    }
    // unbounded, the same guard stops them
    let v = interact(
        &head_on,
        &[[15.0, 0.0], [-15.0, 0.0]],
        &[[15.0, 0.0], [-15.0, 0.0]],
        &rule(IDM),
        dt,
    );
    assert!(
        v.iter().all(|vi| vi[0].hypot(vi[1]) < 15.0 - dt * 9.0),
        "{v:?}"
    );
}

#[test]
fn a_motion_record_carries_the_braking_bound_and_the_length() {
    let mut r = rec(&[2.0, 1.0, 1.0, 1.0, 2.0, 7.0, 1.5, 1.0, 2.0, 1.5, -1.0, 2.0]);
    let idm = |r: &[f64]| match Motion::from_slice(r).unwrap().rule {
        Rule::Vehicles { idm, .. } => idm,
        _ => unreachable!(),
    };
    // zeros: no bound, no length
    assert_eq!(idm(&r), IDM);
    r[17 + 3 * PROFILE_KNOTS] = 9.0;
    r[18 + 3 * PROFILE_KNOTS] = 4.5;
    r[19 + 3 * PROFILE_KNOTS] = 1.8;
    assert_eq!(idm(&r), BOUNDED);
    for (at, bad) in [
        (17, -1.0),
        (17, f64::NAN),
        (18, -1.0),
        (18, f64::INFINITY),
        (19, f64::NAN),
    ] {
        let mut b = r.clone();
        b[at + 3 * PROFILE_KNOTS] = bad;
        assert!(Motion::from_slice(&b).is_err(), "{at} {bad}");
    }
}

#[test]
fn a_vehicle_alongside_does_not_move_into_ones_side() {
    let rule = Rule::Vehicles {
        idm: BOUNDED,
        personal: 0.5,
    };
    let dt = 0.5;
    // j, 1 ahead and 3 to the left of i (their mean heading is x), drifts right at 2 while i
    // drifts left at 2: across they may close (3 - 1.8) / dt = 2.4 of their 4, so 1.6 is removed,
    // half from each, and after the step they are a width apart across
    let x = [[0.0, 0.0], [1.0, 3.0]];
    let vel = [[10.0, 2.0], [10.0, -2.0]];
    let v = interact(&x, &vel, &vel, &rule, dt);
    assert!(
        (v[0][0] - 10.0).abs() < 1e-12 && (v[0][1] - 1.2).abs() < 1e-12,
        "{v:?}"
    );
    assert!(
        (v[1][0] - 10.0).abs() < 1e-12 && (v[1][1] + 1.2).abs() < 1e-12,
        "{v:?}"
    );
    let after = (x[1][1] + dt * v[1][1]) - (x[0][1] + dt * v[0][1]);
    assert!((after - 1.8).abs() < 1e-12, "{after}");
    // the same in the other order
    let w = interact(
        &[x[1], x[0]],
        &[vel[1], vel[0]],
        &[vel[1], vel[0]],
        &rule,
        dt,
    );
    assert_eq!([w[1], w[0]], [v[0], v[1]]);
    // a length or more ahead it cuts in (the follower's car following answers it), and slowly
    // enough it drifts on; without the vehicles' size, no rule
    let ahead = [[0.0, 0.0], [4.6, 3.0]];
    assert_eq!(interact(&ahead, &vel, &vel, &rule, dt), vel);
    let slow = [[10.0, 1.0], [10.0, -1.0]];
    assert_eq!(interact(&x, &slow, &slow, &rule, dt), slow);
    let plain = Rule::Vehicles {
        idm: Idm {
            width: 0.0,
            ..BOUNDED
        },
        personal: 0.5,
    };
    assert_eq!(interact(&x, &vel, &vel, &plain, dt), vel);
}

#[test]
fn a_generated_vehicle_in_a_slow_field_starts_along_its_recorded_heading() {
    // a field too slow to have a heading (0.05 < min_speed 0.1), drawn east at 1 at the start:
    // a generated steering vehicle with a recorded heading north starts facing north, at the
    // drawn velocity's speed along it (0 here: it stands), and keeps facing north; without one
    // it starts along its drawn velocity (east)
    struct Slow(Option<Vec<f64>>);
    impl Field for Slow {
        fn velocity(&mut self, q: &[Point]) -> Result<Vec<[f64; 2]>> {
            Ok(vec![[0.05, 0.0]; q.len()])
        }
        fn step_start(&mut self, step: usize, q: &[Point]) -> Result<crate::simulate::StepInfo> {
            // the start's GP draw: east at 1
            let east = if step == 0 { [0.95, 0.0] } else { [0.0; 2] };
            Ok(crate::simulate::StepInfo {
                offset: vec![east; q.len()],
                low_data: vec![false; q.len()],
                deferred: false,
            })
        }
        fn recorded_headings(&self) -> Option<&[f64]> {
            self.0.as_deref()
        }
    }
    let motion = Motion {
        rule: Rule::Free,
        ..steering_vehicles(2.0)
    };
    let north = std::f64::consts::FRAC_PI_2;
    let run = |m: &Motion, recorded: Option<Vec<f64>>| {
        drive(
            &[[0.0, 0.0]],
            None,
            &opts(0.5, 4),
            m,
            None,
            &mut Slow(recorded),
        )
        .unwrap()
    };
    let r = run(&motion, Some(vec![north]));
    assert_eq!(r.drivers[0][0], north, "{:?}", r.drivers);
    // its heading at every time goes with the rollout (its zero velocity at the start has none)
    assert_eq!(r.headings, vec![north; 5]);
    // standing at the start, then relaxing toward the field's speed, always north
    assert!(r.velocities[0][1].abs() < 1e-12, "{:?}", r.velocities);
    assert!(
        r.velocities
            .iter()
            .all(|v| v[0].abs() < 1e-12 && v[1] >= 0.0),
        "{:?}",
        r.velocities
    );
    let r = run(&motion, None);
    assert_eq!(r.drivers[0][0], 0.0, "{:?}", r.drivers);
    assert!(r.velocities[0][0] > 0.9, "{:?}", r.velocities);
    assert_eq!(r.headings, vec![0.0; 5]);
    // a rollout without steering records none
    let plain = Motion {
        tau_heading: None,
        ..motion
    };
    assert!(run(&plain, None).headings.is_empty());
    // an unknown recorded heading (NaN) is none
    let r = run(&motion, Some(vec![f64::NAN]));
    assert_eq!(r.drivers[0][0], 0.0, "{:?}", r.drivers);
}

#[test]
fn at_a_crossing_the_vehicle_that_comes_second_yields() {
    let rule = |idm| Rule::Vehicles { idm, personal: 0.5 };
    let heads = [[1.0, 0.0], [0.0, 1.0]];
    let go = |x: [Point; 2], idm| {
        let vel = [[10.0, 0.0], [0.0, 10.0]];
        interact_headed(&x, &vel, &vel, Some(&heads), &[], &rule(idm), 0.5)
    };
    // i 20 west of the crossing heading east, j 15 south heading north, both at 10: clear of each
    // other's paths by half a length and half a width (3.15), j arrives at 1.185 s, i at 1.685 s,
    // before j has cleared (1.815 s) plus the margin: i brakes for a standing vehicle one jam
    // distance beyond the point where it stops clear (gap 20 - 3.15 + 7), j drives on
    let v = go([[-20.0, 0.0], [0.0, -15.0]], BOUNDED);
    let gap = Some((20.0 - 3.15 + 7.0, 0.0));
    let want = 10.0 + 0.5 * acc_accel(10.0, 10.0, gap, &BOUNDED);
    assert!(
        (v[0][0] - want).abs() < 1e-9 && want < 8.0,
        "{v:?} vs {want}"
    );
    assert_eq!(v[1], [0.0, 10.0]);
    // without the vehicles' size (rollouts of recorded frames), no such rule
    assert_eq!(
        go([[-20.0, 0.0], [0.0, -15.0]], IDM),
        [[10.0, 0.0], [0.0, 10.0]]
    );
    // i too close to stop clear within its braking bound (5 ahead: 1.85 of room, 5.6 needed)
    // goes on, and j, now second, yields
    let v = go([[-5.0, 0.0], [0.0, -15.0]], BOUNDED);
    assert_eq!(v[0], [10.0, 0.0]);
    assert!(v[1][1] < 9.0 && v[1][0] == 0.0, "{v:?}");
    // j already past the crossing, or far enough ahead to have cleared it: nobody yields
    for j in [[0.0, 5.0], [0.0, -3.5]] {
        let far = go([[-40.0, 0.0], j], BOUNDED);
        assert_eq!(far, [[10.0, 0.0], [0.0, 10.0]], "{j:?}");
    }
}
