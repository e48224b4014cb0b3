use std::sync::Arc;

use super::*;
use crate::basis::Basis;
use crate::frame::{FrameRef, LengthScales};
use crate::hsgp::HsgpPattern;
use crate::pattern::Pattern;
use crate::pattern_model::PatternModel;
use crate::test_util::{frames, headings, refs_with, uniform};

fn params(noise: f64) -> GpParams {
    let mut p = GpParams::new((6.0, 20.0), (1.5, 0.8), (noise, 0.3), (0.2, 20.0)).unwrap();
    p.length_scales = LengthScales::new(6.0, 20.0)
        .unwrap()
        .with_heading(0.8)
        .unwrap();
    p
}

/// The three ways a pattern holds its GP over position and heading, each with its kernel: the
/// exact one, the reduced-rank one on a dense factor, and the reduced-rank statistics.
fn patterns(
    p: GpParams,
    members: &[(usize, FrameRef<'_>)],
) -> Vec<(Box<dyn PatternModel>, Correlation)> {
    let basis = Arc::new(
        Basis::new([15.0, 50.0], [25.0, 70.0], [8, 12])
            .unwrap()
            .with_heading(2, [4, 6])
            .unwrap(),
    );
    let reduced = Correlation::Reduced(Arc::clone(&basis));
    vec![
        (
            Box::new(Pattern::new(p, members).unwrap()),
            Correlation::SquaredExp,
        ),
        (
            Box::new(Pattern::with_correlation(reduced.clone(), p, members).unwrap()),
            reduced.clone(),
        ),
        (
            Box::new(HsgpPattern::new(basis, p, members).unwrap()),
            reduced,
        ),
    ]
}

fn full_flags(pat: &dyn PatternModel, q: Inputs<'_>, f: f64) -> Vec<bool> {
    let s2 = pat.params().signal_var;
    let (_, var) = pat.posterior_at(q);
    var.iter()
        .map(|v| (0..2).any(|d| v[d] > f * s2[d]))
        .collect()
}

/// Conditioning on fewer observations never lowers a Gaussian posterior variance: the nearest
/// points' variance is at or above the full posterior's at every query, for every kernel; and
/// the flags equal the full solve's at every threshold, including thresholds at the queries'
/// own variances, where only the margin keeps the two computations from disagreeing.
#[test]
fn the_bound_is_above_the_posterior_variance_and_the_flags_are_the_full_solves() {
    let fs = frames(7, 60);
    let hs = headings(&fs, 6, |i, k| (0.7 * (i + k) as f64).sin() * 3.0);
    let refs = refs_with(&fs, &hs);
    let members: Vec<(usize, FrameRef)> = refs.iter().copied().enumerate().collect();
    let mut u = uniform(3);
    let mut qxy: Vec<Point> = (0..150)
        .map(|_| [u() * 50.0 - 10.0, u() * 140.0 - 20.0])
        .collect();
    qxy.push([-100.0, 0.0]); // outside the basis's box
    qxy.extend(fs[0].0.iter().copied()); // on training points
    let qh: Vec<f64> = (0..qxy.len())
        .map(|j| {
            if j % 7 == 0 {
                f64::NAN
            } else {
                u() * 6.0 - 3.0
            }
        })
        .collect();
    let q = Inputs { xy: &qxy, h: &qh };
    for noise in [0.7, 0.01] {
        let p = params(noise);
        for (pat, corr) in patterns(p, &members) {
            let (xy, _) = pat.points();
            let train = Inputs {
                xy,
                h: pat.headings(),
            };
            let model = Model {
                train,
                params: pat.params(),
                corr: &corr,
                groups: (p.groups().iter())
                    .map(|outs| {
                        let (s2, n) = p.group_vars(outs);
                        (*outs, s2, n)
                    })
                    .collect(),
            };
            let grid = PointGrid::new(xy);
            let (_, var) = pat.posterior_at(q);
            let (mut below, mut cand) = (0, Vec::new());
            for j in 0..q.len() {
                if corr.unsupported(qxy[j]) {
                    continue;
                }
                // none without training points in the rings around: the full solve decides
                let Some(bound) = bound_at(&model, &grid, qxy[j], qh[j], &mut cand) else {
                    continue;
                };
                for (g, b) in model.groups.iter().zip(&bound) {
                    for &d in g.0 {
                        let tol = 1e-9 * p.signal_var[d];
                        assert!(
                            *b >= var[j][d] - tol,
                            "query {j}: bound {b} < {}",
                            var[j][d]
                        );
                        below += usize::from(*b < 0.5 * p.signal_var[d]);
                    }
                }
            }
            assert!(below > 50, "the bound decided almost nothing ({below})");
            let s2 = p.signal_var;
            let mut thresholds = vec![0.0, 0.02, 0.2, 0.5, 0.9];
            thresholds.extend([3, 40, 152].map(|j| var[j][0] / s2[0]));
            for f in thresholds {
                let want = full_flags(&*pat, q, f);
                assert!(want.iter().any(|&x| x), "no flag at {f}");
                assert_eq!(pat.low_data_at(q, f), want, "threshold {f}");
            }
        }
    }
}

/// A grid over a single point, or none, still answers (its cells have positive size).
#[test]
fn a_degenerate_grid_still_finds_its_points() {
    let one = [[3.0, 4.0]];
    let g = PointGrid::new(&one);
    let mut out = Vec::new();
    g.candidates([3.0, 4.0], &mut out);
    assert_eq!(out, vec![0]);
    g.candidates([2.0, 5.0], &mut out); // beyond the extent: its nearest cell
    assert_eq!(out, vec![0]);
    let none = PointGrid::new(&[]);
    none.candidates([0.0, 0.0], &mut out);
    assert!(out.is_empty());
}
