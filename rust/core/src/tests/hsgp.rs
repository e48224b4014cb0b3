use super::*;
use crate::correlation::Correlation;
use crate::frame::Inputs;
use crate::frame::LengthScales;
use crate::kernel;
use crate::pattern::Pattern;
use crate::pattern_model::{PatternModel, ReducedPattern};
use crate::test_util::{frames, headings, refs, refs_with};

fn basis(m: [usize; 2]) -> Arc<Basis> {
    Arc::new(Basis::new([15.0, 50.0], [25.0, 70.0], m).unwrap())
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * (1.0 + a.abs().max(b.abs()))
}

fn params() -> [GpParams; 3] {
    [
        GpParams::new((6.0, 20.0), (1.5, 1.5), (0.7, 0.7), (0.2, 20.0)).unwrap(),
        GpParams::new((6.0, 20.0), (1.5, 9.0), (0.7, 0.7), (0.2, 20.0)).unwrap(),
        GpParams::new((6.0, 20.0), (1.5, 1.5), (0.7, 0.05), (0.2, 20.0)).unwrap(),
    ]
}

#[test]
fn reduced_correlation_approaches_the_squared_exponential() {
    // A box well beyond the data (the boundary distorts k̃ within a few length scales of it).
    let b = Arc::new(Basis::new([15.0, 50.0], [45.0, 110.0], [40, 96]).unwrap());
    let fs = frames(1, 4);
    let pts: Vec<Point> = fs.iter().flat_map(|f| f.0.iter().copied()).collect();
    let ls = LengthScales::new(6.0, 20.0).unwrap();
    let approx = b.correlation(Inputs::positions(&pts), Inputs::positions(&pts), ls, 1.0);
    let exact = kernel::cross(&pts, &pts, ls, 1.0, false);
    for (a, e) in approx.iter().zip(&exact) {
        assert!((a - e).abs() < 2e-3, "{a} vs {e}");
    }
}

#[test]
fn basis_statistics_match_the_dense_reduced_gp() {
    // The M x M statistics and the dense n x n factor of k̃ are two computations of one model.
    let b = basis([8, 12]);
    for p in params() {
        let fs = frames(5, 12);
        let r = refs(&fs);
        let members: Vec<(usize, FrameRef)> = (0..8).map(|i| (i, r[i])).collect();
        let stats = HsgpPattern::new(Arc::clone(&b), p, &members).unwrap();
        let dense =
            Pattern::with_correlation(Correlation::Reduced(Arc::clone(&b)), p, &members).unwrap();
        assert!(close(stats.log_marginal(), dense.log_marginal(), 1e-9));
        let s = HsgpPattern::score(&stats, &r[8..]).unwrap();
        let d = Pattern::score(&dense, &r[8..]).unwrap();
        for (a, e) in s.iter().zip(&d) {
            assert!(close(*a, *e, 1e-8), "{a} vs {e}");
        }
        for id in [0, 3, 7] {
            let a = HsgpPattern::loo_score(&stats, id).unwrap().unwrap();
            let e = Pattern::loo_score(&dense, id).unwrap().unwrap();
            assert!(close(a, e, 1e-8), "loo {a} vs {e}");
        }
        let q = [[3.0, 10.0], [20.0, 90.0], [-100.0, 0.0]];
        let (ms, vs) = HsgpPattern::posterior(&stats, &q);
        let (md, vd) = Pattern::posterior(&dense, &q);
        for j in 0..3 {
            for d in 0..2 {
                assert!(close(ms[j][d], md[j][d], 1e-8));
                assert!((vs[j][d] - vd[j][d]).abs() < 1e-8 * p.signal_var[d]);
            }
        }
        let (_, cs) = HsgpPattern::predict_joint(&stats, &q);
        let (_, cd) = Pattern::predict_joint(&dense, &q);
        for d in 0..2 {
            for (a, e) in cs[d].iter().zip(&cd[d]) {
                assert!((a - e).abs() < 1e-8 * p.signal_var[d]);
            }
        }
    }
}

#[test]
fn moves_match_fresh_statistics() {
    let b = basis([8, 12]);
    for p in params() {
        let fs = frames(9, 14);
        let r = refs(&fs);
        let members: Vec<(usize, FrameRef)> = (0..6).map(|i| (i, r[i])).collect();
        let mut pat = HsgpPattern::new(Arc::clone(&b), p, &members).unwrap();
        for i in 6..14 {
            pat.insert(i, r[i]).unwrap();
        }
        for id in [2, 9, 13, 0] {
            assert!(pat.remove(id).unwrap());
        }
        assert!(!pat.remove(2).unwrap());
        let kept: Vec<(usize, FrameRef)> = pat.frames().iter().map(|&i| (i, r[i])).collect();
        let fresh = HsgpPattern::new(Arc::clone(&b), p, &kept).unwrap();
        assert!(close(pat.log_marginal(), fresh.log_marginal(), 1e-9));
        let a = HsgpPattern::score(&pat, &r[2..3]).unwrap()[0];
        let e = HsgpPattern::score(&fresh, &r[2..3]).unwrap()[0];
        assert!(close(a, e, 1e-9));
        // Leave-one-out equals the score against the pattern without the frame.
        let id = pat.frames()[1];
        let mut rest = pat.clone();
        rest.remove(id).unwrap();
        let loo = HsgpPattern::loo_score(&pat, id).unwrap().unwrap();
        let direct = HsgpPattern::score(&rest, &r[id..id + 1]).unwrap()[0];
        assert!(close(loo, direct, 1e-9), "{loo} vs {direct}");
    }
}

#[test]
fn reduced_pattern_switches_representation_without_changing_densities() {
    // 16 basis functions: ten frames (at least 20 points) exceed them; one frame (at most 7
    // points, below 16 / 2) goes back to dense.
    let b = basis([4, 4]);
    let p = params()[1];
    let fs = frames(11, 10);
    let r = refs(&fs);
    let mut pat = ReducedPattern::new(Arc::clone(&b), p, &[(0, r[0])]).unwrap();
    assert!(matches!(pat, ReducedPattern::Dense(_)));
    for i in 1..10 {
        PatternModel::insert(&mut pat, i, r[i]).unwrap();
    }
    assert!(matches!(pat, ReducedPattern::Basis(_)));
    let members: Vec<(usize, FrameRef)> = (0..10).map(|i| (i, r[i])).collect();
    let dense =
        Pattern::with_correlation(Correlation::Reduced(Arc::clone(&b)), p, &members).unwrap();
    assert!(close(pat.log_marginal(), dense.log_marginal(), 1e-9));
    for i in 1..10 {
        PatternModel::remove(&mut pat, i).unwrap();
    }
    assert!(matches!(pat, ReducedPattern::Dense(_)));
    let single =
        Pattern::with_correlation(Correlation::Reduced(Arc::clone(&b)), p, &members[..1]).unwrap();
    assert!(close(pat.log_marginal(), single.log_marginal(), 1e-9));
}

#[test]
fn sizing_rule_covers_the_data_and_respects_the_cap() {
    let xy = [[0.0, 1350.0], [72.0, 1550.0]];
    let b = Basis::for_data(&xy, [5.0, 5.0], [10.0, 10.0], None).unwrap();
    assert_eq!(b.center(), [36.0, 1450.0]);
    assert!(b.half_widths()[0] >= 36.0 + 20.0 && b.half_widths()[1] >= 120.0);
    assert_eq!(b.counts(), [23, 48]);
    let tiny = Basis::for_data(&xy, [0.01, 0.01], [0.1, 0.1], None).unwrap();
    assert!(tiny.len() <= MAX_BASIS);
    assert!(Basis::for_data(&xy, [5.0, 5.0], [10.0, 10.0], Some([100, 100])).is_err());
    assert!(Basis::new([0.0, 0.0], [0.0, 1.0], [2, 2]).is_err());
}

#[test]
fn scoring_many_frames_in_blocks_equals_scoring_each_alone() {
    // More points than one block holds, so the blocks' edges are crossed.
    let b = basis([8, 12]);
    let fs = frames(9, 8 + SCORE_POINTS);
    let r = refs(&fs);
    let members: Vec<(usize, FrameRef)> = (0..8).map(|i| (i, r[i])).collect();
    let pat = HsgpPattern::new(Arc::clone(&b), params()[0], &members).unwrap();
    let rest = &r[8..];
    assert!(rest.iter().map(|f| f.xy.len()).sum::<usize>() > 2 * SCORE_POINTS);
    let all = pat.score(rest).unwrap();
    for (j, f) in rest.iter().enumerate().step_by(97) {
        let one = pat.score(std::slice::from_ref(f)).unwrap()[0];
        assert!(close(all[j], one, 1e-12), "frame {j}: {} vs {one}", all[j]);
    }
}

/// A basis whose heading blocks hold fewer position functions: its features are the full
/// product's at [`Basis::tensor_indices`], and its correlation is `Σ s φ φᵀ` of those features
/// (one kernel for the sums, the dense path and the prior score), which differs from the full
/// product's.
#[test]
fn coarse_heading_blocks_give_the_kernel_of_their_features() {
    let (c, h) = ([15.0, 50.0], [25.0, 70.0]);
    let full = Basis::new(c, h, [6, 8]).unwrap().with_harmonics(2).unwrap();
    let b = Basis::new(c, h, [6, 8])
        .unwrap()
        .with_heading(2, [3, 2])
        .unwrap();
    assert_eq!(b.len(), 48 + 4 * 6);
    let fs = frames(1, 9);
    let xy: Vec<Point> = fs.iter().flat_map(|f| f.0.iter().copied()).collect();
    let hd: Vec<f64> = (0..xy.len())
        .map(|i| {
            if i == 2 {
                f64::NAN
            } else {
                0.7 * i as f64 - 2.0
            }
        })
        .collect();
    let pts = Inputs { xy: &xy, h: &hd };
    let (ft, fb) = (full.features_of(pts), b.features_of(pts));
    let idx: Vec<usize> = b.tensor_indices().collect();
    for (cf, cb) in ft.chunks(full.len()).zip(fb.chunks(b.len())) {
        let picked: Vec<f64> = idx.iter().map(|&i| cf[i]).collect();
        assert_eq!(picked, cb);
    }
    let ls = LengthScales::new(6.0, 20.0)
        .unwrap()
        .with_heading(0.8)
        .unwrap();
    let s = b.sqrt_spectral(ls);
    let n = xy.len();
    let got = b.correlation(pts, pts, ls, 1.0);
    let dense = full.correlation(pts, pts, ls, 1.0);
    let mut differs = 0.0f64;
    for i in 0..n {
        for j in 0..n {
            let want: f64 = (0..b.len())
                .map(|f| s[f] * s[f] * fb[i * b.len() + f] * fb[j * b.len() + f])
                .sum();
            let g = got[j * n + i];
            assert!(
                (g - want).abs() < 1e-12 * (1.0 + want.abs()),
                "{g} vs {want}"
            );
            differs = differs.max((g - dense[j * n + i]).abs());
        }
    }
    assert!(
        differs > 1e-3,
        "the coarse blocks changed nothing ({differs})"
    );
}

/// A small reduced-rank pattern's posterior mean is taken in weight space (`φ(q)ᵀ w`, the
/// weights cached); it equals the function-space mean `σ² R(q, X) K⁻¹ (v − μ)` of its
/// correlations (what `posterior_at` computes), and the basis-statistics pattern's, over
/// heading with coarse heading blocks, and stays so after the points or hyperparameters change.
#[test]
fn dense_reduced_mean_in_weight_space_is_the_function_space_mean() {
    let b = Arc::new(
        Basis::new([15.0, 50.0], [25.0, 70.0], [6, 8])
            .unwrap()
            .with_heading(2, [3, 2])
            .unwrap(),
    );
    let mut p = params()[1];
    p.length_scales = p.length_scales.with_heading(0.8).unwrap();
    let fs = frames(3, 8);
    let hs = headings(&fs, 5, |i, k| 0.9 * (i + 2 * k) as f64 - 3.0);
    let r = refs_with(&fs, &hs);
    let members: Vec<(usize, FrameRef)> = (0..6).map(|i| (i, r[i])).collect();
    let q_xy = [[3.0, 10.0], [20.0, 90.0], [-100.0, 0.0], [12.0, 55.0]];
    let q_h = [0.3, f64::NAN, 2.0, -2.5];
    let q = Inputs { xy: &q_xy, h: &q_h };
    let check = |dense: &Pattern, stats: &HsgpPattern| {
        let w = dense.predict_mean_at(q);
        let (f, _) = dense.posterior_at(q);
        let s = stats.predict_mean_at(q);
        for j in 0..q_xy.len() {
            for d in 0..2 {
                assert!(close(w[j][d], f[j][d], 1e-10), "{} vs {}", w[j][d], f[j][d]);
                assert!(close(w[j][d], s[j][d], 1e-8), "{} vs {}", w[j][d], s[j][d]);
            }
        }
        // Outside the box the basis has no support: the prior mean.
        assert_eq!(w[2], dense.params.mean);
    };
    let corr = Correlation::Reduced(Arc::clone(&b));
    let mut dense = Pattern::with_correlation(corr.clone(), p, &members).unwrap();
    let mut stats = HsgpPattern::new(Arc::clone(&b), p, &members).unwrap();
    check(&dense, &stats);
    dense.insert(6, r[6]).unwrap();
    stats.insert(6, r[6]).unwrap();
    check(&dense, &stats);
    dense.remove(2).unwrap();
    stats.remove(2).unwrap();
    check(&dense, &stats);
    let mut p2 = p;
    p2.length_scales = LengthScales::new(4.0, 12.0)
        .unwrap()
        .with_heading(1.5)
        .unwrap();
    p2.signal_var = [2.0, 0.5];
    check(
        &dense.with_params(p2).unwrap(),
        &stats.with_params(p2).unwrap(),
    );
}
