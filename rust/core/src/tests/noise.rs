//! The noise step: with the partition held, its draws follow the noise's posterior (checked
//! against quadrature of the prior times the marginal likelihood on a grid); the chain is the
//! same in other units, and whatever the thread count.

use super::*;
use crate::gibbs::split_merge::tests::{tiny, tiny_hsgp, tiny_settings};
use crate::gibbs::{Data, Settings};
use crate::pattern::FrameRef;
use crate::pattern_model::Likelihood;

const PRIOR: NoisePrior = NoisePrior {
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
