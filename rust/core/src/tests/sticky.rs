//! The sticky prior against enumeration. On the 5 small frames of the split–merge tests, in
//! one run or two (also in an order that is not the frames' index order), with w and α fixed,
//! the chain's label-sequence frequencies (Gibbs sweep + split–merge + the ρ step) match the
//! posterior enumerated over every partition z and every link configuration s (summed out):
//!
//! `p(z, s | V) ∝ ρ^{#on} (1 − ρ)^{#off} · α^K Γ(α)/Γ(α + M) Π_k Γ(m_k) · Π_k p(D_k)`,
//!
//! with `m_k` the fresh draws (run starts and frames whose link is off) of pattern k, and
//! `ρ^{#on}(1 − ρ)^{#off}` replaced by `B(a + #on, b + #off) / B(a, b)` when ρ ~ Beta(a, b) is
//! sampled.

use std::collections::HashMap;

use crate::test_util::tv;
use std::sync::Arc;

use super::super::split_merge::tests::{canonical, partitions, tiny, tiny_settings};
use super::*;
use crate::frame::FrameRef;
use crate::gibbs::{Data, Proposal, Settings};
use crate::pattern_model::Likelihood;
use crate::special::log_sum_exp;

const N: usize = NONE;

/// One run; two runs; two runs in an order that is not the frames' (0 → 2 → 4, 3 → 1).
const ORDERS: [[usize; 5]; 3] = [[N, 0, 1, 2, 3], [N, 0, 1, N, 3], [N, 3, 0, N, 2]];

fn sticky_settings(prev: [usize; 5], rho: Option<f64>, proposal: Proposal) -> Settings {
    let mut st = tiny_settings(Likelihood::Exact, 3);
    st.proposal = proposal;
    st.dynamics = Some(StickyPrior {
        prev: Arc::from(prev.to_vec()),
        rho,
        rho_prior: (2.0, 1.0),
    });
    st
}

fn ln_beta(a: f64, b: f64) -> f64 {
    ln_gamma(a) + ln_gamma(b) - ln_gamma(a + b)
}

/// `log p(z, s, V)` up to a constant, or `None` if `s` links frames of different patterns.
/// `rho: None` integrates ρ over its Beta prior; `drop_rho` leaves the links' factor out (a
/// wrong prior, to show the check has power).
fn log_weight(data: &Data, st: &Settings, z: &[usize], s: &[bool], drop_rho: bool) -> Option<f64> {
    let d = st.dynamics.as_ref().unwrap();
    let alpha = st.alpha.unwrap();
    let (mut on, mut off) = (0.0, 0.0);
    let k = z.iter().max().unwrap() + 1;
    let mut m = vec![0usize; k];
    for t in 0..z.len() {
        let p = d.prev[t];
        if p == NONE {
            m[z[t]] += 1;
        } else if s[t] {
            if z[t] != z[p] {
                return None;
            }
            on += 1.0;
        } else {
            off += 1.0;
            m[z[t]] += 1;
        }
    }
    assert!(m.iter().all(|&c| c > 0), "every pattern has a fresh draw");
    let total: usize = m.iter().sum();
    let mut w = k as f64 * alpha.ln() + ln_gamma(alpha) - ln_gamma(alpha + total as f64);
    w += m.iter().map(|&c| ln_gamma(c as f64)).sum::<f64>();
    if !drop_rho {
        w += match d.rho {
            Some(r) => on * r.ln() + off * (1.0 - r).ln(),
            None => {
                let (a, b) = d.rho_prior;
                ln_beta(a + on, b + off) - ln_beta(a, b)
            }
        };
    }
    for c in 0..k {
        let members: Vec<(usize, FrameRef)> = (0..z.len())
            .filter(|&i| z[i] == c)
            .map(|i| (i, data.frame(i)))
            .collect();
        w += st
            .likelihood
            .pattern(st.base, &members)
            .unwrap()
            .log_marginal();
    }
    Some(w)
}

/// Every link configuration (`false` where a frame has no predecessor).
fn link_configs(prev: &[usize]) -> Vec<Vec<bool>> {
    let with: Vec<usize> = (0..prev.len()).filter(|&t| prev[t] != NONE).collect();
    (0..1usize << with.len())
        .map(|bits| {
            let mut s = vec![false; prev.len()];
            for (j, &t) in with.iter().enumerate() {
                s[t] = bits >> j & 1 == 1;
            }
            s
        })
        .collect()
}

/// The posterior over label sequences (canonical), links summed out.
fn enumerated(st: &Settings, drop_rho: bool) -> HashMap<Vec<usize>, f64> {
    let data = tiny();
    let prev = st.dynamics.as_ref().unwrap().prev.clone();
    let mut out = Vec::new();
    for z in partitions(data.len()) {
        let ws: Vec<f64> = link_configs(&prev)
            .iter()
            .filter_map(|s| log_weight(&data, st, &z, s, drop_rho))
            .collect();
        out.push((z, log_sum_exp(&ws)));
    }
    let norm = log_sum_exp(&out.iter().map(|p| p.1).collect::<Vec<_>>());
    out.into_iter()
        .map(|(z, w)| (z, (w - norm).exp()))
        .collect()
}

/// Label-sequence frequencies over `sweeps` sweeps (after 100 of burn-in).
fn chain(st: Settings, sweeps: usize) -> (HashMap<Vec<usize>, f64>, Sampler) {
    let mut s = Sampler::new(tiny(), st).unwrap();
    for _ in 0..100 {
        s.sweep(&|| false).unwrap();
    }
    let mut counts: HashMap<Vec<usize>, f64> = HashMap::new();
    for _ in 0..sweeps {
        s.sweep(&|| false).unwrap();
        *counts.entry(canonical(s.labels())).or_default() += 1.0;
    }
    for c in counts.values_mut() {
        *c /= sweeps as f64;
    }
    (counts, s)
}

#[test]
fn sticky_chain_samples_the_enumerated_posterior() {
    for prev in ORDERS {
        for rho in [Some(0.8), None] {
            for proposal in [Proposal::Full, Proposal::Informed] {
                let st = sticky_settings(prev, rho, proposal);
                let exact = enumerated(&st, false);
                let (freq, s) = chain(st, 60_000);
                let d = tv(&freq, &exact);
                let order = prev.map(|p| if p == N { -1 } else { p as i64 });
                let name = format!("prev {order:?} rho {rho:?} {proposal:?}");
                assert!(d <= 0.03, "{name}: TV {d:.4} > 0.03");
                let sm = s.split_merge;
                assert!(
                    sm.split_accepted > 100 && sm.merge_accepted > 100,
                    "{name}: {sm:?}"
                );
                let seg = s.links.as_ref().unwrap().segment_moves;
                assert!(seg.1 > 200, "{name}: segment moves {seg:?}");
                eprintln!("{name}: TV {d:.4}, segment moves {seg:?}");
            }
        }
    }
}

/// The check has power: the chain is far from the posterior with the links' factor dropped,
/// and from the independent DP's.
#[test]
fn the_check_detects_a_wrong_prior() {
    let st = sticky_settings(ORDERS[0], Some(0.8), Proposal::Full);
    let wrong = enumerated(&st, true);
    let mut plain = st.clone();
    plain.dynamics = None;
    let (freq, _) = chain(st, 30_000);
    let d = tv(&freq, &wrong);
    eprintln!("links' factor dropped: TV {d:.4}");
    assert!(d > 0.06, "links' factor dropped: TV {d:.4}");
    let independent = {
        let mut st = plain;
        st.dynamics = Some(StickyPrior {
            prev: Arc::from(vec![N; 5]),
            rho: Some(0.5),
            rho_prior: (1.0, 1.0),
        });
        enumerated(&st, false)
    };
    let d = tv(&freq, &independent);
    eprintln!("independent DP: TV {d:.4}");
    assert!(d > 0.06, "independent DP: TV {d:.4}");
}

/// Split–merge alone, links fixed, samples `p(z | s, V)`: the segments are its items.
#[test]
fn split_merge_moves_segments() {
    let st = sticky_settings(ORDERS[0], Some(0.8), Proposal::Full);
    let links = [false, true, false, true, false]; // segments {0, 1}, {2, 3}, {4}
    let data = tiny();
    let mut exact = Vec::new();
    for z in partitions(5) {
        if let Some(w) = log_weight(&data, &st, &z, &links, false) {
            exact.push((z, w));
        }
    }
    assert_eq!(exact.len(), 5, "the partitions of three segments");
    let norm = log_sum_exp(&exact.iter().map(|p| p.1).collect::<Vec<_>>());
    let exact: HashMap<Vec<usize>, f64> = exact
        .into_iter()
        .map(|(z, w)| (z, (w - norm).exp()))
        .collect();
    let mut s = Sampler::new(data, st).unwrap();
    let ls = s.settings.base.length_scales;
    s.set_state(&[0, 0, 1, 1, 2], &[ls; 3], 1.0).unwrap();
    s.set_links(&links, 0.8).unwrap();
    let steps = 100_000;
    let mut counts: HashMap<Vec<usize>, f64> = HashMap::new();
    for m in 0..steps {
        let mut rng = stream(9, 0, Phase::SplitMerge, m as u64);
        s.split_merge_step(&mut rng).unwrap();
        assert_eq!(s.links().unwrap(), &links, "split–merge keeps the links");
        *counts.entry(canonical(s.labels())).or_default() += 1.0 / steps as f64;
    }
    let d = tv(&counts, &exact);
    assert!(d <= 0.03, "TV {d:.4}: {counts:?} vs {exact:?}");
    assert!(s.split_merge.split_accepted > 1000 && s.split_merge.merge_accepted > 1000);
}

/// `log_joint` differs between states by exactly the enumerated log weights (ρ fixed, and
/// sampled at its current value), and a frame's conditional is the enumerated one with its
/// block's links summed out (a run's middle frame, a run's first, a run's last).
#[test]
fn log_joint_and_conditional_match_the_formula() {
    for rho in [Some(0.7), None] {
        let st = sticky_settings(ORDERS[1], rho, Proposal::Full);
        // The enumeration at the chain's current ρ: p(ρ) is a constant then.
        let at = sticky_settings(ORDERS[1], Some(0.7), Proposal::Full);
        let prev = ORDERS[1];
        let data = tiny();
        let mut s = Sampler::new(data.clone(), st).unwrap();
        let ls = s.settings.base.length_scales;
        let states: [([usize; 5], [bool; 5]); 4] = [
            ([0, 0, 1, 2, 2], [false, true, false, false, true]),
            ([0, 0, 0, 1, 1], [false, true, true, false, false]),
            ([0, 1, 0, 0, 0], [false, false, false, false, true]),
            ([0, 0, 0, 0, 0], [false, true, true, false, true]),
        ];
        let mut diffs = Vec::new();
        for (z, links) in states {
            s.set_state(&z, &[ls; 3], 1.0).unwrap();
            s.set_links(&links, 0.7).unwrap();
            assert_eq!(s.links().unwrap(), &links);
            let want = log_weight(&data, &at, &z, &links, false).unwrap();
            diffs.push(s.log_joint() - want);
            for t in [1, 3, 2] {
                let succ = (0..5).find(|&f| prev[f] == t);
                let own = s.labels()[t];
                let alone = s.labels().iter().filter(|&&l| l == own).count() == 1;
                let slots: Vec<usize> = s.patterns().iter().map(|p| p.slot).collect();
                let mut want = Vec::new();
                for &k in slots.iter().chain([NONE].iter()) {
                    if alone && k == own {
                        want.push(f64::NEG_INFINITY); // a singleton's own pattern is "new"
                        continue;
                    }
                    let mut zz = s.labels().to_vec();
                    zz[t] = if k == NONE { 99 } else { k };
                    let zz = canonical(&zz);
                    let mut ws = Vec::new();
                    for st_on in [false, true] {
                        for sn_on in [false, true] {
                            if (st_on && prev[t] == NONE) || (sn_on && succ.is_none()) {
                                continue;
                            }
                            let mut l = links;
                            l[t] = st_on;
                            if let Some(n) = succ {
                                l[n] = sn_on;
                            }
                            if let Some(w) = log_weight(&data, &at, &zz, &l, false) {
                                ws.push(w);
                            }
                        }
                    }
                    want.push(log_sum_exp(&ws));
                }
                let norm = log_sum_exp(&want);
                let got = s.conditional_log_probs(t).unwrap();
                assert_eq!(got.len(), want.len());
                for (g, w) in got.iter().zip(&want) {
                    let w = w - norm;
                    assert!(
                        (g - w).abs() < 1e-9 || (g.is_infinite() && w.is_infinite()),
                        "{z:?} frame {t}: conditional {got:?} vs {want:?}"
                    );
                }
            }
        }
        for d in &diffs {
            assert!((d - diffs[0]).abs() < 1e-9, "{rho:?}: {diffs:?}");
        }
    }
}

#[test]
fn sticky_chain_is_the_same_whatever_the_thread_count() {
    let run = |threads: usize, proposal: Proposal| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut st = sticky_settings(ORDERS[2], None, proposal);
            st.fixed_length_scales = false;
            st.alpha = None;
            st.new_pattern_samples = 5;
            let mut s = Sampler::new(tiny(), st).unwrap();
            let trace: Vec<f64> = (0..30)
                .map(|_| s.sweep(&|| false).unwrap().log_joint)
                .collect();
            (s.labels().to_vec(), s.links().unwrap().to_vec(), trace)
        })
    };
    for p in [Proposal::Full, Proposal::Informed] {
        assert_eq!(run(1, p), run(2, p));
    }
}

#[test]
fn bad_time_orders_are_refused() {
    for prev in [
        [N, 0, 0, N, N],
        [1, 0, N, N, N],
        [N, 5, N, N, N],
        [N, 1, N, N, N],
    ] {
        let st = sticky_settings(prev, None, Proposal::Full);
        assert!(Sampler::new(tiny(), st).is_err(), "{prev:?}");
    }
    let mut st = sticky_settings(ORDERS[0], Some(1.0), Proposal::Full);
    assert!(Sampler::new(tiny(), st.clone()).is_err());
    st.dynamics.as_mut().unwrap().rho = None;
    st.dynamics.as_mut().unwrap().rho_prior = (0.0, 1.0);
    assert!(Sampler::new(tiny(), st).is_err());
}

/// Segment moves alone, links fixed (all off: every frame its own segment), from a state where
/// they can only shift the boundary between two patterns: the chain samples the posterior
/// restricted to those four states, whose CRP weights differ (so a wrong count ratio fails).
#[test]
fn segment_moves_sample_the_restricted_posterior() {
    let st = sticky_settings(ORDERS[0], Some(0.8), Proposal::Full);
    let data = tiny();
    let links = [false; 5];
    let states = [
        [0, 1, 1, 1, 1],
        [0, 0, 1, 1, 1],
        [0, 0, 0, 1, 1],
        [0, 0, 0, 0, 1],
    ];
    let w: Vec<f64> = states
        .iter()
        .map(|z| log_weight(&data, &st, z, &links, false).unwrap())
        .collect();
    let norm = log_sum_exp(&w);
    let exact: HashMap<Vec<usize>, f64> = states
        .iter()
        .zip(&w)
        .map(|(z, w)| (z.to_vec(), (w - norm).exp()))
        .collect();
    // Without the CRP's count ratio the target would be this one.
    let flat: Vec<f64> = states
        .iter()
        .zip(&w)
        .map(|(z, w)| {
            let m0 = z.iter().filter(|&&k| k == 0).count() as f64;
            w - ln_gamma(m0) - ln_gamma(5.0 - m0)
        })
        .collect();
    let fnorm = log_sum_exp(&flat);
    let wrong: HashMap<Vec<usize>, f64> = states
        .iter()
        .zip(&flat)
        .map(|(z, w)| (z.to_vec(), (w - fnorm).exp()))
        .collect();
    let mut s = Sampler::new(data, st).unwrap();
    let ls = s.settings.base.length_scales;
    s.set_state(&[0, 0, 1, 1, 1], &[ls; 2], 1.0).unwrap();
    s.set_links(&links, 0.8).unwrap();
    let steps = 60_000;
    let mut counts: HashMap<Vec<usize>, f64> = HashMap::new();
    for step in 0..steps {
        s.sweep = step as u64;
        s.segment_moves().unwrap();
        *counts.entry(canonical(s.labels())).or_default() += 1.0 / steps as f64;
    }
    let d = tv(&counts, &exact);
    let bad = tv(&counts, &wrong);
    eprintln!("segment moves alone: TV {d:.4}; against the target without counts {bad:.4}");
    assert!(d <= 0.03, "TV {d:.4}: {counts:?} vs {exact:?}");
    assert!(bad > 0.06, "no power: {bad:.4}");
    let moves = s.links.as_ref().unwrap().segment_moves;
    assert!(moves.1 > 10_000, "{moves:?}");
}
