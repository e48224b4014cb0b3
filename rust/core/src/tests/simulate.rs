use super::*;
use crate::frame::LengthScales;
use crate::gp::GpParams;
use crate::pattern::FrameRef;
use crate::pattern::Pattern;
use crate::pattern_model::PatternModel;

fn opts(dt: f64, steps: usize, method: Method) -> Options {
    Options {
        dt,
        steps,
        method,
        roi: Roi::everywhere(),
        max_curvature: None,
    }
}

fn rotation(q: &[Point]) -> Result<Vec<[f64; 2]>> {
    Ok(q.iter().map(|p| [-p[1], p[0]]).collect())
}

fn max_error(r: &Rollout, exact: impl Fn(f64, Point) -> Point, start: &[Point], dt: f64) -> f64 {
    let mut worst: f64 = 0.0;
    for t in 0..=r.steps {
        for (j, &s) in start.iter().enumerate() {
            let (p, e) = (r.positions[t * r.vehicles + j], exact(t as f64 * dt, s));
            worst = worst.max((p[0] - e[0]).hypot(p[1] - e[1]));
        }
    }
    worst
}

#[test]
fn constant_field_is_exact_for_both_methods() {
    let start = [[0.0, 0.0], [3.0, -2.0], [-1.5, 7.25]];
    for method in [Method::Euler, Method::Rk4] {
        let r = integrate(&start, &opts(0.1, 50, method), &mut |q: &[Point]| {
            Ok(vec![[2.0, -0.5]; q.len()])
        })
        .unwrap();
        let err = max_error(&r, |t, s| [s[0] + 2.0 * t, s[1] - 0.5 * t], &start, 0.1);
        assert!(err < 1e-12, "{method:?}: {err}");
        assert!(r.in_roi.iter().all(|&b| b) && r.velocities.iter().all(|v| *v == [2.0, -0.5]));
    }
}

/// Error at dt and dt/2, dt/4: the observed order log2(e(h)/e(h/2)).
fn orders(method: Method) -> Vec<f64> {
    let start = [[1.0, 0.0], [0.0, 2.0], [-0.5, -0.5]];
    let exact = |t: f64, s: Point| {
        [
            s[0] * t.cos() - s[1] * t.sin(),
            s[0] * t.sin() + s[1] * t.cos(),
        ]
    };
    let errs: Vec<f64> = [0.1f64, 0.05, 0.025, 0.0125]
        .iter()
        .map(|&dt| {
            let steps = (2.0 / dt).round() as usize; // to t = 2: a third of a turn
            let r = integrate(&start, &opts(dt, steps, method), &mut rotation).unwrap();
            max_error(&r, exact, &start, dt)
        })
        .collect();
    errs.windows(2).map(|w| (w[0] / w[1]).log2()).collect()
}

#[test]
fn euler_converges_at_first_order_and_rk4_at_fourth() {
    eprintln!(
        "observed orders: Euler {:?}, RK4 {:?}",
        orders(Method::Euler),
        orders(Method::Rk4)
    );
    for p in orders(Method::Euler) {
        assert!((p - 1.0).abs() < 0.1, "Euler order {p}");
    }
    for p in orders(Method::Rk4) {
        assert!((p - 4.0).abs() < 0.15, "RK4 order {p}");
    }
}

#[test]
fn rk4_is_accurate_on_a_full_turn() {
    let start = [[1.0, 0.0]];
    let steps = 200;
    let dt = std::f64::consts::TAU / steps as f64;
    let r = integrate(&start, &opts(dt, steps, Method::Rk4), &mut rotation).unwrap();
    let end = r.positions[steps];
    assert!(
        (end[0] - 1.0).abs() < 1e-7 && end[1].abs() < 1e-7,
        "{end:?}"
    );
}

#[test]
fn vehicles_stop_when_they_leave_the_roi() {
    let roi = Roi::new(-10.0, 10.0, -10.0, 10.0).unwrap();
    let o = Options {
        dt: 1.0,
        steps: 8,
        method: Method::Euler,
        roi,
        max_curvature: None,
    };
    let start = [[0.0, 0.0], [5.0, 0.0], [20.0, 0.0]];
    let r = integrate(&start, &o, &mut |q: &[Point]| Ok(vec![[2.0, 0.0]; q.len()])).unwrap();
    let row = |t: usize, j: usize| t * 3 + j;
    // Vehicle 1 is at x = 9 after 2 steps, 11 (outside) after 3, then stands still.
    assert!(r.in_roi[row(2, 1)] && !r.in_roi[row(3, 1)]);
    for t in 3..=8 {
        assert_eq!(r.positions[row(t, 1)], [11.0, 0.0]);
        assert_eq!(r.velocities[row(t, 1)], [0.0, 0.0]);
    }
    assert_eq!(r.velocities[row(2, 1)], [2.0, 0.0]);
    assert!(r.in_roi[row(5, 0)] && !r.in_roi[row(6, 0)] && r.positions[row(8, 0)] == [12.0, 0.0]);
    // Starting outside: never moves.
    assert!((0..=8).all(|t| !r.in_roi[row(t, 2)] && r.positions[row(t, 2)] == [20.0, 0.0]));
    assert_eq!(r.positions.len(), 27);
}

#[test]
fn bad_input_is_an_error() {
    let mut f = |q: &[Point]| Ok(vec![[1.0, 0.0]; q.len()]);
    assert!(integrate(&[[0.0, 0.0]], &opts(0.0, 3, Method::Euler), &mut f).is_err());
    assert!(integrate(&[[f64::NAN, 0.0]], &opts(0.1, 3, Method::Euler), &mut f).is_err());
    assert!(integrate(&[[0.0, 0.0]], &opts(0.1, usize::MAX, Method::Euler), &mut f).is_err());
    let mut short = |_: &[Point]| Ok(vec![]);
    assert!(matches!(
        integrate(&[[0.0, 0.0]], &opts(0.1, 3, Method::Euler), &mut short),
        Err(Error::Shape(_))
    ));
    assert!(Roi::new(1.0, 0.0, 0.0, 1.0).is_err());
    assert!(Method::parse("midpoint").is_err());
    assert_eq!(Method::parse("RK4").unwrap(), Method::Rk4);
    let empty = integrate(&[], &opts(0.1, 3, Method::Rk4), &mut f).unwrap();
    assert!(empty.positions.is_empty());
}

/// A pattern whose data all move at `c`, with prior mean `c`: its posterior mean is exactly
/// `c` everywhere, and its variance is small near the data and the prior's far away.
fn constant_pattern(c: [f64; 2]) -> Pattern {
    grid_pattern(c, [0.0, 0.0], c)
}

/// Data at `origin` + a 14 m × 8 m grid, all moving at `c`, under the prior mean `mean`.
fn grid_pattern(c: [f64; 2], origin: Point, mean: [f64; 2]) -> Pattern {
    let xy: Vec<Point> = (0..40)
        .map(|i| {
            [
                origin[0] + (i % 8) as f64 * 2.0,
                origin[1] + (i / 8) as f64 * 2.0,
            ]
        })
        .collect();
    let v = vec![c; xy.len()];
    let p = GpParams::new((3.0, 3.0), (4.0, 4.0), (0.05, 0.05), (mean[0], mean[1])).unwrap();
    let frames: Vec<(usize, FrameRef)> = (0..5)
        .map(|f| {
            (
                f,
                FrameRef {
                    xy: &xy[f * 8..f * 8 + 8],
                    v: &v[f * 8..f * 8 + 8],
                    h: &[],
                },
            )
        })
        .collect();
    Pattern::new(p, &frames).unwrap()
}

#[test]
fn pattern_rollout_follows_its_mean_and_flags_low_data() {
    let pat = constant_pattern([1.0, 0.5]);
    let start = [[2.0, 2.0], [100.0, 100.0]];
    let o = opts(0.5, 10, Method::Rk4);
    let r = rollout(&pat, &start, &o, None, Some(0.5)).unwrap();
    let err = max_error(&r, |t, s| [s[0] + t, s[1] + 0.5 * t], &start, 0.5);
    assert!(err < 1e-9, "{err}");
    assert!(!r.low_data[0], "inside the data");
    assert!(r.low_data[1], "far from the data");
    let none = rollout(&pat, &start, &o, None, None).unwrap();
    assert!(none.low_data.iter().all(|&b| !b) && none.positions == r.positions);
}

#[test]
fn stochastic_rollouts_are_seeded_draws_of_the_posterior() {
    let pat = constant_pattern([0.0, 0.0]);
    let o = opts(0.1, 400, Method::Euler);
    // Far from the data the posterior is the prior: independent N(0, 4) per output.
    let start = [[1e4, 1e4], [-1e4, 1e4]];
    let a = rollout(&pat, &start, &o, Some(7), None).unwrap();
    let b = rollout(&pat, &start, &o, Some(7), None).unwrap();
    let c = rollout(&pat, &start, &o, Some(8), None).unwrap();
    assert_eq!(a, b);
    assert_ne!(a.positions, c.positions);
    let vx: Vec<f64> = a.velocities.iter().map(|v| v[0]).collect();
    let n = vx.len() as f64;
    let mean = vx.iter().sum::<f64>() / n;
    let var = vx.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
    assert!(
        mean.abs() < 0.3 && (var - 4.0).abs() < 0.8,
        "mean {mean} var {var}"
    );
    // Near the data the draws hug the mean: the posterior variance is tiny.
    let near = rollout(
        &pat,
        &[[4.0, 4.0]],
        &opts(0.1, 1, Method::Euler),
        Some(7),
        None,
    )
    .unwrap();
    assert!(
        near.velocities[0][0].abs() < 0.5,
        "{:?}",
        near.velocities[0]
    );
    // Two vehicles at one spot: a singular covariance, handled by jitter.
    let same = rollout(
        &pat,
        &[[50.0, 50.0], [50.0, 50.0]],
        &opts(0.1, 3, Method::Rk4),
        Some(1),
        None,
    )
    .unwrap();
    assert!(same.positions.iter().all(|p| p[0].is_finite()));
}

/// Data at `origin` + a 14 m × 8 m grid, all moving at `c`, under a zero prior mean: the
/// posterior mean is `c` on the data and 0 far away.
fn local_pattern(c: [f64; 2], origin: Point) -> Pattern {
    grid_pattern(c, origin, [0.0, 0.0])
}

#[test]
fn a_mixture_of_one_pattern_is_that_pattern_with_support() {
    let pat = local_pattern([1.0, 0.5], [0.0, 0.0]);
    let q = [[4.0, 4.0], [20.0, 3.0], [500.0, 500.0]];
    let mut one = PatternField::new(&pat, None, None)
        .unwrap()
        .with_support(true);
    let mut mix = MixtureField::new(vec![(&pat, 3.0)]).unwrap();
    let (a, b) = (one.velocity(&q).unwrap(), mix.velocity(&q).unwrap());
    for j in 0..3 {
        for d in 0..2 {
            assert!((a[j][d] - b[j][d]).abs() < 1e-12, "{a:?} {b:?}");
        }
    }
    let (sa, sb) = (
        one.support(&q).unwrap().unwrap(),
        mix.support(&q).unwrap().unwrap(),
    );
    for j in 0..3 {
        assert!((sa[j] - sb[j]).abs() < 1e-12, "{sa:?} {sb:?}");
    }
    assert!(sa[0] > 0.9 && sa[2] < 1e-6);
}

#[test]
fn in_a_mixture_the_patterns_that_know_a_point_speak_for_it() {
    let east = local_pattern([1.0, 0.0], [0.0, 0.0]);
    let north = local_pattern([0.0, 2.0], [100.0, 0.0]);
    // east is the rare pattern, yet on its own data it is the field
    let mut mix = MixtureField::new(vec![(&east, 0.1), (&north, 0.9)]).unwrap();
    let q = [[6.0, 4.0], [106.0, 4.0], [55.0, 4.0], [1e4, 1e4]];
    let v = mix.velocity(&q).unwrap();
    let s = mix.support(&q).unwrap().unwrap();
    assert!(
        (v[0][0] - 1.0).abs() < 0.05 && v[0][1].abs() < 0.05,
        "{v:?}"
    );
    assert!(v[1][0].abs() < 0.05 && (v[1][1] - 2.0).abs() < 0.1, "{v:?}");
    assert!(s[0] > 0.9 && s[1] > 0.9, "{s:?}");
    // far from both: the prior's mean (zero) and no support
    assert!(v[3][0].abs() < 1e-9 && v[3][1].abs() < 1e-9 && s[3] < 1e-9);
    // anywhere: the formula, from each pattern's own posterior
    for (j, p) in q.iter().enumerate() {
        let (mut num, mut den, mut sq) = ([0.0; 2], 0.0, 0.0);
        for (pat, w) in [(&east, 0.1), (&north, 0.9)] {
            let (m, var) = pat.posterior(&[*p]);
            let sk = (0..2)
                .map(|d| 1.0 - var[0][d] / 4.0)
                .fold(1.0, f64::min)
                .clamp(0.0, 1.0);
            for d in 0..2 {
                num[d] += w * sk * m[0][d];
            }
            den += w * sk;
            sq += w * sk * sk;
        }
        if den > 1e-12 {
            for d in 0..2 {
                assert!((v[j][d] - num[d] / den).abs() < 1e-12, "point {j}");
            }
            assert!((s[j] - sq / den).abs() < 1e-12, "point {j}");
        }
    }
    assert!(MixtureField::new(vec![]).is_err());
    assert!(MixtureField::new(vec![(&east, f64::NAN)]).is_err());
    assert!(MixtureField::new(vec![(&east, 0.0)]).is_err());
}

/// A two-way road: the same positions driven east at 5 m/s (heading 0) and west (heading π),
/// under a field over heading of length scale `wh` (rad).
fn two_way_pattern(wh: f64) -> Pattern {
    let xy: Vec<Point> = (0..16)
        .map(|i| [(i % 8) as f64 * 2.0, (i / 8) as f64 * 2.0])
        .collect();
    let east = vec![[5.0, 0.0]; 16];
    let west = vec![[-5.0, 0.0]; 16];
    let (h_east, h_west) = (vec![0.0; 16], vec![std::f64::consts::PI; 16]);
    let ls = LengthScales::new(3.0, 3.0)
        .unwrap()
        .with_heading(wh)
        .unwrap();
    let p = GpParams::new((3.0, 3.0), (25.0, 25.0), (0.05, 0.05), (0.0, 0.0))
        .unwrap()
        .with_length_scales(ls);
    let frames = [
        (
            0,
            FrameRef {
                xy: &xy,
                v: &east,
                h: &h_east,
            },
        ),
        (
            1,
            FrameRef {
                xy: &xy,
                v: &west,
                h: &h_west,
            },
        ),
    ];
    Pattern::new(p, &frames).unwrap()
}

#[test]
fn a_field_over_heading_sends_each_vehicle_its_own_way() {
    let pat = two_way_pattern(0.5);
    assert!(PatternModel::headed(&pat));
    let start = [[4.0, 1.0], [6.0, 1.0], [8.0, 1.0]];
    let o = opts(0.1, 10, Method::Rk4);
    let h0 = vec![0.0, std::f64::consts::PI, f64::NAN];
    let mut field = PatternField::new(&pat, None, None)
        .unwrap()
        .with_headings(h0, 0.5);
    let r = integrate(&start, &o, &mut field).unwrap();
    for t in 0..=10 {
        let v = &r.velocities[t * 3..t * 3 + 3];
        assert!(
            (v[0][0] - 5.0).abs() < 0.5 && v[0][1].abs() < 0.1,
            "east: {v:?}"
        );
        assert!(
            (v[1][0] + 5.0).abs() < 0.5 && v[1][1].abs() < 0.1,
            "west: {v:?}"
        );
        // unknown heading: both ways averaged, standing (it never moves fast enough to get one)
        assert!(v[2][0].abs() < 0.1, "averaged: {v:?}");
    }
    // the same starts asked without headings: everyone sees the average
    let blind = rollout(&pat, &start, &o, None, None).unwrap();
    assert!(blind.velocities.iter().all(|v| v[0].abs() < 0.1));
    // a field over position ignores headings; the wrong number of them is an error
    let flat = constant_pattern([1.0, 0.5]);
    let mut f = PatternField::new(&flat, None, None)
        .unwrap()
        .with_headings(vec![0.0; 3], 0.5);
    assert!(f.start_headings().is_none());
    assert_eq!(
        integrate(&start, &o, &mut f).unwrap(),
        rollout(&flat, &start, &o, None, None).unwrap()
    );
    let mut short = PatternField::new(&pat, None, None)
        .unwrap()
        .with_headings(vec![0.0; 2], 0.5);
    assert!(matches!(
        integrate(&start, &o, &mut short),
        Err(Error::Shape(_))
    ));
}

#[test]
fn a_heading_track_keeps_the_last_heading_fast_enough_to_be_one() {
    let pat = two_way_pattern(0.5);
    let field = PatternField::new(&pat, None, None)
        .unwrap()
        .with_headings(vec![f64::NAN, 1.0], 0.5);
    let mut track = HeadingTrack::of(&field, 2).unwrap().unwrap();
    track.moved(0, [0.0, 2.0]);
    track.moved(1, [0.3, 0.0]); // slower than 0.5: no heading, the start's stays
    assert_eq!(track.h, vec![std::f64::consts::FRAC_PI_2, 1.0]);
    track.moved(0, [0.0, 0.0]);
    assert_eq!(track.h[0], std::f64::consts::FRAC_PI_2);
    let bad = PatternField::new(&pat, None, None)
        .unwrap()
        .with_headings(vec![f64::INFINITY, 0.0], 0.5);
    assert!(HeadingTrack::of(&bad, 2).is_err());
}

/// A field over heading that always answers `v` (the start headings as given).
struct Headed {
    v: [f64; 2],
    start: Vec<f64>,
}

impl Field for Headed {
    fn velocity(&mut self, q: &[Point]) -> Result<Vec<[f64; 2]>> {
        Ok(vec![self.v; q.len()])
    }
    fn start_headings(&self) -> Option<(&[f64], f64)> {
        Some((&self.start, 0.5))
    }
}

/// Under a turning limit a vehicle heading east in a field pointing back west stands; in a field
/// pointing north it turns by `κ |v| dt` a step at most, the heading it records each step, and
/// arrives at the field's direction; without the limit it follows the field at once.
#[test]
fn a_turning_limit_turns_vehicles_by_their_path_and_never_backward() {
    let mut o = opts(0.5, 20, Method::Euler);
    o.max_curvature = Some(0.2);
    let mut back = Headed {
        v: [-3.0, 0.1],
        start: vec![0.0],
    };
    let r = integrate(&[[0.0, 0.0]], &o, &mut back).unwrap();
    assert!(
        r.positions.iter().all(|p| p == &[0.0, 0.0]),
        "{:?}",
        &r.positions[..3]
    );
    let mut north = Headed {
        v: [0.0, 4.0],
        start: vec![0.0],
    };
    let r = integrate(&[[0.0, 0.0]], &o, &mut north).unwrap();
    let mut h = 0.0f64;
    for t in 0..20 {
        let v = r.velocities[t];
        let (now, speed) = (v[1].atan2(v[0]), v[0].hypot(v[1]));
        assert!(
            now - h <= 0.2 * 4.0 * 0.5 + 1e-12 && now >= h - 1e-12,
            "step {t}: {h} -> {now}"
        );
        assert!(speed <= 4.0 + 1e-12);
        h = now;
    }
    assert!((h - std::f64::consts::FRAC_PI_2).abs() < 1e-12, "{h}");
    o.max_curvature = None;
    let r = integrate(&[[0.0, 0.0]], &o, &mut north).unwrap();
    assert_eq!(r.velocities[0], [0.0, 4.0]);
}

#[test]
fn a_turning_limit_needs_headings_and_a_positive_curvature() {
    let mut o = opts(0.5, 2, Method::Euler);
    o.max_curvature = Some(0.2);
    let err = integrate(&[[0.0, 0.0]], &o, &mut |q: &[Point]| {
        Ok(vec![[1.0, 0.0]; q.len()])
    });
    assert!(matches!(err, Err(Error::InvalidInput(_))));
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        o.max_curvature = Some(bad);
        let mut f = Headed {
            v: [1.0, 0.0],
            start: vec![0.0],
        };
        assert!(matches!(
            integrate(&[[0.0, 0.0]], &o, &mut f),
            Err(Error::InvalidInput(_))
        ));
    }
}

/// A pattern's field that flags each step's vehicles when the step starts, by the definition (a
/// latent posterior variance above `f` of the prior's, by the full solve): the reference for the
/// flags [`PatternField`] puts off to the end of a rollout.
struct FlagsNow<'a>(PatternField<'a>);

impl Field for FlagsNow<'_> {
    fn velocity(&mut self, q: &[Point]) -> Result<Vec<[f64; 2]>> {
        self.0.velocity(q)
    }
    fn start_headings(&self) -> Option<(&[f64], f64)> {
        self.0.start_headings()
    }
    fn set_headings(&mut self, h: &[f64]) {
        self.0.set_headings(h)
    }
    fn step_start(&mut self, _: usize, q: &[Point]) -> Result<StepInfo> {
        let (f, s2) = (self.0.low_data.unwrap(), self.0.pattern.params().signal_var);
        let (_, var) = self.0.pattern.posterior_at(self.0.inputs(q));
        Ok(StepInfo {
            offset: vec![[0.0; 2]; q.len()],
            low_data: var
                .iter()
                .map(|v| crate::low_data::is_low(*v, s2, f))
                .collect(),
            deferred: false,
        })
    }
}

/// Flags put off to the end (one batched solve) are the flags of each step: over heading,
/// vehicles driving out of the data (east and west) and one of unknown heading, through the pure
/// field (both methods) and the interactive drivers, at several thresholds. Each case flags some
/// rows and not others (a rollout that never filled the late flags would fail).
#[test]
fn flags_put_off_to_the_end_are_each_steps_flags() {
    let pat = two_way_pattern(0.5);
    let start = [[4.0, 1.0], [10.0, 1.0], [8.0, 0.0], [2.0, 2.0]];
    let h0 = vec![0.0, std::f64::consts::PI, f64::NAN, 0.0];
    let field = |f: f64| {
        PatternField::new(&pat, None, Some(f))
            .unwrap()
            .with_headings(h0.clone(), 0.5)
    };
    let motion = crate::motion::Motion {
        tau: 1.0,
        sigma: [0.5, 0.5],
        spread: crate::motion::Spread::Components,
        rule: crate::motion::Rule::Free,
        profile: crate::motion::Profile::FLAT,
        tau_heading: None,
        heading_tolerance: 0.0,
        stand_speed: 0.0,
        jitter: [0.0; 2],
    };
    let v0 = [[5.0, 0.0], [-5.0, 0.0], [0.0, 0.0], [5.0, 0.0]];
    for f in [0.05, 0.5, 0.9] {
        for method in [Method::Euler, Method::Rk4] {
            let o = opts(0.5, 12, method);
            let late = integrate(&start, &o, &mut field(f)).unwrap();
            let now = integrate(&start, &o, &mut FlagsNow(field(f))).unwrap();
            assert_eq!(late, now, "f {f}, {method:?}");
            assert!(late.low_data.iter().any(|&b| b) && !late.low_data.iter().all(|&b| b));
        }
        let o = opts(0.5, 12, Method::Euler);
        let drive = |field: &mut dyn Field| {
            crate::motion::drive(&start, Some(&v0), &o, &motion, None, field).unwrap()
        };
        let late = drive(&mut field(f));
        assert_eq!(late, drive(&mut FlagsNow(field(f))), "f {f}, drivers");
        assert!(late.low_data.iter().any(|&b| b) && !late.low_data.iter().all(|&b| b));
    }
}
