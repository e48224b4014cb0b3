//! The noise step: with the partition held, its draws follow the noise's posterior (checked
//! against quadrature of the prior times the marginal likelihood on a grid); the chain is the
//! same in other units, and whatever the thread count.

use super::*;
use crate::gibbs::split_merge::tests::{tiny, tiny_hsgp, tiny_settings};
use crate::gibbs::{Data, Settings};
use crate::pattern::FrameRef;
use crate::pattern_model::Likelihood;
use std::collections::HashMap;

pub(crate) const PRIOR: NoisePrior = NoisePrior {
    log_mean: -std::f64::consts::LN_10, // ln 0.1
    sd: 2.0,
};

fn noise_settings(likelihood: Likelihood, seed: u64) -> Settings {
    let mut st = tiny_settings(likelihood, seed);
    st.noise_prior = Some(PRIOR);
    st.split_merge.moves_per_sweep = 0;
    st
}

/// Mean and sd of `log σ_n,d²` under `prior × p(D | σ²)` for one pattern holding `labels`' groups,
/// by quadrature on a fine grid (the other component held at its starting value).
fn quadrature(data: &Data, st: &Settings, groups: &[Vec<usize>], d: usize) -> (f64, f64) {
    let xs: Vec<f64> = (0..4000)
        .map(|t| -14.0 + 20.0 * t as f64 / 4000.0)
        .collect();
    let lp: Vec<f64> = xs
        .iter()
        .map(|&x| {
            let mut base = st.base;
            base.noise_var[d] = x.exp();
            let lm: f64 = groups
                .iter()
                .map(|g| {
                    let m: Vec<(usize, FrameRef)> = g.iter().map(|&i| (i, data.frame(i))).collect();
                    st.likelihood.pattern(base, &m).unwrap().log_marginal()
                })
                .sum();
            PRIOR.log_density(x, st.base.signal_var[d]) + lm
        })
        .collect();
    let z = crate::special::log_sum_exp(&lp);
    let w: Vec<f64> = lp.iter().map(|l| (l - z).exp()).collect();
    let mean: f64 = xs.iter().zip(&w).map(|(x, w)| x * w).sum();
    let var: f64 = xs.iter().zip(&w).map(|(x, w)| (x - mean).powi(2) * w).sum();
    (mean, var.sqrt())
}

#[test]
fn noise_draws_follow_the_posterior_given_the_partition() {
    for likelihood in [Likelihood::Exact, tiny_hsgp()] {
        let st = noise_settings(likelihood.clone(), 2);
        let data = tiny();
        let labels = [0, 1, 0, 1, 1];
        let groups = vec![vec![0, 2], vec![1, 3, 4]];
        let mut s = Sampler::new(tiny(), st.clone()).unwrap();
        let ls = st.base.length_scales;
        s.set_state(&labels, &[ls, ls], 1.0).unwrap();
        let n = 20_000;
        let mut draws = [Vec::with_capacity(n), Vec::with_capacity(n)];
        for t in 0..n {
            s.sweep = t as u64;
            s.update_noise().unwrap();
            for (d, row) in draws.iter_mut().enumerate() {
                row.push(s.settings.base.noise_var[d].ln());
            }
        }
        for d in 0..2 {
            // The marginal of one component does not depend on the other's value: the two
            // outputs are independent GPs given the partition and length scales.
            let (m, sd) = quadrature(&data, &st, &groups, d);
            let got_m = draws[d].iter().sum::<f64>() / n as f64;
            let got_sd =
                (draws[d].iter().map(|x| (x - got_m).powi(2)).sum::<f64>() / n as f64).sqrt();
            // Slice draws are nearly independent here; 0.05 sd is ~7 standard errors.
            assert!(
                (got_m - m).abs() < 0.05 * sd + 1e-3,
                "{} d={d}: mean {got_m} vs {m} (sd {sd})",
                likelihood.name()
            );
            assert!(
                (got_sd / sd - 1.0).abs() < 0.05,
                "{} d={d}: sd {got_sd} vs {sd}",
                likelihood.name()
            );
        }
    }
}

/// The same chain in other units: positions and velocities times c, every setting scaled with
/// them (the noise prior is relative to the velocity variance, so it scales itself).
#[test]
fn sampled_noise_is_unit_free() {
    let c = 3.280_839_895; // feet per metre
    let run = |scale: f64| {
        let d = tiny();
        let n = d.len();
        let (mut xy, mut v, mut off) = (Vec::new(), Vec::new(), vec![0]);
        for i in 0..n {
            let f = d.frame(i);
            xy.extend(f.xy.iter().map(|p| [p[0] * scale, p[1] * scale]));
            v.extend(f.v.iter().map(|p| [p[0] * scale, p[1] * scale]));
            off.push(xy.len());
        }
        let mut st = noise_settings(Likelihood::Exact, 4);
        st.fixed_length_scales = false;
        st.alpha = None;
        st.new_pattern_samples = 5;
        st.split_merge.moves_per_sweep = 2;
        let b = st.base;
        st.base = GpParams::new(
            (b.length_scales.wx * scale, b.length_scales.wy * scale),
            (
                b.signal_var[0] * scale * scale,
                b.signal_var[1] * scale * scale,
            ),
            (
                b.noise_var[0] * scale * scale,
                b.noise_var[1] * scale * scale,
            ),
            (b.mean[0] * scale, b.mean[1] * scale),
        )
        .unwrap();
        st.length_scale_prior.1 *= scale;
        let mut s = Sampler::new(Data::new(xy, v, off).unwrap(), st).unwrap();
        let mut out = Vec::new();
        for _ in 0..15 {
            s.sweep(&|| false).unwrap();
            let nv = s.settings.base.noise_var;
            out.push((
                crate::gibbs::split_merge::tests::canonical(s.labels()),
                [nv[0] / (scale * scale), nv[1] / (scale * scale)],
            ));
        }
        out
    };
    let (m, f) = (run(1.0), run(c));
    for (t, (a, b)) in m.iter().zip(&f).enumerate() {
        assert_eq!(a.0, b.0, "sweep {t}");
        for d in 0..2 {
            assert!(
                (a.1[d] / b.1[d] - 1.0).abs() < 1e-6,
                "sweep {t}: {:?} vs {:?}",
                a.1,
                b.1
            );
        }
    }
}

#[test]
fn bad_noise_prior_is_an_error() {
    let mut st = noise_settings(Likelihood::Exact, 1);
    st.noise_prior = Some(NoisePrior {
        log_mean: 0.0,
        sd: 0.0,
    });
    assert!(matches!(
        Sampler::new(tiny(), st),
        Err(Error::InvalidInput(_))
    ));
}

// --- per-pattern noise ----------------------------------------------------------------------

fn per_pattern_settings(likelihood: Likelihood, seed: u64) -> Settings {
    let mut st = noise_settings(likelihood, seed);
    st.noise_scope = NoiseScope::PerPattern;
    st
}

/// Mean and sd of `log σ_n,d²` under `prior × p(D | σ²)` for ONE pattern holding `group`, by
/// quadrature (the pattern's other output held at `params`' value).
fn quadrature_one(
    data: &Data,
    st: &Settings,
    params: GpParams,
    group: &[usize],
    d: usize,
) -> (f64, f64) {
    let xs: Vec<f64> = (0..4000)
        .map(|t| -14.0 + 20.0 * t as f64 / 4000.0)
        .collect();
    let m: Vec<(usize, FrameRef)> = group.iter().map(|&i| (i, data.frame(i))).collect();
    let lp: Vec<f64> = xs
        .iter()
        .map(|&x| {
            let mut p = params;
            p.noise_var[d] = x.exp();
            PRIOR.log_density(x, st.base.signal_var[d])
                + st.likelihood.pattern(p, &m).unwrap().log_marginal()
        })
        .collect();
    let z = crate::special::log_sum_exp(&lp);
    let w: Vec<f64> = lp.iter().map(|l| (l - z).exp()).collect();
    let mean: f64 = xs.iter().zip(&w).map(|(x, w)| x * w).sum();
    let var: f64 = xs.iter().zip(&w).map(|(x, w)| (x - mean).powi(2) * w).sum();
    (mean, var.sqrt())
}

#[test]
fn per_pattern_noise_draws_follow_each_patterns_posterior() {
    for likelihood in [Likelihood::Exact, tiny_hsgp()] {
        let st = per_pattern_settings(likelihood.clone(), 2);
        let data = tiny();
        let labels = [0, 1, 0, 1, 1];
        let groups = [vec![0, 2], vec![1, 3, 4]];
        let mut s = Sampler::new(tiny(), st.clone()).unwrap();
        let ls = st.base.length_scales;
        s.set_state_with_noise(&labels, &[ls, ls], Some(&[[0.3, 2.0], [1.5, 0.2]]), 1.0)
            .unwrap();
        // Slot of each group: the pattern holding its first frame.
        let slots = [s.labels()[0], s.labels()[1]];
        let n = 20_000;
        let mut draws = vec![[Vec::with_capacity(n), Vec::with_capacity(n)]; 2];
        for t in 0..n {
            s.sweep = t as u64;
            s.update_noise().unwrap();
            for g in 0..2 {
                let nv = s.pattern(slots[g]).unwrap().params().noise_var;
                for d in 0..2 {
                    draws[g][d].push(nv[d].ln());
                }
            }
        }
        // The chain's pair is untouched per pattern.
        assert_eq!(s.noise_var(), st.base.noise_var);
        for g in 0..2 {
            for d in 0..2 {
                let (m, sd) = quadrature_one(&data, &st, st.base, &groups[g], d);
                let x = &draws[g][d];
                let got_m = x.iter().sum::<f64>() / n as f64;
                let got_sd = (x.iter().map(|v| (v - got_m).powi(2)).sum::<f64>() / n as f64).sqrt();
                let name = format!("{} pattern {g} d={d}", likelihood.name());
                assert!(
                    (got_m - m).abs() < 0.05 * sd + 1e-3,
                    "{name}: mean {got_m} vs {m} (sd {sd})"
                );
                assert!(
                    (got_sd / sd - 1.0).abs() < 0.05,
                    "{name}: sd {got_sd} vs {sd}"
                );
            }
        }
    }
}

/// `log ∫∫ prior(σ_x²) prior(σ_y²) p(D | σ²) dσ²` of one pattern holding `members`, the noise of
/// each output integrated on a 1-D grid of `log σ²` (the outputs are independent GPs given the
/// partition, so `p(D | σ²) = p_x(D | σ_x²) p_y(D | σ_y²)` and the double integral is
/// `I_x I_y = [∫ prior · p(D | ·, σ_y0²)] [∫ prior · p(D | σ_x0², ·)] / p(D | σ_0²)`).
fn noise_integrated(data: &Data, st: &Settings, members: &[usize]) -> f64 {
    let m: Vec<(usize, FrameRef)> = members.iter().map(|&i| (i, data.frame(i))).collect();
    let at = |n: [f64; 2]| {
        let p = GpParams {
            noise_var: n,
            ..st.base
        };
        st.likelihood.pattern(p, &m).unwrap().log_marginal()
    };
    let n0 = st.base.noise_var;
    let step = 0.04;
    let one = |d: usize| {
        let c = st.base.signal_var[d].ln() + PRIOR.log_mean;
        let lp: Vec<f64> = (0..=800)
            .map(|t| {
                let x = c - 16.0 + step * t as f64;
                let mut n = n0;
                n[d] = x.exp();
                PRIOR.log_density(x, st.base.signal_var[d]) + at(n)
            })
            .collect();
        crate::special::log_sum_exp(&lp) + step.ln()
    };
    one(0) + one(1) - at(n0)
}

/// The partition posterior with every pattern's noise integrated out under its prior.
pub(crate) fn enumerated_noise_integrated(data: &Data, st: &Settings) -> HashMap<Vec<usize>, f64> {
    crate::gibbs::split_merge::tests::enumerated_by(data.len(), st.alpha.unwrap(), |members| {
        noise_integrated(data, st, members)
    })
}

fn per_pattern_chain(
    st: Settings,
    sweeps: usize,
) -> (HashMap<Vec<usize>, f64>, crate::gibbs::SplitMergeStats) {
    let mut s = Sampler::new(tiny(), st).unwrap();
    let mut counts: HashMap<Vec<usize>, f64> = HashMap::new();
    for _ in 0..sweeps {
        s.sweep(&|| false).unwrap();
        *counts
            .entry(crate::gibbs::split_merge::tests::canonical(s.labels()))
            .or_default() += 1.0;
    }
    for c in counts.values_mut() {
        *c /= sweeps as f64;
    }
    (counts, s.split_merge)
}

/// Gibbs + split–merge with per-pattern noise samples the partition posterior with each
/// pattern's noise integrated out (length scales fixed), exact and hsgp; and that posterior is
/// far from the one with the noise global, so the check has power.
#[test]
fn per_pattern_noise_chain_samples_the_enumerated_posterior() {
    use crate::test_util::tv;
    for likelihood in [Likelihood::Exact, tiny_hsgp()] {
        let mut st = per_pattern_settings(likelihood.clone(), 3);
        st.split_merge.moves_per_sweep = 2;
        st.new_pattern_samples = 3;
        let exact = enumerated_noise_integrated(&tiny(), &st);
        let (freq, stats) = per_pattern_chain(st.clone(), 40_000);
        let d = tv(&freq, &exact);
        let name = likelihood.name();
        eprintln!("{name}: per-pattern noise TV {d:.4} ({stats:?})");
        assert!(d <= 0.03, "{name}: TV {d:.4} > 0.03 ({stats:?})");
        assert!(
            stats.split_accepted > 100 && stats.merge_accepted > 100,
            "{name}: {stats:?}"
        );
        // The global sampled noise: a different posterior, which the chain must not match.
        let mut global = st.clone();
        global.noise_scope = NoiseScope::Global;
        let (gfreq, _) = per_pattern_chain(global, 20_000);
        let g = tv(&gfreq, &exact);
        eprintln!("{name}: global noise chain vs per-pattern posterior TV {g:.4}");
        assert!(
            g > 0.05,
            "{name}: the global chain is within {g:.4} of the per-pattern posterior"
        );
    }
}

#[test]
fn per_pattern_noise_chain_is_the_same_whatever_the_thread_count() {
    let run = |threads: usize, likelihood: Likelihood, proposal: crate::gibbs::Proposal| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut st = per_pattern_settings(likelihood, 5);
            st.fixed_length_scales = false;
            st.alpha = None;
            st.new_pattern_samples = 5;
            st.proposal = proposal;
            st.split_merge.moves_per_sweep = 3;
            st.split_merge.pairs = crate::gibbs::PairChoice::Informed;
            let mut s = Sampler::new(tiny(), st).unwrap();
            let trace: Vec<f64> = (0..30)
                .map(|_| s.sweep(&|| false).unwrap().log_joint)
                .collect();
            let noise: Vec<[f64; 2]> = s.patterns().iter().map(|p| p.noise_var).collect();
            (s.labels().to_vec(), trace, noise, s.split_merge)
        })
    };
    for l in [Likelihood::Exact, tiny_hsgp()] {
        for p in [
            crate::gibbs::Proposal::Full,
            crate::gibbs::Proposal::Informed,
        ] {
            let (a, b) = (run(1, l.clone(), p), run(2, l.clone(), p));
            assert_eq!(a, b);
        }
    }
}

/// Per-pattern noise: the same chain in feet and metres (the prior is relative to the velocity
/// variance, and so is every prior draw of a new pattern's noise).
#[test]
fn per_pattern_noise_is_unit_free() {
    let c = 3.280_839_895;
    let run = |scale: f64| {
        let d = tiny();
        let (mut xy, mut v, mut off) = (Vec::new(), Vec::new(), vec![0]);
        for i in 0..d.len() {
            let f = d.frame(i);
            xy.extend(f.xy.iter().map(|p| [p[0] * scale, p[1] * scale]));
            v.extend(f.v.iter().map(|p| [p[0] * scale, p[1] * scale]));
            off.push(xy.len());
        }
        let mut st = per_pattern_settings(Likelihood::Exact, 4);
        st.fixed_length_scales = false;
        st.alpha = None;
        st.new_pattern_samples = 5;
        st.split_merge.moves_per_sweep = 2;
        let b = st.base;
        let s2 = scale * scale;
        st.base = GpParams::new(
            (b.length_scales.wx * scale, b.length_scales.wy * scale),
            (b.signal_var[0] * s2, b.signal_var[1] * s2),
            (b.noise_var[0] * s2, b.noise_var[1] * s2),
            (b.mean[0] * scale, b.mean[1] * scale),
        )
        .unwrap();
        st.length_scale_prior.1 *= scale;
        let mut s = Sampler::new(Data::new(xy, v, off).unwrap(), st).unwrap();
        (0..15)
            .map(|_| {
                s.sweep(&|| false).unwrap();
                let noise: Vec<[f64; 2]> = s
                    .patterns()
                    .iter()
                    .map(|p| p.noise_var.map(|x| x / s2))
                    .collect();
                (
                    crate::gibbs::split_merge::tests::canonical(s.labels()),
                    noise,
                )
            })
            .collect::<Vec<_>>()
    };
    let (m, f) = (run(1.0), run(c));
    for (t, (a, b)) in m.iter().zip(&f).enumerate() {
        assert_eq!(a.0, b.0, "sweep {t}");
        assert_eq!(a.1.len(), b.1.len());
        for (x, y) in a.1.iter().zip(&b.1) {
            for d in 0..2 {
                assert!(
                    (x[d] / y[d] - 1.0).abs() < 1e-6,
                    "sweep {t}: {x:?} vs {y:?}"
                );
            }
        }
    }
}

#[test]
fn per_pattern_noise_needs_a_prior() {
    let mut st = per_pattern_settings(Likelihood::Exact, 1);
    st.noise_prior = None;
    assert!(matches!(
        Sampler::new(tiny(), st),
        Err(Error::InvalidInput(_))
    ));
    assert!("per_pattern".parse::<NoiseScope>().unwrap() == NoiseScope::PerPattern);
    assert!("each".parse::<NoiseScope>().is_err());
}
