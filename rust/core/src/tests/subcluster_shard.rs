//! Shards: every request and reply survives the trip through bytes (and damaged bytes are an
//! error, not a panic); a chain over shards samples the enumerated posterior, is the same served
//! in process or through bytes and for any thread count, and one shard is the chain over all
//! frames.

use std::collections::HashMap;

use super::*;
use crate::gibbs::enumeration::{
    canonical, enumerated_by, headed_settings, tiny, tiny_headed, tiny_hsgp, tiny_hsgp_headed,
    tiny_settings,
};
use crate::gibbs::{SamplerKind, Settings};
use crate::subcluster::{Start, SubclusterSampler};
use crate::test_util::tv;

/// Shards served through bytes both ways, as a link to other processes serves them.
#[derive(Debug)]
struct Bytes(Vec<Shard>);

impl Link for Bytes {
    fn run(&self, jobs: Vec<(usize, Request)>) -> Result<Vec<Reply>> {
        jobs.iter()
            .map(|(s, r)| {
                let req = Request::decode(&r.encode())?;
                Reply::decode(&self.0[*s].handle(&req)?.encode())
            })
            .collect()
    }
}

/// `data` cut into consecutive shards of `sizes` frames.
fn cut(data: &Data, sizes: &[usize]) -> Vec<Shard> {
    let (xy, v) = data.points();
    let o = data.offsets();
    let mut first = 0;
    sizes
        .iter()
        .map(|&n| {
            let (a, b) = (o[first], o[first + n]);
            let offsets = o[first..=first + n].iter().map(|x| x - a).collect();
            let mut d = Data::new(xy[a..b].to_vec(), v[a..b].to_vec(), offsets).unwrap();
            if !data.headings().is_empty() {
                d = d.with_headings(data.headings()[a..b].to_vec()).unwrap();
            }
            let s = Shard::new(Arc::new(d), first);
            first += n;
            s
        })
        .collect()
}

fn settings(seed: u64) -> Settings {
    let mut st = tiny_settings(tiny_hsgp(), seed);
    st.sampler = SamplerKind::Subcluster;
    st.split_merge.moves_per_sweep = 2;
    st
}

fn basis() -> Basis {
    Basis::new([1.0, -2.0], [5.0, 7.5], [3, 2]).unwrap()
}

#[test]
fn requests_and_replies_cross_as_bytes() {
    let bank = Bank {
        weights: vec![[vec![0.5; 6], vec![-1.25; 6]], [vec![2.0; 6], vec![0.0; 6]]],
        noise: vec![[0.1, 0.2], [0.3, 0.4]],
        mean: [1.5, -0.5],
    };
    let requests = [
        Request::Sums {
            basis: basis(),
            sets: vec![vec![0, 3], vec![], vec![7]],
        },
        Request::Logliks {
            basis: basis(),
            bank: bank.clone(),
            frames: vec![4, 1],
        },
        Request::Draw {
            basis: basis(),
            bank,
            log_w: vec![-0.7, -1.2],
            frames: 2..9,
            key: DrawKey {
                seed: 17,
                sweep: 3,
                phase: 12,
                map: true,
            },
        },
        Request::Means,
        Request::Points { frames: vec![5] },
        Request::Sums {
            basis: basis().with_heading(2, [2, 1]).unwrap(),
            sets: vec![vec![1]],
        },
    ];
    let data = tiny();
    let shard = Shard::new(Arc::new(data), 0);
    let mut sums = Sums::zeros(&basis());
    sums.h[1] = 3.25;
    sums.vecs.phi_v[2] = -1.0;
    sums.vecs.v_sq = [2.0, 9.0];
    sums.vecs.n_points = 11;
    sums.n_frames = 4;
    let replies = [
        Reply::Sums(vec![sums]),
        Reply::Logliks(vec![-1.0, f64::NEG_INFINITY]),
        Reply::Draw(vec![0, 1, 1]),
        Reply::Means(vec![[1.0, 2.0]]),
        shard
            .handle(&Request::Points { frames: vec![4, 0] })
            .unwrap(),
        Shard::new(Arc::new(tiny_headed()), 0)
            .handle(&Request::Points { frames: vec![4, 0] })
            .unwrap(),
    ];
    for r in &requests {
        let bytes = r.encode();
        assert_eq!(&Request::decode(&bytes).unwrap(), r);
        // Damaged: cut short, one byte too many, another magic. An error each, never a panic.
        assert!(Request::decode(&bytes[..bytes.len() - 1]).is_err());
        let mut long = bytes.clone();
        long.push(0);
        assert!(Request::decode(&long).is_err());
        let mut bad = bytes.clone();
        bad[0] ^= 1;
        assert!(Request::decode(&bad).is_err());
    }
    for r in &replies {
        let bytes = r.encode();
        assert_eq!(&Reply::decode(&bytes).unwrap(), r);
        assert!(Reply::decode(&bytes[..bytes.len() - 1]).is_err());
    }
    // A length that claims more than the message holds.
    let mut huge = Request::Points { frames: vec![1] }.encode();
    huge[12..20].copy_from_slice(&u64::MAX.to_le_bytes());
    assert!(Request::decode(&huge).is_err());
}

#[test]
fn a_shard_refuses_frames_it_does_not_hold() {
    let shard = Shard::new(Arc::new(tiny()), 10);
    let err = shard
        .handle(&Request::Points { frames: vec![0, 5] })
        .unwrap_err();
    assert!(err.to_string().contains("frame 5"), "{err}");
    let err = shard
        .handle(&Request::Sums {
            basis: basis(),
            sets: vec![vec![9]],
        })
        .unwrap_err();
    assert!(err.to_string().contains("frame 9"), "{err}");
}

#[test]
fn the_store_answers_as_all_frames_in_one_place() {
    let data = Arc::new(tiny());
    let one = Store::local(Arc::clone(&data));
    let many = Store::sharded(&[2, 1, 2], Arc::new(Bytes(cut(&data, &[2, 1, 2])))).unwrap();
    let b = basis();
    let sets: [&[usize]; 3] = [&[4, 0, 2], &[1], &[]];
    for (x, y) in one
        .sums_of_sets(&b, &sets)
        .unwrap()
        .iter()
        .zip(many.sums_of_sets(&b, &sets).unwrap())
    {
        assert_eq!(x.n_frames, y.n_frames);
        assert_eq!(x.vecs.n_points, y.vecs.n_points);
        for (p, q) in x.h.iter().zip(&y.h) {
            assert!((p - q).abs() <= 1e-12 * (1.0 + p.abs()), "{p} {q}");
        }
    }
    // The groups of labels (label 7 in none) give the sums of their member lists, bit for bit.
    let (labels, group) = ([2, 5, 2, 7, 2], [9, 9, 0, 9, 9, 1]);
    for store in [&one, &many] {
        let by_group = store.sums_of_groups(&b, &labels, &group, 2).unwrap();
        let by_sets = store.sums_of_sets(&b, &[&[0, 2, 4], &[1]]).unwrap();
        assert_eq!(by_group, by_sets);
    }
    assert!(one.sums_of_groups(&b, &labels[..4], &group, 2).is_err());
    let bank = Bank {
        weights: vec![[vec![0.1; 6], vec![0.2; 6]], [vec![-0.3; 6], vec![0.0; 6]]],
        noise: vec![[0.5, 0.5], [1.0, 2.0]],
        mean: [0.0, 0.0],
    };
    let order = [3, 0, 4, 1];
    assert_eq!(
        one.logliks(&b, &bank, &order).unwrap(),
        many.logliks(&b, &bank, &order).unwrap()
    );
    let key = DrawKey {
        seed: 4,
        sweep: 2,
        phase: 12,
        map: false,
    };
    assert_eq!(
        one.draw(&b, &bank, &[0.0, -0.5], 1..5, key).unwrap(),
        many.draw(&b, &bank, &[0.0, -0.5], 1..5, key).unwrap()
    );
    assert_eq!(one.means().unwrap(), many.means().unwrap());
    let (f1, f2) = (one.frames(&order).unwrap(), many.frames(&order).unwrap());
    assert_eq!(f1.points(), f2.points());
    assert_eq!(f1.offsets(), f2.offsets());
}

/// The labels, log joint and α of 150 sweeps from the sequential start under `st` (length scales
/// and α sampled).
fn trace_with(store: Store, mut st: Settings, threads: usize) -> Vec<(Vec<usize>, u64, u64)> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        st.fixed_length_scales = false;
        st.alpha = None;
        let mut s = SubclusterSampler::with_store(store, st).unwrap();
        s.initialize(Start::Sequential, &|| false).unwrap();
        (0..150)
            .map(|_| {
                let r = s.sweep(&|| false).unwrap();
                (
                    canonical(s.labels()),
                    r.log_joint.to_bits(),
                    r.alpha.to_bits(),
                )
            })
            .collect()
    })
}

/// The chain over shards of `sizes` is the same in process and through bytes and for 1–3
/// threads, and on one shard the chain over all frames in one place (more shards add their sums
/// in another order: the same chain up to round-off). Returns the latter's trace.
fn assert_one_chain_wherever_served(
    data: &Data,
    sizes: &[usize],
    st: &Settings,
) -> Vec<(Vec<usize>, u64, u64)> {
    let run = |store: Store, threads| trace_with(store, st.clone(), threads);
    let in_process = || Store::in_process_shards(cut(data, sizes)).unwrap();
    let bytes = || Store::sharded(sizes, Arc::new(Bytes(cut(data, sizes)))).unwrap();
    let reference = run(in_process(), 1);
    assert_eq!(reference, run(bytes(), 1));
    assert_eq!(reference, run(bytes(), 3));
    assert_eq!(reference, run(in_process(), 2));
    let whole = run(Store::local(Arc::new(data.clone())), 1);
    let one = Store::in_process_shards(cut(data, &[data.len()])).unwrap();
    assert_eq!(whole, run(one, 2));
    whole
}

#[test]
fn a_sharded_chain_is_the_same_in_process_through_bytes_and_for_any_thread_count() {
    assert_one_chain_wherever_served(&tiny(), &[2, 3], &settings(5));
}

/// Fields over heading: the shards send their points' headings with the points and sum the
/// heading moments.
#[test]
fn a_sharded_chain_over_heading_is_the_chain_over_all_frames() {
    let mut st = headed_settings(tiny_hsgp_headed(), 5);
    st.sampler = SamplerKind::Subcluster;
    st.split_merge.moves_per_sweep = 2;
    let whole = assert_one_chain_wherever_served(&tiny_headed(), &[3, 2], &st);
    // Not the chain over position: the headings were used.
    let mut blind = st.clone();
    blind.heading_prior = None;
    blind.likelihood = tiny_hsgp();
    blind.base = st
        .base
        .with_length_scales(st.base.length_scales.with_heading(f64::INFINITY).unwrap());
    assert_ne!(whole, trace_with(Store::local(Arc::new(tiny())), blind, 1));
}

#[test]
fn a_sharded_chain_samples_the_enumerated_posterior() {
    let data = tiny();
    let st = settings(8);
    let exact = enumerated_by(data.len(), st.alpha.unwrap(), |members| {
        let m: Vec<(usize, crate::frame::FrameRef)> =
            members.iter().map(|&i| (i, data.frame(i))).collect();
        st.likelihood.pattern(st.base, &m).unwrap().log_marginal()
    });
    let store = Store::in_process_shards(cut(&data, &[1, 2, 2])).unwrap();
    let mut s = SubclusterSampler::with_store(store, st).unwrap();
    let ls = s.settings().base.length_scales;
    s.set_state(&[0, 1, 2, 3, 4], &[ls; 5], None, 1.0).unwrap();
    let sweeps = 60_000;
    let mut freq: HashMap<Vec<usize>, f64> = HashMap::new();
    for _ in 0..sweeps {
        s.sweep(&|| false).unwrap();
        *freq.entry(canonical(s.labels())).or_default() += 1.0 / sweeps as f64;
    }
    let d = tv(&freq, &exact);
    eprintln!("three shards: TV {d:.4}");
    assert!(d <= 0.03, "TV {d:.4} > 0.03");
}

#[test]
fn shards_out_of_order_are_refused() {
    let data = tiny();
    let mut shards = cut(&data, &[2, 3]);
    shards.swap(0, 1);
    let err = Store::in_process_shards(shards).unwrap_err();
    assert!(err.to_string().contains("in order"), "{err}");
    assert!(Store::sharded(&[2, 0], Arc::new(InProcess(Vec::new()))).is_err());
}

#[test]
fn held_label_requests_and_replies_cross_as_bytes() {
    let bank = Bank {
        weights: vec![[vec![0.5; 6], vec![-1.0; 6]]],
        noise: vec![[0.3, 0.4]],
        mean: [0.1, -0.2],
    };
    let key = DrawKey {
        seed: 3,
        sweep: 4,
        phase: 5,
        map: false,
    };
    let requests = [
        Request::SetLabels {
            chain: 2,
            labels: vec![4, 0, 4],
        },
        Request::Pass {
            chain: 2,
            basis: basis(),
            bank,
            log_w: vec![-0.5],
            slots: vec![4],
            key,
        },
        Request::Events {
            chain: 2,
            risk: vec![true, false],
        },
        Request::Move {
            chain: 2,
            basis: basis(),
            stays: vec![1, 5],
            rebuild: true,
        },
        Request::Labels { chain: 9 },
        Request::Forget { chain: 9 },
    ];
    for r in requests {
        let bytes = r.encode();
        assert_eq!(Request::decode(&bytes).unwrap(), r);
        for cut in 0..bytes.len() {
            assert!(Request::decode(&bytes[..cut]).is_err());
        }
    }
    let mut s = Sums::zeros(&basis());
    s.n_frames = 2;
    s.h[1] = 0.25;
    let replies = [
        Reply::Done,
        Reply::Proposal {
            keeps: vec![true, false, true],
            leaving: 7,
        },
        Reply::Events(vec![(1, 2, 0), (4, 0, 2)]),
        Reply::Moved {
            pairs: vec![[3, 1], [1, 3]],
            sums: vec![s.clone(), s],
        },
        Reply::Labels(vec![1, 1, 0]),
    ];
    for r in replies {
        let bytes = r.encode();
        assert_eq!(Reply::decode(&bytes).unwrap(), r);
        for cut in 0..bytes.len() {
            assert!(Reply::decode(&bytes[..cut]).is_err());
        }
    }
}

/// A link that counts the requests for events it passes on.
#[derive(Debug)]
struct Counted(Bytes, std::sync::atomic::AtomicUsize);

impl Link for Counted {
    fn run(&self, jobs: Vec<(usize, Request)>) -> Result<Vec<Reply>> {
        let n = jobs
            .iter()
            .filter(|(_, r)| matches!(r, Request::Events { .. }))
            .count();
        self.1.fetch_add(n, std::sync::atomic::Ordering::Relaxed);
        self.0.run(jobs)
    }
}

/// `n` frames of two to four points, their velocities in three groups.
fn frames(n: usize) -> Data {
    let mut u = crate::test_util::uniform(3u64);
    let (mut xy, mut v, mut offsets) = (Vec::new(), Vec::new(), vec![0]);
    for i in 0..n {
        let shift = 1.5 * (i % 3) as f64;
        for _ in 0..(2 + i % 3) {
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

fn bits(s: &Sums) -> String {
    format!("{s:?}")
}

#[test]
fn a_pass_over_held_labels_is_the_leaders_pass() {
    let data = frames(600);
    let sizes = [200, 250, 150];
    let leader = Store::in_process_shards(cut(&data, &sizes)).unwrap();
    let mut s = SubclusterSampler::with_store(leader, settings(9)).unwrap();
    s.initialize(Start::Many, &|| false).unwrap();
    // Shards that hold the labels, reached through bytes as workers are.
    let link = Arc::new(Counted(Bytes(cut(&data, &sizes)), Default::default()));
    let held = Store::sharded(&sizes, Arc::clone(&link) as Arc<dyn Link>).unwrap();
    let chain = 7;
    held.set_held_labels(chain, s.labels()).unwrap();
    let (mut rebuilt, mut paired) = (0, 0);
    for sweep in 0..40 {
        let mut c = s.clone();
        c.sweep += 1;
        let (slots, bank, log_w) = c.pass_bank().unwrap();
        let counts: Vec<usize> = slots.iter().map(|&k| c.part(k).sums.n_frames).collect();
        let key = c.draw_key(c.sweep, crate::rng::Phase::Labels);
        let before = c.labels().to_vec();
        let got = held
            .held_pass(chain, &c.basis, &bank, &log_w, &slots, &counts, key)
            .unwrap();
        let moved = c.assignment_pass(&|| false).unwrap();
        let after = c.labels().to_vec();
        assert_eq!(held.held_labels(chain).unwrap(), after, "sweep {sweep}");
        let store = c.store();
        match got {
            Moved::Rebuilt { moved: m, sums } => {
                rebuilt += 1;
                assert_eq!(m, moved);
                let mut index = vec![usize::MAX; c.slots.len()];
                for (j, &k) in slots.iter().enumerate() {
                    index[k] = j;
                }
                let want = store
                    .sums_of_groups(&c.basis, &after, &index, slots.len())
                    .unwrap();
                assert_eq!(
                    sums.iter().map(bits).collect::<Vec<_>>(),
                    want.iter().map(bits).collect::<Vec<_>>()
                );
            }
            Moved::Pairs { moved: m, sums } => {
                paired += 1;
                assert_eq!(m, moved);
                let mut groups: std::collections::BTreeMap<(usize, usize), Vec<usize>> =
                    Default::default();
                for (i, (&a, &b)) in before.iter().zip(&after).enumerate() {
                    if a != b {
                        groups.entry((a, b)).or_default().push(i);
                    }
                }
                assert_eq!(
                    sums.keys().collect::<Vec<_>>(),
                    groups.keys().collect::<Vec<_>>()
                );
                let sets: Vec<&[usize]> = groups.values().map(|g| &g[..]).collect();
                let want = store.sums_of_sets(&c.basis, &sets).unwrap();
                assert_eq!(
                    sums.values().map(bits).collect::<Vec<_>>(),
                    want.iter().map(bits).collect::<Vec<_>>()
                );
            }
        }
        // The rest of the sweep (moves, hyperparameters) on the leader, which sets the shards'
        // labels again where its moves changed them.
        s.sweep(&|| false).unwrap();
        held.set_held_labels(chain, s.labels()).unwrap();
    }
    assert!(
        rebuilt >= 1 && paired >= 20,
        "{rebuilt} rebuilt, {paired} by pairs"
    );
    // Passes with at-risk patterns (small patterns here: every pass has some).
    let events = link.1.load(std::sync::atomic::Ordering::Relaxed);
    assert!(events >= 3, "{events} requests for events");
    // A replaced shard holds no labels: a clear error until they are set again.
    let fresh = Store::sharded(&sizes, Arc::new(Bytes(cut(&data, &sizes)))).unwrap();
    let err = fresh.held_labels(chain).unwrap_err().to_string();
    assert!(err.contains("holds no labels"), "{err}");
    fresh.set_held_labels(chain, s.labels()).unwrap();
    assert_eq!(fresh.held_labels(chain).unwrap(), s.labels());
}

/// A chain's state as numbers: labels, α, log joint, and every pattern's slot, id, size, length
/// scales and noise, as bits.
fn state(s: &SubclusterSampler) -> (Vec<usize>, Vec<u64>, String) {
    let patterns = format!("{:?}", s.patterns());
    (
        s.gather_labels().unwrap(),
        vec![s.alpha().to_bits(), s.log_joint().to_bits()],
        patterns,
    )
}

/// The canonical order a fit rebuilds in: patterns by decreasing size, then slot.
fn canonical_groups(s: &SubclusterSampler) -> (Vec<usize>, Vec<crate::frame::LengthScales>) {
    let mut p = s.patterns();
    p.sort_by_key(|p| (std::cmp::Reverse(p.n_frames), p.slot));
    let top = p.iter().map(|p| p.slot).max().unwrap() + 1;
    let mut group = vec![usize::MAX; top];
    for (g, info) in p.iter().enumerate() {
        group[info.slot] = g;
    }
    (group, p.iter().map(|p| p.length_scales).collect())
}

/// Two chains over `data` cut into shards of `sizes`: one with the labels on the leader, one
/// with them on the shards (through bytes).
fn leader_and_held(
    data: &Data,
    sizes: &[usize],
    st: Settings,
) -> (SubclusterSampler, SubclusterSampler) {
    let leader = Store::in_process_shards(cut(data, sizes)).unwrap();
    let a = SubclusterSampler::with_store(leader, st.clone()).unwrap();
    let link = Arc::new(Bytes(cut(data, sizes)));
    let held = Store::sharded(sizes, link as Arc<dyn Link>).unwrap();
    let mut b = SubclusterSampler::with_store(held, st).unwrap();
    b.hold_labels_on_shards().unwrap();
    (a, b)
}

/// The chain over 600 frames in 3 shards from `start`, with the labels on the leader and on the
/// shards (through bytes), compared at every step; the moves' counts.
fn compare_held(start: Start) -> (crate::gibbs::SplitMergeStats, super::super::PeelStats) {
    let data = frames(600);
    let sizes = [200, 250, 150];
    let mut st = settings(9);
    st.fixed_length_scales = false;
    st.alpha = None;
    st.split_merge.moves_per_sweep = 6;
    let (mut a, mut b) = leader_and_held(&data, &sizes, st);
    a.initialize(start, &|| false).unwrap();
    b.initialize(start, &|| false).unwrap();
    assert!(b.labels().is_empty(), "the leader keeps no label");
    assert_eq!(state(&a), state(&b));
    let mut previous = a.labels().to_vec();
    for sweep in 0..60 {
        let ra = a.sweep(&|| false).unwrap();
        let rb = b.sweep(&|| false).unwrap();
        assert_eq!(ra.moves, rb.moves, "sweep {sweep}");
        assert_eq!(state(&a), state(&b), "sweep {sweep}");
        assert!(b.labels().is_empty());
        // The table since the last mark is the contingency of the leader's two labellings.
        let mut want: std::collections::BTreeMap<(usize, usize), u64> = Default::default();
        for (&x, &y) in previous.iter().zip(a.labels()) {
            *want.entry((x, y)).or_default() += 1;
        }
        let got: Vec<[u64; 3]> = b.label_table().unwrap().unwrap();
        let want: Vec<[u64; 3]> = want
            .into_iter()
            .map(|((x, y), c)| [x as u64, y as u64, c])
            .collect();
        assert_eq!(got, want, "sweep {sweep}");
        previous = a.labels().to_vec();
        if sweep % 7 == 3 {
            // A canonical rebuild: the shards relabel and sum, no label crosses.
            let (group, ls) = canonical_groups(&a);
            let labels: Vec<usize> = a.labels().iter().map(|&l| group[l]).collect();
            let (alpha, noise) = (a.alpha(), a.noise_var());
            a.set_state(&labels, &ls, None, alpha).unwrap();
            b.regroup(&group, &ls, None, alpha).unwrap();
            assert_eq!(state(&a), state(&b), "rebuild at sweep {sweep}");
            assert_eq!(a.noise_var(), noise);
        }
        if sweep % 11 == 5 {
            // The state set again (a replaced worker, a resume): a new chain number.
            let before = b.held_chain();
            let labels = a.labels().to_vec();
            let infos = a.patterns();
            let slot_group: std::collections::HashMap<usize, usize> =
                infos.iter().enumerate().map(|(g, p)| (p.slot, g)).collect();
            let groups: Vec<usize> = labels.iter().map(|l| slot_group[l]).collect();
            let ls: Vec<_> = infos.iter().map(|p| p.length_scales).collect();
            a.set_state(&groups, &ls, None, a.alpha()).unwrap();
            b.set_state(&groups, &ls, None, b.alpha()).unwrap();
            assert_ne!(b.held_chain(), before);
            assert_eq!(state(&a), state(&b), "set at sweep {sweep}");
            // The labels under the last number are gone from every shard.
            let err = b.store().held_labels(before.unwrap()).unwrap_err();
            assert!(err.to_string().contains("holds no labels"), "{err}");
            previous = a.labels().to_vec();
            b.label_table().unwrap();
        }
    }
    assert_eq!((b.split_merge, b.peels), (a.split_merge, a.peels));
    (b.split_merge, b.peels)
}

#[test]
fn a_chain_whose_shards_hold_its_labels_is_the_leaders_chain() {
    // From one pattern (splits) and from many (merges), with peels and absorbs on the way.
    let (one, peels) = compare_held(Start::One);
    let (many, _) = compare_held(Start::Many);
    eprintln!("{one:?} {many:?} {peels:?}");
    assert!(
        one.split_accepted >= 1 && many.merge_accepted >= 1,
        "{one:?} {many:?}"
    );
    assert!(
        peels.peel_accepted >= 1 && peels.absorb_accepted >= 1,
        "{peels:?}"
    );
}

#[test]
fn new_held_label_requests_cross_as_bytes() {
    let requests = [
        Request::LabelsOf {
            chain: 1,
            frames: vec![3, 0],
        },
        Request::Members {
            chain: 1,
            slots: vec![2, 5],
        },
        Request::Find {
            chain: 1,
            slots: vec![2],
            nth: u64::MAX,
        },
        Request::Relabel {
            chain: 1,
            map: vec![[1, 4], [2, 4]],
            frames: vec![7],
            to: 3,
        },
        Request::Regroup {
            chain: 1,
            basis: basis(),
            map: vec![1, u32::MAX, 0],
            n: 2,
        },
        Request::Table { chain: 4 },
    ];
    for r in requests {
        let bytes = r.encode();
        assert_eq!(Request::decode(&bytes).unwrap(), r);
        for cut in 0..bytes.len() {
            assert!(Request::decode(&bytes[..cut]).is_err());
        }
    }
    let replies = [
        Reply::Members {
            frames: vec![1, 4],
            which: vec![0, 1],
        },
        Reply::Found {
            count: 3,
            hit: Some([2, 9]),
        },
        Reply::Found {
            count: 0,
            hit: None,
        },
        Reply::Table(vec![[0, 1, 5], [2, 2, 1]]),
    ];
    for r in replies {
        let bytes = r.encode();
        assert_eq!(Reply::decode(&bytes).unwrap(), r);
        for cut in 0..bytes.len() {
            assert!(Reply::decode(&bytes[..cut]).is_err());
        }
    }
}

/// The coarsened start relabels on the shards as on the leader: from six interleaved groups of
/// 600 frames in 3 shards, both chains merge the same patterns, then sweep alike.
#[test]
fn the_coarsened_start_is_the_same_with_the_labels_on_the_shards() {
    let data = frames(600);
    let sizes = [200, 250, 150];
    let st = settings(4);
    let (mut a, mut b) = leader_and_held(&data, &sizes, st);
    let groups: Vec<usize> = (0..600).map(|f| f % 6).collect();
    let ls = vec![a.settings().base.length_scales; 6];
    for s in [&mut a, &mut b] {
        s.set_state(&groups, &ls, None, 1.0).unwrap();
        s.coalesce(&|| false).unwrap();
    }
    assert!(a.patterns().len() < 6, "nothing merged: {:?}", a.patterns());
    assert!(b.labels().is_empty(), "the leader keeps no label");
    assert_eq!(state(&a), state(&b));
    for sweep in 0..10 {
        a.sweep(&|| false).unwrap();
        b.sweep(&|| false).unwrap();
        assert_eq!(state(&a), state(&b), "sweep {sweep}");
    }
}
