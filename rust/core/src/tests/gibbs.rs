use super::*;
use crate::hsgp::Basis;

/// Two obvious patterns: vehicles moving +y and vehicles moving +x, 30 frames each.
fn two_patterns() -> Data {
    let mut u = crate::test_util::uniform(7u64);
    let (mut xy, mut v, mut offsets) = (Vec::new(), Vec::new(), vec![0]);
    for i in 0..60 {
        for _ in 0..4 {
            let p = [u() * 40.0, u() * 40.0];
            xy.push(p);
            v.push(if i % 2 == 0 {
                [0.3 * u(), 10.0 + u()]
            } else {
                [10.0 + u(), 0.3 * u()]
            });
        }
        offsets.push(xy.len());
    }
    Data::new(xy, v, offsets).unwrap()
}

fn settings(assignment: Assignment, seed: u64) -> Settings {
    Settings {
        assignment,
        base: GpParams::new((10.0, 10.0), (25.0, 25.0), (1.0, 1.0), (5.0, 5.0)).unwrap(),
        fixed_length_scales: false,
        length_scale_prior: (10.0, 1.0),
        heading_prior: None,
        alpha: None,
        new_pattern_samples: 10,
        length_scale_fraction: 1.0,
        pattern_moments: false,
        seed,
        likelihood: Likelihood::Exact,
        proposal: Proposal::Full,
        memory_budget: None,
        split_merge: Default::default(),
        noise_prior: None,
        noise_scope: crate::gibbs::NoiseScope::Global,
        dynamics: None,
        sampler: crate::gibbs::SamplerKind::Collapsed,
    }
}

/// A reduced-rank likelihood for `two_patterns` (positions in [0, 40]²): few basis functions,
/// so that patterns cross between the dense and the statistics representations.
fn hsgp() -> Likelihood {
    Likelihood::Hsgp(Arc::new(
        Basis::new([20.0, 20.0], [40.0, 40.0], [6, 6]).unwrap(),
    ))
}

/// Every combination of likelihood and proposal.
fn variants() -> Vec<(Likelihood, Proposal)> {
    let mut out = Vec::new();
    for l in [Likelihood::Exact, hsgp()] {
        for p in [Proposal::Full, Proposal::Informed] {
            out.push((l.clone(), p));
        }
    }
    out
}

fn run(assignment: Assignment, seed: u64, threads: usize) -> (Vec<usize>, Vec<f64>) {
    run_with(assignment, seed, threads, Likelihood::Exact, Proposal::Full)
}

fn run_with(
    assignment: Assignment,
    seed: u64,
    threads: usize,
    likelihood: Likelihood,
    proposal: Proposal,
) -> (Vec<usize>, Vec<f64>) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let mut st = settings(assignment, seed);
        st.likelihood = likelihood;
        st.proposal = proposal;
        let mut s = Sampler::new(two_patterns(), st).unwrap();
        let mut trace = Vec::new();
        for _ in 0..5 {
            trace.push(s.sweep(&|| false).unwrap().log_joint);
        }
        (s.labels().to_vec(), trace)
    })
}

#[test]
fn separates_two_obvious_patterns_in_every_mode() {
    for (likelihood, proposal) in variants() {
        for mode in [Assignment::Gibbs, Assignment::Map] {
            let name = format!("{mode:?} {} {proposal:?}", likelihood.name());
            let (labels, _) = run_with(mode, 1, 1, likelihood.clone(), proposal);
            for i in (0..60).step_by(2) {
                assert_eq!(labels[i], labels[0], "{name}: frame {i}");
                assert_eq!(labels[i + 1], labels[1], "{name}: frame {}", i + 1);
            }
            assert_ne!(labels[0], labels[1], "{name}");
        }
    }
}

#[test]
fn same_seed_same_chain_whatever_the_thread_count() {
    let a = run(Assignment::Gibbs, 3, 1);
    let b = run(Assignment::Gibbs, 3, 2);
    assert_eq!(a, b);
    let c = run(Assignment::Gibbs, 4, 2);
    assert_ne!(a.1, c.1);
    for (likelihood, proposal) in variants() {
        for mode in [Assignment::Gibbs, Assignment::Map] {
            let one = run_with(mode, 3, 1, likelihood.clone(), proposal);
            let two = run_with(mode, 3, 2, likelihood.clone(), proposal);
            assert_eq!(one, two, "{mode:?} {} {proposal:?}", likelihood.name());
        }
    }
}

#[test]
fn memory_budget_stops_before_allocating_and_keeps_the_state() {
    let mut st = settings(Assignment::Gibbs, 1);
    st.memory_budget = Some(200_000);
    let mut s = Sampler::new(two_patterns(), st).unwrap();
    let err = s.initialize(&|| false).unwrap_err();
    assert!(matches!(err, Error::MemoryBudget { .. }), "{err:?}");
    assert!(err.to_string().contains("hsgp"));
    assert!(s.memory_bytes() <= 200_000);
    // Every frame placed so far still has a live pattern.
    for (i, &k) in s.labels().iter().enumerate() {
        assert!(k == NONE || s.pattern(k).unwrap().frames().contains(&i));
    }
}

#[test]
fn cached_scores_equal_fresh_scores() {
    let mut s = Sampler::new(two_patterns(), settings(Assignment::Gibbs, 5)).unwrap();
    for _ in 0..2 {
        s.sweep(&|| false).unwrap();
    }
    let data = Arc::clone(&s.data);
    for i in 0..data.len() {
        for (k, slot) in s.live() {
            if s.labels[i] == k || s.cache[i].get(k).is_none_or(|c| c.0 != slot.version) {
                continue;
            }
            let fresh = slot.pattern.score(&[data.frame(i)]).unwrap()[0];
            assert!((s.cache[i][k].1 - fresh).abs() < 1e-8 * fresh.abs().max(1.0));
        }
    }
}

#[test]
fn bad_settings_are_errors() {
    let mut st = settings(Assignment::Gibbs, 0);
    st.alpha = Some(-1.0);
    assert!(Sampler::new(two_patterns(), st.clone()).is_err());
    st.alpha = None;
    st.new_pattern_samples = 0;
    assert!(Sampler::new(two_patterns(), st).is_err());
    assert!(Data::new(vec![[0.0, 0.0]], vec![[0.0, 0.0]], vec![0, 0, 1]).is_err());
}

#[test]
fn pattern_moments_follow_each_patterns_own_data() {
    let mut st = settings(Assignment::Gibbs, 2);
    st.pattern_moments = true;
    let mut s = Sampler::new(two_patterns(), st).unwrap();
    for _ in 0..3 {
        s.sweep(&|| false).unwrap();
    }
    for info in s.patterns() {
        let p = s.pattern(info.slot).unwrap();
        let (_, v) = p.points();
        let n = v.len() as f64;
        for d in 0..2 {
            let mean = v.iter().map(|r| r[d]).sum::<f64>() / n;
            let var = v.iter().map(|r| (r[d] - mean).powi(2)).sum::<f64>() / n;
            assert!((p.params().mean[d] - mean).abs() < 1e-12);
            assert!((p.params().signal_var[d] - var.max(25.0e-3)).abs() < 1e-12);
        }
    }
}

#[test]
fn settings_names_parse_in_the_core_and_a_wrong_one_lists_the_right_ones() {
    use crate::pattern_model::LikelihoodKind;
    assert_eq!("map".parse::<Assignment>(), Ok(Assignment::Map));
    assert_eq!("informed".parse::<Proposal>(), Ok(Proposal::Informed));
    assert_eq!("uniform".parse::<PairChoice>(), Ok(PairChoice::Uniform));
    assert_eq!("hsgp".parse::<LikelihoodKind>(), Ok(LikelihoodKind::Hsgp));
    let Err(Error::InvalidInput(msg)) = "greedy".parse::<Assignment>() else {
        panic!("an unknown assignment must be InvalidInput");
    };
    assert!(
        msg.contains("'gibbs', 'map'") && msg.contains("greedy"),
        "{msg}"
    );
    assert!("smart".parse::<Proposal>().is_err());
    assert!("near".parse::<PairChoice>().is_err());
    assert!("sparse".parse::<LikelihoodKind>().is_err());
    assert!(Likelihood::new(LikelihoodKind::Hsgp, None).is_err());
}

#[test]
fn settings_limits_are_checked_once_here() {
    assert!(Settings::default().validate().is_ok());
    let bad = [
        Settings {
            new_pattern_samples: MAX_NEW_PATTERN_SAMPLES + 1,
            ..Settings::default()
        },
        Settings {
            alpha: Some(ALPHA_RANGE.1 * 10.0),
            ..Settings::default()
        },
        Settings {
            split_merge: SplitMerge {
                moves_per_sweep: MAX_SPLIT_MERGE_MOVES + 1,
                pairs: PairChoice::Uniform,
            },
            ..Settings::default()
        },
    ];
    for st in bad {
        assert!(matches!(st.validate(), Err(Error::InvalidInput(_))));
    }
    assert_eq!(check_threads(None), Ok(0));
    assert_eq!(check_threads(Some(MAX_THREADS)), Ok(MAX_THREADS));
    assert!(check_threads(Some(0)).is_err());
    assert!(check_threads(Some(MAX_THREADS + 1)).is_err());
}

#[test]
fn the_length_scale_prior_rule_refuses_what_leaves_double_precision() {
    assert!(check_length_scale_prior((10.0, 1.0)).is_ok());
    assert!(check_length_scale_prior((1e-100, 1e-50)).is_ok());
    for bad in [
        (0.0, 1.0),
        (1.0, f64::NAN),
        (1e101, 1.0),
        (1.0, 1e-101),
        (1e-100, 1e-60),
        (1e60, 1e60),
    ] {
        assert!(
            matches!(check_length_scale_prior(bad), Err(Error::InvalidInput(_))),
            "{bad:?}"
        );
        let s = Settings {
            length_scale_prior: bad,
            ..Settings::default()
        };
        assert!(s.validate().is_err(), "{bad:?}");
    }
}

#[test]
fn candidate_bytes_are_two_copies_of_the_largest_patterns_one_per_worker() {
    let mut s = Sampler::new(two_patterns(), settings(Assignment::Gibbs, 2)).unwrap();
    s.initialize(&|| false).unwrap();
    s.sweep(&|| false).unwrap();
    let mut sizes: Vec<usize> = s.live().map(|(_, sl)| sl.pattern.bytes()).collect();
    sizes.sort_unstable();
    for threads in [1usize, 2, 8] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let got = pool.install(|| s.candidate_bytes());
        let want: usize = sizes.iter().rev().take(threads).sum::<usize>() * 2;
        assert_eq!(got, want, "{threads} threads, pattern bytes {sizes:?}");
        // never more than two copies of every pattern, whatever the thread count
        assert!(got <= 2 * sizes.iter().sum::<usize>());
    }
}
