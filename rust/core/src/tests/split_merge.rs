//! Split–merge moves alone (no frame-by-frame sweep) leave the posterior over partitions
//! invariant: on 5 small frames with w and α fixed, the chain's partition frequencies match
//! the posterior enumerated over all 52 partitions from the patterns' marginal likelihoods
//! (which tests/pattern.rs checks against the direct formulas). Every likelihood × pair choice.

use std::collections::HashMap;

use crate::frame::LengthScales;
use crate::test_util::tv;
use std::sync::Arc;

use super::*;
use crate::gibbs::{Assignment, Data, Proposal, Settings};
use crate::gp::GpParams;
use crate::hsgp::Basis;
use crate::pattern_model::Likelihood;

/// Five frames of 2-3 vehicles from two loosely different fields: a posterior spread over many
/// partitions.
pub(crate) fn tiny() -> Data {
    let mut u = crate::test_util::uniform(11u64);
    let (mut xy, mut v, mut offsets) = (Vec::new(), Vec::new(), vec![0]);
    for i in 0..5 {
        let shift = 1.5 * (i % 2) as f64;
        for _ in 0..(2 + i % 2) {
            xy.push([6.0 * u(), 6.0 * u()]);
            v.push([
                1.0 + shift + 2.0 * (u() - 0.5),
                -0.5 + 0.5 * shift + 2.0 * (u() - 0.5),
            ]);
        }
        offsets.push(xy.len());
    }
    Data::new(xy, v, offsets).unwrap()
}

pub(crate) fn tiny_settings(likelihood: Likelihood, seed: u64) -> Settings {
    Settings {
        assignment: Assignment::Gibbs,
        base: GpParams::new((3.0, 4.0), (1.0, 2.0), (1.0, 1.0), (1.0, 0.0)).unwrap(),
        fixed_length_scales: true,
        length_scale_prior: (10.0, 0.35),
        heading_prior: None,
        alpha: Some(1.0),
        new_pattern_samples: 1,
        length_scale_fraction: 1.0,
        pattern_moments: false,
        seed,
        likelihood,
        proposal: Proposal::Full,
        memory_budget: None,
        split_merge: SplitMerge {
            moves_per_sweep: 1,
            pairs: PairChoice::Uniform,
        },
        noise_prior: None,
        noise_scope: crate::gibbs::NoiseScope::Global,
        dynamics: None,
        sampler: crate::gibbs::SamplerKind::Collapsed,
    }
}

pub(crate) fn tiny_hsgp() -> Likelihood {
    Likelihood::Hsgp(Arc::new(
        Basis::new([3.0, 3.0], [6.0, 6.0], [3, 3]).unwrap(),
    ))
}

/// Canonical labels (first appearance order).
pub(crate) fn canonical(labels: &[usize]) -> Vec<usize> {
    let mut seen = HashMap::new();
    labels
        .iter()
        .map(|l| {
            let n = seen.len();
            *seen.entry(*l).or_insert(n)
        })
        .collect()
}

/// Every partition of `n` items as canonical labels.
pub(crate) fn partitions(n: usize) -> Vec<Vec<usize>> {
    fn grow(prefix: &mut Vec<usize>, k: usize, n: usize, out: &mut Vec<Vec<usize>>) {
        if prefix.len() == n {
            out.push(prefix.clone());
            return;
        }
        for c in 0..=k {
            prefix.push(c);
            grow(prefix, k.max(c + 1), n, out);
            prefix.pop();
        }
    }
    let mut out = Vec::new();
    grow(&mut Vec::new(), 0, n, &mut out);
    out
}

/// `log [α^K Π Γ(n_k) p(D_k | w)]` of every partition, normalised.
pub(crate) fn enumerated(data: &Data, st: &Settings) -> HashMap<Vec<usize>, f64> {
    enumerated_by(data.len(), st.alpha.unwrap(), |members| {
        let m: Vec<(usize, FrameRef)> = members.iter().map(|&i| (i, data.frame(i))).collect();
        st.likelihood.pattern(st.base, &m).unwrap().log_marginal()
    })
}

/// The posterior over every partition of `n` frames, normalised, with `log_pattern(members)` a
/// pattern's log marginal likelihood (hyperparameters fixed or integrated out; computed once
/// per subset): `∝ α^K Π Γ(n_k) exp(log_pattern(D_k))`.
pub(crate) fn enumerated_by(
    n: usize,
    alpha: f64,
    mut log_pattern: impl FnMut(&[usize]) -> f64,
) -> HashMap<Vec<usize>, f64> {
    let parts = partitions(n);
    let mut cache: HashMap<Vec<usize>, f64> = HashMap::new();
    let logw: Vec<f64> = parts
        .iter()
        .map(|z| {
            let k = z.iter().max().unwrap() + 1;
            (0..k)
                .map(|c| {
                    let members: Vec<usize> = (0..z.len()).filter(|&i| z[i] == c).collect();
                    let lm = match cache.get(&members) {
                        Some(&lm) => lm,
                        None => {
                            let lm = log_pattern(&members);
                            cache.insert(members.clone(), lm);
                            lm
                        }
                    };
                    alpha.ln() + ln_gamma(members.len() as f64) + lm
                })
                .sum()
        })
        .collect();
    let z = crate::special::log_sum_exp(&logw);
    parts
        .into_iter()
        .zip(logw)
        .map(|(p, w)| (p, (w - z).exp()))
        .collect()
}

/// Partition frequencies of a chain of `steps` split–merge moves alone, from all singletons.
fn split_merge_only(st: Settings, steps: usize) -> (HashMap<Vec<usize>, f64>, SplitMergeStats) {
    let data = tiny();
    let mut s = Sampler::new(data, st).unwrap();
    s.set_state(&[0, 1, 2, 3, 4], &[s.settings.base.length_scales; 5], 1.0)
        .unwrap();
    let mut counts: HashMap<Vec<usize>, f64> = HashMap::new();
    for m in 0..steps {
        let mut rng = stream(7, 0, Phase::SplitMerge, m as u64);
        s.split_merge_step(&mut rng).unwrap();
        *counts.entry(canonical(s.labels())).or_default() += 1.0;
    }
    for c in counts.values_mut() {
        *c /= steps as f64;
    }
    (counts, s.split_merge)
}

#[test]
fn split_merge_alone_samples_the_enumerated_posterior() {
    for likelihood in [Likelihood::Exact, tiny_hsgp()] {
        for pairs in [PairChoice::Uniform, PairChoice::Informed] {
            let mut st = tiny_settings(likelihood.clone(), 1);
            st.split_merge.pairs = pairs;
            let exact = enumerated(&tiny(), &st);
            let (freq, stats) = split_merge_only(st, 200_000);
            let d = tv(&freq, &exact);
            let name = format!("{} {pairs:?}", likelihood.name());
            assert!(d <= 0.03, "{name}: TV {d:.4} > 0.03 ({stats:?})");
            assert!(
                stats.split_accepted > 1000 && stats.merge_accepted > 1000,
                "{name}: {stats:?}"
            );
        }
    }
}

/// The check has power: the same chain's frequencies are far from the posterior of a
/// slightly different model (α = 2), so a ratio off by that much would fail it.
#[test]
fn the_check_detects_a_different_target() {
    let st = tiny_settings(Likelihood::Exact, 1);
    let mut other = st.clone();
    other.alpha = Some(2.0);
    let wrong = enumerated(&tiny(), &other);
    let (freq, _) = split_merge_only(st, 100_000);
    assert!(tv(&freq, &wrong) > 0.05, "TV {}", tv(&freq, &wrong));
}

#[test]
fn split_merge_chain_is_the_same_whatever_the_thread_count() {
    let run = |threads: usize, likelihood: Likelihood, proposal: Proposal| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut st = tiny_settings(likelihood, 5);
            st.fixed_length_scales = false;
            st.alpha = None;
            st.new_pattern_samples = 5;
            st.proposal = proposal;
            st.split_merge.moves_per_sweep = 3;
            st.split_merge.pairs = PairChoice::Informed;
            st.noise_prior = Some(crate::gibbs::NoisePrior {
                log_mean: 0.1f64.ln(),
                sd: 2.0,
            });
            let mut s = Sampler::new(tiny(), st).unwrap();
            let trace: Vec<f64> = (0..30)
                .map(|_| s.sweep(&|| false).unwrap().log_joint)
                .collect();
            (s.labels().to_vec(), trace, s.split_merge)
        })
    };
    for l in [Likelihood::Exact, tiny_hsgp()] {
        for p in [Proposal::Full, Proposal::Informed] {
            let (a, b) = (run(1, l.clone(), p), run(2, l.clone(), p));
            assert_eq!(a.0, b.0);
            assert_eq!(a.1, b.1);
            assert_eq!(a.2, b.2);
            assert!(a.2.split_proposed + a.2.merge_proposed == 90, "{:?}", a.2);
        }
    }
}

/// A split that is accepted leaves every pattern's cached factor equal to a fresh one, and the
/// labels consistent with the patterns' members.
#[test]
fn accepted_moves_leave_a_consistent_state() {
    let mut st = tiny_settings(Likelihood::Exact, 3);
    st.split_merge.moves_per_sweep = 20;
    let mut s = Sampler::new(tiny(), st).unwrap();
    for _ in 0..20 {
        s.sweep(&|| false).unwrap();
        for p in s.patterns() {
            let pat = s.pattern(p.slot).unwrap();
            for &f in pat.frames() {
                assert_eq!(s.labels()[f], p.slot);
            }
            let fresh = s
                .settings
                .likelihood
                .pattern(*pat.params(), &pat.members())
                .unwrap();
            assert!((fresh.log_marginal() - pat.log_marginal()).abs() < 1e-9);
        }
    }
    assert!(s.split_merge.split_accepted + s.split_merge.merge_accepted > 0);
}

/// `log ∫∫ Gamma(w_x) Gamma(w_y) p(D | w) dw` of one pattern holding `members`, on a grid of
/// `log w` (±4 around the prior mean's log, ~7 prior sds of a Gamma(3, ·)).
fn length_scales_integrated(data: &Data, st: &Settings, members: &[usize]) -> f64 {
    let m: Vec<(usize, FrameRef)> = members.iter().map(|&i| (i, data.frame(i))).collect();
    let (a, b) = st.length_scale_prior;
    let (centre, half, n) = ((a * b).ln(), 4.0, 160);
    let step = 2.0 * half / n as f64;
    let lp: Vec<f64> = (0..=n)
        .flat_map(|s| (0..=n).map(move |t| (s, t)))
        .map(|(s, t)| {
            let (ux, uy) = (
                centre - half + step * s as f64,
                centre - half + step * t as f64,
            );
            let (wx, wy) = (ux.exp(), uy.exp());
            let p = st.base.with_length_scales(LengthScales {
                wx,
                wy,
                wh: f64::INFINITY,
            });
            // the Gamma densities of w times w (the grid is on log w)
            let prior = crate::special::ln_gamma_pdf(wx, a, b)
                + crate::special::ln_gamma_pdf(wy, a, b)
                + ux
                + uy;
            prior + st.likelihood.pattern(p, &m).unwrap().log_marginal()
        })
        .collect();
    crate::special::log_sum_exp(&lp) + 2.0 * step.ln()
}

/// Gibbs + split–merge with every pattern's length scales sampled (split patterns drawing
/// theirs from the mixture of the prior and a log-normal around the split pattern's) samples
/// the partition posterior with each pattern's length scales integrated out; the same chain is
/// far from the posterior at fixed length scales, so the check has power.
#[test]
fn split_merge_with_sampled_length_scales_samples_the_enumerated_posterior() {
    let data = tiny();
    for likelihood in [Likelihood::Exact, tiny_hsgp()] {
        let mut st = tiny_settings(likelihood.clone(), 4);
        st.fixed_length_scales = false;
        // A wide prior, so that the length scales' uncertainty moves the partition posterior.
        st.length_scale_prior = (3.0, 1.2);
        st.split_merge.moves_per_sweep = 2;
        st.new_pattern_samples = 3;
        let exact = enumerated_by(data.len(), st.alpha.unwrap(), |members| {
            length_scales_integrated(&data, &st, members)
        });
        let mut s = Sampler::new(tiny(), st.clone()).unwrap();
        let sweeps = 40_000;
        let mut freq: HashMap<Vec<usize>, f64> = HashMap::new();
        for _ in 0..sweeps {
            s.sweep(&|| false).unwrap();
            *freq.entry(canonical(s.labels())).or_default() += 1.0 / sweeps as f64;
        }
        let d = tv(&freq, &exact);
        let fixed = tv(&freq, &enumerated(&data, &st));
        let name = likelihood.name();
        eprintln!(
            "{name}: sampled length scales TV {d:.4}; against fixed length scales {fixed:.4}; {:?}",
            s.split_merge
        );
        assert!(d <= 0.03, "{name}: TV {d:.4} > 0.03 ({:?})", s.split_merge);
        assert!(fixed > 0.04, "{name}: no power ({fixed:.4})");
        let sm = s.split_merge;
        assert!(
            sm.split_accepted > 1000 && sm.merge_accepted > 1000,
            "{name}: {sm:?}"
        );
    }
}

/// [`tiny`] with each vehicle's previous heading: the frames of the two fields head opposite
/// ways (one vehicle's heading unknown), so a field over heading tells them apart.
pub(crate) fn tiny_headed() -> Data {
    let d = tiny();
    let mut u = crate::test_util::uniform(12u64);
    let mut h = Vec::new();
    for i in 0..d.len() {
        for _ in d.frame(i).xy {
            h.push(std::f64::consts::PI * (i % 2) as f64 + 0.3 * (u() - 0.5));
        }
    }
    h[4] = f64::NAN;
    d.with_headings(h).unwrap()
}

pub(crate) fn tiny_hsgp_headed() -> Likelihood {
    Likelihood::Hsgp(Arc::new(
        Basis::new([3.0, 3.0], [6.0, 6.0], [3, 3])
            .unwrap()
            .with_harmonics(2)
            .unwrap(),
    ))
}

/// [`tiny_hsgp_headed`] with its heading blocks on the lowest 2 x 2 position functions.
pub(crate) fn tiny_hsgp_headed_coarse() -> Likelihood {
    Likelihood::Hsgp(Arc::new(
        Basis::new([3.0, 3.0], [6.0, 6.0], [3, 3])
            .unwrap()
            .with_heading(2, [2, 2])
            .unwrap(),
    ))
}

pub(crate) fn headed_settings(likelihood: Likelihood, seed: u64) -> Settings {
    let mut st = tiny_settings(likelihood, seed);
    st.heading_prior = Some((3.0, 0.4));
    st.base = st
        .base
        .with_length_scales(st.base.length_scales.with_heading(0.6).unwrap());
    st
}

fn chain_frequencies(data: Data, st: Settings, sweeps: usize) -> HashMap<Vec<usize>, f64> {
    let mut s = Sampler::new(data, st).unwrap();
    let mut freq: HashMap<Vec<usize>, f64> = HashMap::new();
    for _ in 0..sweeps {
        s.sweep(&|| false).unwrap();
        *freq.entry(canonical(s.labels())).or_default() += 1.0 / sweeps as f64;
    }
    freq
}

/// Gibbs + split–merge over fields of position and heading, hyperparameters fixed: the
/// partition posterior enumerated from the patterns' marginal likelihoods (product kernel), and
/// far from the posterior of the fields over position alone (the check has power).
#[test]
fn heading_fields_sample_the_enumerated_posterior() {
    let data = tiny_headed();
    for likelihood in [Likelihood::Exact, tiny_hsgp_headed()] {
        let st = headed_settings(likelihood.clone(), 6);
        let exact = enumerated(&data, &st);
        let mut blind = st.clone();
        blind.base = st
            .base
            .with_length_scales(st.base.length_scales.with_heading(f64::INFINITY).unwrap());
        let freq = chain_frequencies(tiny_headed(), st, 40_000);
        let (d, other) = (tv(&freq, &exact), tv(&freq, &enumerated(&data, &blind)));
        let name = likelihood.name();
        eprintln!("{name} over heading: TV {d:.4}; against position only {other:.4}");
        assert!(d <= 0.03, "{name}: TV {d:.4} > 0.03");
        assert!(other > 0.05, "{name}: no power ({other:.4})");
    }
}

/// `log ∫ Gamma(w_x) Gamma(w_y) Gamma(w_h) p(D | w) dw` of one pattern, on a grid of `log w`.
pub(crate) fn three_scales_integrated(data: &Data, st: &Settings, members: &[usize]) -> f64 {
    let m: Vec<(usize, FrameRef)> = members.iter().map(|&i| (i, data.frame(i))).collect();
    let priors = st.length_scale_priors();
    let (half, n) = (4.0, 36);
    let step = 2.0 * half / n as f64;
    let mut lp = Vec::with_capacity((n + 1) * (n + 1) * (n + 1));
    for s in 0..=n {
        for t in 0..=n {
            for r in 0..=n {
                let mut ls = st.base.length_scales;
                let mut prior = 0.0;
                for (i, k) in [s, t, r].into_iter().enumerate() {
                    let (a, b) = priors[i];
                    let u = (a * b).ln() - half + step * k as f64;
                    ls = ls.with_coord(i, u.exp());
                    prior += crate::special::ln_gamma_pdf(u.exp(), a, b) + u;
                }
                let p = st.base.with_length_scales(ls);
                lp.push(prior + st.likelihood.pattern(p, &m).unwrap().log_marginal());
            }
        }
    }
    crate::special::log_sum_exp(&lp) + 3.0 * step.ln()
}

/// The same with every pattern's length scales sampled, the heading's among them (and split
/// patterns drawing all three): the partition posterior with the three integrated out.
#[test]
fn heading_fields_with_sampled_length_scales_sample_the_enumerated_posterior() {
    let data = tiny_headed();
    for likelihood in [Likelihood::Exact, tiny_hsgp_headed()] {
        let mut st = headed_settings(likelihood.clone(), 8);
        st.fixed_length_scales = false;
        st.length_scale_prior = (3.0, 1.2);
        st.split_merge.moves_per_sweep = 2;
        st.new_pattern_samples = 3;
        let exact = enumerated_by(data.len(), st.alpha.unwrap(), |members| {
            three_scales_integrated(&data, &st, members)
        });
        let freq = chain_frequencies(tiny_headed(), st.clone(), 25_000);
        let d = tv(&freq, &exact);
        let fixed = tv(&freq, &enumerated(&data, &st));
        let name = likelihood.name();
        eprintln!("{name}: sampled w_x, w_y, w_h: TV {d:.4}; against fixed {fixed:.4}");
        assert!(d <= 0.03, "{name}: TV {d:.4} > 0.03");
        assert!(fixed > 0.04, "{name}: no power ({fixed:.4})");
    }
}
