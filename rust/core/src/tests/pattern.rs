use super::*;
use crate::gp;
use crate::test_util::{frames, refs};

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
        let (xy, v) = fresh.points();
        let got = pat.score(&[r[0], r[7], r[11]]).unwrap();
        for (k, &i) in [0usize, 7, 11].iter().enumerate() {
            let want = gp::log_predictive(xy, v, r[i].xy, r[i].v, &p, Par::Seq).unwrap();
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
            let rest = Pattern::new(p, &others).unwrap();
            let (oxy, ov) = rest.points();
            let want = gp::log_predictive(oxy, ov, r[i].xy, r[i].v, &p, Par::Seq).unwrap();
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
        let (gm, gv) = gp::posterior(xy, v, &q, &p, Par::Seq).unwrap();
        for j in 0..3 {
            for d in 0..2 {
                assert!((mean[j][d] - gm[j][d]).abs() < 1e-9 * gm[j][d].abs().max(1.0));
                assert!((cov[d][j * 3 + j] - gv[j][d]).abs() < 1e-9);
                assert!((pm[j][d] - gm[j][d]).abs() < 1e-9 * gm[j][d].abs().max(1.0));
                assert!((pv[j][d] - gv[j][d]).abs() < 1e-9);
            }
        }
        let want = gp::log_marginal_likelihood(r[3].xy, r[3].v, &p, Par::Seq).unwrap();
        assert!((prior_score(r[3], &p).unwrap() - want).abs() < 1e-10 * want.abs());
    }
}
