use super::*;

const CAR: [f64; 2] = [4.0, 2.0];

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * (1.0 + b.abs())
}

#[test]
fn time_to_collision_by_hand() {
    let a = Rect::new([0.0, 0.0], 0.0, CAR);
    // head on: fronts 16 m apart closing at 10 m/s
    let b = Rect::new([20.0, 0.0], std::f64::consts::PI, CAR);
    assert!(close(
        time_to_collision(&a, [5.0, 0.0], &b, [-5.0, 0.0]),
        1.6
    ));
    // rear end: the follower 3 m/s faster, 16 m between them
    let lead = Rect::new([20.0, 0.0], 0.0, CAR);
    assert!(close(
        time_to_collision(&a, [13.0, 0.0], &lead, [10.0, 0.0]),
        16.0 / 3.0
    ));
    // moving apart, or side by side in the next lane at the same speed: never
    assert_eq!(
        time_to_collision(&a, [-5.0, 0.0], &lead, [5.0, 0.0]),
        f64::INFINITY
    );
    let beside = Rect::new([0.0, 3.5], 0.0, CAR);
    assert_eq!(
        time_to_collision(&a, [9.0, 0.0], &beside, [9.0, 0.0]),
        f64::INFINITY
    );
    // touching now: 0; overlapping: 0
    let touching = Rect::new([4.0, 0.0], 0.0, CAR);
    assert_eq!(time_to_collision(&a, [0.0; 2], &touching, [0.0; 2]), 0.0);
    assert_eq!(
        time_to_collision(&a, [1.0, 0.0], &Rect::new([1.0, 0.5], 0.3, CAR), [0.0; 2]),
        0.0
    );
    // crossing at right angles: b (heading north) must get its front to a's side (y = -1)
    // while a's rear has not passed b's far side
    let b = Rect::new([0.0, -11.0], std::f64::consts::FRAC_PI_2, CAR);
    assert!(close(
        time_to_collision(&a, [0.0; 2], &b, [0.0, 4.0]),
        (11.0 - 1.0 - 2.0) / 4.0
    ));
    // ... unless a has left: a at 10 m/s clears x = -1 (b's left side) after 0.3 s, b needs 2 s
    assert_eq!(
        time_to_collision(&a, [10.0, 0.0], &b, [0.0, 4.0]),
        f64::INFINITY
    );
}

#[test]
fn gap_by_hand() {
    let a = Rect::new([0.0, 0.0], 0.0, CAR);
    assert!(close(gap(&a, &Rect::new([10.0, 0.0], 0.0, CAR)), 6.0));
    // corner to corner: 3 m and 4 m apart along the axes
    assert!(close(gap(&a, &Rect::new([7.0, 6.0], 0.0, CAR)), 5.0));
    // a square turned 45°: its corner points at a's side, 1 m away
    let d = Rect::new(
        [0.0, 1.0 + 1.0 + 2f64.sqrt()],
        std::f64::consts::FRAC_PI_4,
        [2.0, 2.0],
    );
    assert!(close(gap(&a, &d), 1.0));
    assert_eq!(gap(&a, &Rect::new([3.0, 1.5], 1.0, CAR)), 0.0);
    // only the turned square's own axis separates them: its side faces a's corner (2, 1)
    let e = Rect::new([3.2, 2.2], std::f64::consts::FRAC_PI_4, [2.0, 2.0]);
    assert!(close(gap(&a, &e), 2.4 / 2f64.sqrt() - 1.0));
}

/// Two vehicles of length 4 m crossing at the origin: `a` east at 10 m/s from x = -50, `b`
/// north at 10 m/s from y = -80, with a third standing north of the crossing.
fn crossing_scene(steps: usize, dt: f64) -> (Vec<Point>, Vec<[f64; 2]>, Vec<bool>) {
    let (mut pos, mut vel, mut present) = (Vec::new(), Vec::new(), Vec::new());
    for t in 0..=steps {
        let s = t as f64 * dt;
        pos.extend([
            [-50.0 + 10.0 * s, 0.0],
            [0.0, -80.0 + 10.0 * s],
            [0.0, 30.0],
        ]);
        vel.extend([[10.0, 0.0], [0.0, 10.0], [0.0, 0.0]]);
        present.extend([true, true, t >= 10]);
    }
    (pos, vel, present)
}

#[test]
fn scene_measures_by_hand() {
    let (dt, steps) = (0.1, 100);
    let (pos, vel, present) = crossing_scene(steps, dt);
    let sizes = [CAR; 3];
    let scene = Scene {
        vehicles: 3,
        positions: &pos,
        velocities: &vel,
        present: &present,
        sizes: &sizes,
        dt,
        min_speed: 0.5,
        headings: None,
    };
    let m = scene.measures().unwrap();
    assert_eq!(m.pairs.len(), 3);
    let ab = m.pairs[0];
    assert_eq!((ab.a, ab.b), (0, 1));
    // a's rear leaves the crossing at 5.2 s (centre at x = 2), b's front reaches it at 7.8 s
    assert!(close(ab.pet, 2.6), "{}", ab.pet);
    assert!(!ab.collision && ab.ttc == f64::INFINITY);
    // least gap: the least over the times of the rectangles' distance
    let brute = (0..=steps)
        .map(|t| {
            gap(
                &Rect::new(pos[3 * t], 0.0, CAR),
                &Rect::new(pos[3 * t + 1], std::f64::consts::FRAC_PI_2, CAR),
            )
        })
        .fold(f64::INFINITY, f64::min);
    assert!(close(ab.gap, brute));
    // b drives north toward the standing vehicle (heading +x: it never moved): its front (2 m
    // ahead of its centre) would meet the standing one's near side (y = 29) when its centre is
    // at 27, at 10.7 s; at the last time, 10 s, that is 0.7 s ahead
    let bc = m.pairs[2];
    assert_eq!((bc.a, bc.b), (1, 2));
    assert!((bc.ttc - 0.7).abs() < 1e-9, "{}", bc.ttc);
    assert!(!bc.collision && bc.pet == f64::INFINITY);
    assert_eq!(m.deceleration, vec![0.0; 3]);
}

#[test]
fn a_collision_and_the_hardest_deceleration() {
    // a brakes from 10 to 4 m/s in 0.5 s steps (the hardest: 8 m/s to 4 m/s, 8 m/s²) and b
    // stands 12 m ahead: a's front (x = 2) reaches b's rear (x = 10) while it brakes
    let speeds = [10.0, 9.0, 8.0, 4.0, 4.0, 4.0];
    let (mut pos, mut vel, mut x) = (Vec::new(), Vec::new(), 0.0);
    for s in speeds {
        pos.extend([[x, 0.0], [12.0, 0.0]]);
        vel.extend([[s, 0.0], [0.0, 0.0]]);
        x += 0.5 * s;
    }
    let present = vec![true; 12];
    let scene = Scene {
        vehicles: 2,
        positions: &pos,
        velocities: &vel,
        present: &present,
        sizes: &[CAR, CAR],
        dt: 0.5,
        min_speed: 0.5,
        headings: None,
    };
    let m = scene.measures().unwrap();
    assert_eq!(m.deceleration, vec![8.0, 0.0]);
    let p = m.pairs[0];
    // positions 0, 5, 9.5, 13.5: at 9.5 the fronts overlap (11.5 > 10): a collision
    assert!(p.collision && p.ttc == 0.0 && p.gap == 0.0);
}

#[test]
fn headings_hold_while_standing_and_bad_scenes_are_errors() {
    // still, then north, then still: the first heading is the later one, then it holds
    let pos = vec![[0.0, 0.0]; 4];
    let vel = [[0.0, 0.0], [0.0, 3.0], [0.1, 0.0], [0.0, 0.0]];
    let present = [true; 4];
    let sizes = [CAR];
    let scene = Scene {
        vehicles: 1,
        positions: &pos,
        velocities: &vel,
        present: &present,
        sizes: &sizes,
        dt: 1.0,
        min_speed: 0.5,
        headings: None,
    };
    assert_eq!(scene.headings(0), vec![std::f64::consts::FRAC_PI_2; 4]);
    let still = [[0.0; 2]; 4];
    assert_eq!(
        Scene {
            velocities: &still,
            ..scene
        }
        .headings(0),
        vec![0.0; 4]
    );
    assert!(matches!(
        Scene {
            sizes: &[],
            ..scene
        }
        .measures(),
        Err(Error::Shape(_))
    ));
    assert!(Scene { dt: 0.0, ..scene }.measures().is_err());
    assert!(
        Scene {
            min_speed: f64::NAN,
            ..scene
        }
        .measures()
        .is_err()
    );
    assert!(
        Scene {
            sizes: &[[4.0, -1.0]],
            ..scene
        }
        .measures()
        .is_err()
    );
    let nan = [[f64::NAN, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]];
    assert!(
        Scene {
            positions: &nan,
            ..scene
        }
        .measures()
        .is_err()
    );
    // a NaN where the vehicle is absent is no error
    let absent = [false, true, true, true];
    assert!(
        Scene {
            positions: &nan,
            present: &absent,
            ..scene
        }
        .measures()
        .is_ok()
    );
    let empty = Scene {
        vehicles: 0,
        positions: &[],
        velocities: &[],
        present: &[],
        sizes: &[],
        ..scene
    };
    assert_eq!(
        empty.measures().unwrap(),
        Measures {
            pairs: vec![],
            deceleration: vec![]
        }
    );
}

#[test]
fn a_standing_vehicle_faces_its_recorded_heading() {
    use std::f64::consts::FRAC_PI_2;
    // two cars standing side by side in lanes along y, 3 apart (wider than a car): facing +x,
    // the default of a vehicle that never moves, their 4-long boxes overlap; facing their
    // recorded heading (north), they do not
    let pos = vec![[0.0, 0.0], [3.0, 0.0], [0.0, 0.0], [3.0, 0.0]];
    let vel = vec![[0.0, 0.0]; 4];
    let present = [true; 4];
    let sizes = [CAR, CAR];
    let north = [FRAC_PI_2; 4];
    let scene = Scene {
        vehicles: 2,
        positions: &pos,
        velocities: &vel,
        present: &present,
        sizes: &sizes,
        dt: 0.5,
        min_speed: 0.5,
        headings: None,
    };
    assert!(scene.measures().unwrap().pairs[0].collision);
    let recorded = Scene {
        headings: Some(&north),
        ..scene
    };
    assert_eq!(recorded.headings(0), vec![FRAC_PI_2; 2]);
    let p = recorded.measures().unwrap().pairs[0];
    assert!(!p.collision && close(p.gap, 1.0), "{p:?}");
    // a moving vehicle's own velocity wins; NaN is not known (the velocity's, held); a recorded
    // heading per row or none
    let moving = vec![[0.0, 0.0], [3.0, 0.0], [1.0, 0.0], [3.0, 0.0]];
    let east = vec![[1.0, 0.0], [0.0, 0.0], [1.0, 0.0], [0.0, 0.0]];
    let some = [f64::NAN, FRAC_PI_2, f64::NAN, FRAC_PI_2];
    let s = Scene {
        positions: &moving,
        velocities: &east,
        headings: Some(&some),
        ..scene
    };
    assert_eq!(s.headings(0), vec![0.0; 2]);
    assert_eq!(s.headings(1), vec![FRAC_PI_2; 2]);
    for bad in [&north[..3], &[0.0, 0.0, f64::INFINITY, 0.0][..]] {
        assert!(
            Scene {
                headings: Some(bad),
                ..scene
            }
            .measures()
            .is_err()
        );
    }
}
