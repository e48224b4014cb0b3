//! The sub-cluster sampler against enumeration: on the 5 small frames of the split–merge tests
//! (hsgp), the chain's partition frequencies match the posterior enumerated over all 52
//! partitions — with the hyperparameters fixed, with each pattern's noise sampled (integrated out
//! by quadrature), and with each pattern's length scales sampled (integrated out on a grid); a
//! ratio without the proposal term is detected; the chain is the same for any thread count.

use std::collections::HashMap;

use super::*;
use crate::frame::FrameRef;
use crate::gibbs::enumeration::{
    NOISE_PRIOR, canonical, enumerated, enumerated_by, enumerated_noise_integrated,
    headed_settings, three_scales_integrated, tiny, tiny_headed, tiny_hsgp, tiny_hsgp_headed,
    tiny_hsgp_headed_coarse, tiny_settings,
};
use crate::gibbs::{NoiseScope, PairChoice, SamplerKind, Settings};
use crate::special::ln_gamma_pdf;
use crate::special::log_sum_exp;
use crate::test_util::tv;

fn settings(seed: u64) -> Settings {
    let mut st = tiny_settings(tiny_hsgp(), seed);
    st.sampler = SamplerKind::Subcluster;
    st.split_merge.moves_per_sweep = 2;
    st
}

/// Partition frequencies of `sweeps` sweeps from all singletons, and the move counts.
fn chain(st: Settings, sweeps: usize) -> (HashMap<Vec<usize>, f64>, SplitMergeStats) {
    chain_on(tiny(), st, sweeps)
}

/// [`chain`] on other frames.
fn chain_on(
    data: Data,
    st: Settings,
    sweeps: usize,
) -> (HashMap<Vec<usize>, f64>, SplitMergeStats) {
    let data = Arc::new(data);
    let mut s = SubclusterSampler::new(data, st).unwrap();
    let ls = s.settings.base.length_scales;
    s.set_state(&[0, 1, 2, 3, 4], &[ls; 5], None, 1.0).unwrap();
    let mut counts: HashMap<Vec<usize>, f64> = HashMap::new();
    for _ in 0..sweeps {
        s.sweep(&|| false).unwrap();
        *counts.entry(canonical(s.labels())).or_default() += 1.0;
    }
    for c in counts.values_mut() {
        *c /= sweeps as f64;
    }
    (counts, s.split_merge)
}

/// The posterior with w, α and the noise fixed.
fn enumerated_fixed(st: &Settings) -> HashMap<Vec<usize>, f64> {
    let data = tiny();
    enumerated_by(data.len(), st.alpha.unwrap(), |members| {
        let m: Vec<(usize, FrameRef)> = members.iter().map(|&i| (i, data.frame(i))).collect();
        st.likelihood.pattern(st.base, &m).unwrap().log_marginal()
    })
}

#[test]
fn subcluster_chain_samples_the_enumerated_posterior() {
    for pairs in [PairChoice::Uniform, PairChoice::Informed] {
        let mut st = settings(1);
        st.split_merge.pairs = pairs;
        let exact = enumerated_fixed(&st);
        let (freq, stats) = chain(st, 40_000);
        let d = tv(&freq, &exact);
        eprintln!("{pairs:?}: TV {d:.4} ({stats:?})");
        assert!(d <= 0.03, "{pairs:?}: TV {d:.4} > 0.03 ({stats:?})");
        assert!(
            stats.split_accepted > 1000 && stats.merge_accepted > 1000,
            "{pairs:?}: {stats:?}"
        );
    }
}

/// A split ratio without its proposal probability (and a merge's without its reverse) is a
/// different chain, and the check sees it.
#[test]
fn a_ratio_without_the_proposal_term_is_detected() {
    let st = settings(2);
    let exact = enumerated_fixed(&st);
    let data = Arc::new(tiny());
    let mut s = SubclusterSampler::new(data, st).unwrap();
    s.wrong_ratio = true;
    let ls = s.settings.base.length_scales;
    s.set_state(&[0, 1, 2, 3, 4], &[ls; 5], None, 1.0).unwrap();
    let mut counts: HashMap<Vec<usize>, f64> = HashMap::new();
    let sweeps = 30_000;
    for _ in 0..sweeps {
        s.sweep(&|| false).unwrap();
        *counts.entry(canonical(s.labels())).or_default() += 1.0 / sweeps as f64;
    }
    let d = tv(&counts, &exact);
    eprintln!("without the proposal term: TV {d:.4}");
    assert!(d > 0.05, "TV {d:.4}: the wrong ratio went unseen");
}

/// The pass with peel and absorb moves alone (no split–merge) is ergodic and exact too; leaving the
/// affinity's reverse probability out of their ratio is detected.
#[test]
fn peel_and_absorb_moves_sample_the_enumerated_posterior() {
    let st = settings(8);
    let exact = enumerated_fixed(&st);
    for wrong in [false, true] {
        let mut s = SubclusterSampler::new(Arc::new(tiny()), st.clone()).unwrap();
        s.only_peel = true;
        s.wrong_ratio = wrong;
        let ls = s.settings.base.length_scales;
        s.set_state(&[0, 0, 0, 0, 0], &[ls], None, 1.0).unwrap();
        let sweeps = 60_000;
        let mut counts: HashMap<Vec<usize>, f64> = HashMap::new();
        for _ in 0..sweeps {
            s.sweep(&|| false).unwrap();
            *counts.entry(canonical(s.labels())).or_default() += 1.0 / sweeps as f64;
        }
        let d = tv(&counts, &exact);
        eprintln!(
            "peel and absorb, wrong ratio {wrong}: TV {d:.4} ({:?})",
            s.peels
        );
        if wrong {
            assert!(d > 0.05, "TV {d:.4}: the wrong ratio went unseen");
        } else {
            assert!(d <= 0.03, "TV {d:.4} > 0.03 ({:?})", s.peels);
            assert!(s.peels.peel_accepted > 1000 && s.peels.absorb_accepted > 1000);
        }
    }
}

#[test]
fn subcluster_chain_with_per_pattern_noise_samples_its_posterior() {
    let mut st = settings(3);
    st.noise_prior = Some(NOISE_PRIOR);
    st.noise_scope = NoiseScope::PerPattern;
    let exact = enumerated_noise_integrated(&tiny(), &st);
    let (freq, stats) = chain(st, 60_000);
    let d = tv(&freq, &exact);
    eprintln!("per-pattern noise: TV {d:.4} ({stats:?})");
    assert!(d <= 0.03, "TV {d:.4} > 0.03 ({stats:?})");
}

/// `log ∫∫ Gamma(w_x) Gamma(w_y) p(D | w) dw` of one pattern, on a grid of `log w`.
fn ls_integrated(data: &Data, st: &Settings, members: &[usize]) -> f64 {
    let m: Vec<(usize, FrameRef)> = members.iter().map(|&i| (i, data.frame(i))).collect();
    let (a, b) = st.length_scale_prior;
    let step = 0.05;
    let grid: Vec<f64> = (0..=120)
        .map(|t| (a * b).ln() - 3.0 + step * t as f64)
        .collect();
    let mut lp = Vec::with_capacity(grid.len() * grid.len());
    for &ux in &grid {
        for &uy in &grid {
            let (wx, wy) = (ux.exp(), uy.exp());
            let p = st.base.with_length_scales(LengthScales {
                wx,
                wy,
                wh: f64::INFINITY,
            });
            let lm = st.likelihood.pattern(p, &m).unwrap().log_marginal();
            lp.push(ln_gamma_pdf(wx, a, b) + ln_gamma_pdf(wy, a, b) + ux + uy + lm);
        }
    }
    log_sum_exp(&lp) + 2.0 * step.ln()
}

#[test]
fn subcluster_chain_with_sampled_length_scales_samples_its_posterior() {
    let mut st = settings(4);
    st.fixed_length_scales = false;
    let data = tiny();
    let exact = enumerated_by(data.len(), st.alpha.unwrap(), |members| {
        ls_integrated(&data, &st, members)
    });
    let (freq, stats) = chain(st, 60_000);
    let d = tv(&freq, &exact);
    eprintln!("sampled length scales: TV {d:.4} ({stats:?})");
    assert!(d <= 0.03, "TV {d:.4} > 0.03 ({stats:?})");
}

/// Fields over position and the previous heading (one vehicle's heading unknown), the
/// hyperparameters fixed: the partition posterior enumerated from the patterns' marginal
/// likelihoods, and far from the posterior over position alone (the check has power).
#[test]
fn subcluster_chain_over_heading_samples_the_enumerated_posterior() {
    let data = tiny_headed();
    let mut st = headed_settings(tiny_hsgp_headed(), 6);
    st.sampler = SamplerKind::Subcluster;
    st.split_merge.moves_per_sweep = 2;
    let exact = enumerated(&data, &st);
    let mut blind = st.clone();
    blind.base = st
        .base
        .with_length_scales(st.base.length_scales.with_heading(f64::INFINITY).unwrap());
    let (freq, stats) = chain_on(tiny_headed(), st, 30_000);
    let (d, other) = (tv(&freq, &exact), tv(&freq, &enumerated(&data, &blind)));
    eprintln!("over heading: TV {d:.4}; against position only {other:.4} ({stats:?})");
    assert!(d <= 0.03, "TV {d:.4} > 0.03 ({stats:?})");
    assert!(other > 0.05, "no power ({other:.4})");
}

/// The same with every pattern's `w_x`, `w_y` and `w_h` sampled: the posterior with the three
/// integrated out on a grid; the heading blocks on fewer position functions than the constant's.
#[test]
fn subcluster_chain_over_heading_with_sampled_length_scales_samples_its_posterior() {
    let data = tiny_headed();
    let mut st = headed_settings(tiny_hsgp_headed_coarse(), 8);
    st.sampler = SamplerKind::Subcluster;
    st.fixed_length_scales = false;
    st.length_scale_prior = (3.0, 1.2);
    st.split_merge.moves_per_sweep = 2;
    let exact = enumerated_by(data.len(), st.alpha.unwrap(), |members| {
        three_scales_integrated(&data, &st, members)
    });
    let fixed = enumerated(&data, &st);
    let (freq, stats) = chain_on(tiny_headed(), st, 30_000);
    let d = tv(&freq, &exact);
    let power = tv(&freq, &fixed);
    eprintln!("over heading, sampled w: TV {d:.4}; against fixed {power:.4} ({stats:?})");
    assert!(d <= 0.03, "TV {d:.4} > 0.03 ({stats:?})");
    assert!(power > 0.04, "no power ({power:.4})");
}

#[test]
fn subcluster_chain_is_the_same_whatever_the_thread_count() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut st = settings(5);
            st.fixed_length_scales = false;
            st.noise_prior = Some(NOISE_PRIOR);
            st.noise_scope = NoiseScope::PerPattern;
            st.alpha = None;
            let mut s = SubclusterSampler::new(Arc::new(tiny()), st).unwrap();
            s.initialize(Start::Sequential, &|| false).unwrap();
            let mut trace = Vec::new();
            for _ in 0..200 {
                let r = s.sweep(&|| false).unwrap();
                trace.push((
                    canonical(s.labels()),
                    r.log_joint.to_bits(),
                    r.alpha.to_bits(),
                ));
            }
            trace
        })
    };
    let one = run(1);
    assert_eq!(one, run(2));
    assert_eq!(one, run(4));
}

/// The pass never empties a pattern: from two patterns of one frame each and one of three, with
/// every frame preferring one place, the singletons stay until a move merges them.
#[test]
fn the_pass_keeps_every_pattern() {
    let mut st = settings(6);
    st.split_merge.moves_per_sweep = 0;
    let mut s = SubclusterSampler::new(Arc::new(tiny()), st).unwrap();
    let ls = s.settings.base.length_scales;
    s.set_state(&[0, 1, 2, 2, 2], &[ls; 3], None, 1.0).unwrap();
    for _ in 0..200 {
        s.sweep(&|| false).unwrap();
        assert_eq!(s.patterns().len(), 3);
    }
}

#[test]
fn starts_one_and_many() {
    assert_eq!(start_groups(Start::One, 4), vec![0; 4]);
    assert_eq!(start_groups(Start::Many, 4), vec![0, 1, 2, 3]);
    let g = start_groups(Start::Many, 10 * MANY_PATTERNS);
    assert_eq!(g.iter().max(), Some(&(MANY_PATTERNS - 1)));
    assert!(g.windows(2).all(|w| w[1] >= w[0]));
    let mut s = SubclusterSampler::new(Arc::new(tiny()), settings(7)).unwrap();
    s.initialize(Start::Many, &|| false).unwrap();
    assert_eq!(s.patterns().len(), 5);
}

#[test]
fn the_exact_likelihood_is_refused() {
    let mut st = tiny_settings(crate::pattern_model::Likelihood::Exact, 1);
    st.sampler = SamplerKind::Subcluster;
    let err = SubclusterSampler::new(Arc::new(tiny()), st).unwrap_err();
    assert!(err.to_string().contains("hsgp"), "{err}");
}

/// The coarsened start (`coalesce`), checked by states set afresh from the frames: from all
/// singletons it raises the log joint, its incremental sums give the log joint of the state set
/// from its labels, and no pair of its patterns merges (the larger side's hyperparameters kept)
/// to a higher log joint.
#[test]
fn the_coarsened_start_leaves_no_merge_that_raises_the_log_joint() {
    for alpha in [0.2, 0.7] {
        let mut st = settings(1);
        st.noise_scope = NoiseScope::PerPattern;
        st.noise_prior = Some(NOISE_PRIOR);
        let mut s = SubclusterSampler::new(Arc::new(tiny()), st).unwrap();
        let ls = s.settings.base.length_scales;
        s.set_state(&[0, 1, 2, 3, 4], &[ls; 5], None, alpha)
            .unwrap();
        let start = s.log_joint();
        s.coalesce(&|| false).unwrap();
        let after = s.log_joint();
        assert!(after > start, "{after} <= {start}");
        let infos = s.patterns();
        assert!(infos.len() < 5, "nothing merged from singletons");
        let slot: HashMap<usize, usize> =
            infos.iter().enumerate().map(|(g, p)| (p.slot, g)).collect();
        let labels: Vec<usize> = s.labels().iter().map(|l| slot[l]).collect();
        let lss: Vec<_> = infos.iter().map(|p| p.length_scales).collect();
        let noise: Vec<[f64; 2]> = infos.iter().map(|p| p.noise_var).collect();
        let mut fresh = SubclusterSampler::new(Arc::new(tiny()), s.settings.clone()).unwrap();
        fresh.set_state(&labels, &lss, Some(&noise), alpha).unwrap();
        assert!(
            (fresh.log_joint() - after).abs() < 1e-8 * after.abs(),
            "{} != {after}",
            fresh.log_joint()
        );
        for a in 0..infos.len() {
            for b in a + 1..infos.len() {
                let keep = if infos[b].n_frames > infos[a].n_frames {
                    b
                } else {
                    a
                };
                let merged: Vec<usize> =
                    labels.iter().map(|&g| if g == b { a } else { g }).collect();
                let (mut l2, mut n2) = (lss.clone(), noise.clone());
                l2[a] = lss[keep];
                n2[a] = noise[keep];
                fresh.set_state(&merged, &l2, Some(&n2), alpha).unwrap();
                assert!(
                    fresh.log_joint() <= after,
                    "merging {a} and {b} raises the log joint"
                );
            }
        }
    }
}

/// Fields over heading on the sub-cluster sampler start every pattern at the prior's mean
/// heading length scale (as the collapsed sampler does), and refuse frames without headings.
#[test]
fn patterns_over_heading_start_at_the_priors_mean_heading_scale() {
    let mut st = headed_settings(tiny_hsgp_headed(), 3);
    st.sampler = SamplerKind::Subcluster;
    st.base = st
        .base
        .with_length_scales(st.base.length_scales.with_heading(f64::INFINITY).unwrap());
    let (a, b) = st.heading_prior.unwrap();
    let mut s = SubclusterSampler::new(Arc::new(tiny_headed()), st.clone()).unwrap();
    s.initialize(Start::Sequential, &|| false).unwrap();
    for p in s.patterns() {
        assert_eq!(p.length_scales.wh, a * b);
    }
    let err = SubclusterSampler::new(Arc::new(tiny()), st).unwrap_err();
    assert!(err.to_string().contains("previous heading"), "{err}");
}
