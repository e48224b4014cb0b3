use super::*;
use crate::gp::LN_2PI;
use crate::test_util::{frames, refs, uniform};

/// The predictive density of `f` given `train` from a pattern factored from scratch.
fn fresh_predictive(p: GpParams, train: &[(usize, FrameRef)], f: FrameRef) -> f64 {
    Pattern::new(p, train).unwrap().score(&[f]).unwrap()[0]
}

#[test]
fn incremental_updates_match_fresh_factors() {
    for p in [
        GpParams::new((6.0, 30.0), (1.5, 1.5), (0.7, 0.7), (0.2, 20.0)).unwrap(),
        GpParams::new((6.0, 30.0), (1.5, 9.0), (0.7, 0.7), (0.2, 20.0)).unwrap(),
        // Equal signal, different noise: the outputs no longer share a factor.
        GpParams::new((6.0, 30.0), (1.5, 1.5), (0.7, 0.05), (0.2, 20.0)).unwrap(),
    ] {
        let fs = frames(3, 12);
        let r = refs(&fs);
        let members: Vec<(usize, FrameRef)> = (0..6).map(|i| (i, r[i])).collect();
        let mut pat = Pattern::new(p, &members).unwrap();
        for i in 6..12 {
            pat.insert(i, r[i]).unwrap();
        }
        for id in [0, 7, 3, 11] {
            assert!(pat.remove(id).unwrap());
        }
        let ids = pat.frames.clone();
        let fresh_members: Vec<(usize, FrameRef)> = ids.iter().map(|&i| (i, r[i])).collect();
        let fresh = Pattern::new(p, &fresh_members).unwrap();
        assert!(
            (pat.log_marginal() - fresh.log_marginal()).abs() < 1e-9 * fresh.log_marginal().abs()
        );
        // Scores of the removed frames equal the predictive density from scratch.
        let got = pat.score(&[r[0], r[7], r[11]]).unwrap();
        for (k, &i) in [0usize, 7, 11].iter().enumerate() {
            let want = fresh_predictive(p, &fresh_members, r[i]);
            assert!(
                (got[k] - want).abs() < 1e-9 * want.abs(),
                "{} vs {want}",
                got[k]
            );
        }
        // Leave-one-block-out of every member equals the predictive given the others.
        for &i in &ids {
            let others: Vec<(usize, FrameRef)> = ids
                .iter()
                .filter(|&&j| j != i)
                .map(|&j| (j, r[j]))
                .collect();
            let want = fresh_predictive(p, &others, r[i]);
            let got = pat.loo_score(i).unwrap().unwrap();
            assert!(
                (got - want).abs() < 1e-8 * want.abs(),
                "loo {i}: {got} vs {want}"
            );
        }
        assert!(pat.loo_score(0).unwrap().is_none());
        let q: Vec<Point> = vec![[3.0, 40.0], [20.0, 70.0], [29.0, 5.0]];
        let (pm, pv) = pat.posterior(&q);
        let (mean, cov) = pat.predict_joint(&q);
        let (gm, gv) = fresh.posterior(&q);
        for j in 0..3 {
            for d in 0..2 {
                assert!((mean[j][d] - gm[j][d]).abs() < 1e-9 * gm[j][d].abs().max(1.0));
                assert!((cov[d][j * 3 + j] - gv[j][d]).abs() < 1e-9);
                assert!((pm[j][d] - gm[j][d]).abs() < 1e-9 * gm[j][d].abs().max(1.0));
                assert!((pv[j][d] - gv[j][d]).abs() < 1e-9);
            }
        }
        let want = Pattern::new(p, &[(3, r[3])]).unwrap().log_marginal();
        assert!((prior_score(r[3], &p).unwrap() - want).abs() < 1e-10 * want.abs());
    }
}

fn data(n: usize, seed: u64) -> (Vec<Point>, Vec<[f64; 2]>) {
    let mut u = uniform(seed);
    let xy: Vec<Point> = (0..n).map(|_| [u() * 60.0, u() * 200.0]).collect();
    let v: Vec<[f64; 2]> = xy
        .iter()
        .map(|p| [(p[1] / 30.0).sin() + u(), 30.0 + p[0] / 10.0 + u()])
        .collect();
    (xy, v)
}

fn params(sx: f64, sy: f64) -> GpParams {
    GpParams::new((7.0, 25.0), (sx, sy), (0.8, 0.8), (0.3, 30.0)).unwrap()
}

#[test]
fn single_predictive_is_the_ratio_of_marginal_likelihoods() {
    let (xy, v) = data(140, 1);
    let unequal_noise = GpParams::new((7.0, 25.0), (2.0, 2.0), (0.8, 0.1), (0.3, 30.0)).unwrap();
    // 140 − 45 = 95 test points: past SMALL_MAX, so the faer path is checked too.
    for (p, cut) in [
        (params(2.0, 2.0), 100),
        (params(1.5, 9.0), 45),
        (unequal_noise, 45),
    ] {
        for par in [Par::Seq, Par::rayon(2)] {
            let all = Pattern::single(p, &xy, &v, par).unwrap().log_marginal();
            let train = Pattern::single(p, &xy[..cut], &v[..cut], par).unwrap();
            let test = FrameRef {
                xy: &xy[cut..],
                v: &v[cut..],
                h: &[],
            };
            let pred = train.score(&[test]).unwrap()[0];
            let (lm, pr) = (train.log_marginal(), pred);
            assert!((all - lm - pr).abs() < 1e-9 * all.abs(), "{all} {lm} {pr}");
        }
    }
}

#[test]
fn single_matches_the_sampler_pattern_and_ignores_the_thread_count() {
    let (xy, v) = data(50, 3);
    let p = params(1.5, 9.0);
    let member = Pattern::new(p, &[(0, FrameRef::new(&xy, &v))]).unwrap();
    let q: Vec<Point> = (0..1500)
        .map(|i| [i as f64 * 0.04, i as f64 * 0.13])
        .collect();
    let (m0, v0) = member.posterior(&q);
    for par in [Par::Seq, Par::rayon(2)] {
        let single = Pattern::single(p, &xy, &v, par).unwrap();
        assert!(
            (single.log_marginal() - member.log_marginal()).abs()
                < 1e-10 * member.log_marginal().abs()
        );
        let (m1, v1) = single.posterior(&q);
        for j in 0..q.len() {
            for d in 0..2 {
                assert!((m1[j][d] - m0[j][d]).abs() < 1e-9 * m0[j][d].abs().max(1.0));
                assert!((v1[j][d] - v0[j][d]).abs() < 1e-9);
            }
        }
    }
}

#[test]
fn single_point_marginal_is_a_normal_density() {
    let p = params(1.5, 9.0);
    let got = Pattern::single(p, &[[1.0, 2.0]], &[[1.0, 33.0]], Par::Seq)
        .unwrap()
        .log_marginal();
    let norm = |x: f64, m: f64, s2: f64| -0.5 * (LN_2PI + s2.ln() + (x - m) * (x - m) / s2);
    let want = norm(1.0, 0.3, 1.5 + 0.8) + norm(33.0, 30.0, 9.0 + 0.8);
    assert!((got - want).abs() < 1e-12);
}

#[test]
fn single_posterior_far_from_data_reverts_to_the_prior() {
    let (xy, v) = data(40, 2);
    let (m, s) = Pattern::single(params(1.5, 9.0), &xy, &v, Par::Seq)
        .unwrap()
        .posterior(&[[1e4, 1e4]]);
    assert!((m[0][0] - 0.3).abs() < 1e-12 && (m[0][1] - 30.0).abs() < 1e-12);
    assert!((s[0][0] - 1.5).abs() < 1e-12 && (s[0][1] - 9.0).abs() < 1e-12);
}

#[test]
fn single_bad_inputs_are_errors_not_panics() {
    let p = params(1.0, 1.0);
    assert!(matches!(
        Pattern::single(p, &[], &[], Par::Seq),
        Err(Error::Shape(_))
    ));
    assert!(matches!(
        Pattern::single(p, &[[0.0, 0.0]], &[], Par::Seq),
        Err(Error::Shape(_))
    ));
    assert!(matches!(
        Pattern::single(p, &[[f64::NAN, 0.0]], &[[0.0, 0.0]], Par::Seq),
        Err(Error::InvalidInput(_))
    ));
}
