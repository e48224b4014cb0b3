//! The shard-by-shard resolution of the "last frame" rule moves exactly the frames the
//! sequential walk moves: on constructed cases (a pattern all of whose frames want to leave,
//! split across shards; at-risk patterns feeding each other) and on many random ones.

use super::*;

/// The pass's sequential walk over all frames: the moves `(frame, from slot, to slot)`.
fn sequential(labels: &[usize], picks: &[u32], slots: &[usize]) -> Vec<(usize, usize, usize)> {
    let mut counts = vec![0usize; slots.iter().max().map_or(0, |m| m + 1)];
    for &l in labels {
        counts[l] += 1;
    }
    let mut out = Vec::new();
    for (i, (&from, &p)) in labels.iter().zip(picks).enumerate() {
        let to = slots[p as usize];
        if to != from && counts[from] > 1 {
            counts[from] -= 1;
            counts[to] += 1;
            out.push((i, from, to));
        }
    }
    out
}

/// The same moves, found shard by shard (`sizes` frames each) as a sharded pass finds them;
/// also the events the leader saw.
fn by_shard(
    labels: &[usize],
    picks: &[u32],
    slots: &[usize],
    sizes: &[usize],
) -> (Vec<(usize, usize, usize)>, usize) {
    let k = slots.len();
    let mut index = vec![u32::MAX; slots.iter().max().map_or(0, |m| m + 1)];
    for (b, &s) in slots.iter().enumerate() {
        index[s] = b as u32;
    }
    let mut ranges = Vec::new();
    let mut a = 0;
    for &n in sizes {
        ranges.push(a..a + n);
        a += n;
    }
    assert_eq!(a, labels.len());
    // Each shard's labels as its own u32 vector: what a worker holds.
    let held: Vec<Vec<u32>> = ranges
        .iter()
        .map(|r| labels[r.clone()].iter().map(|&l| l as u32).collect())
        .collect();
    let proposals: Vec<Proposal> = ranges
        .iter()
        .zip(&held)
        .map(|(r, l)| propose(l, &picks[r.clone()], &index, k))
        .collect();
    let risk = at_risk(&proposals);
    let mut counts = vec![0; k];
    for &l in labels {
        counts[index[l] as usize] += 1;
    }
    let evs: Vec<Vec<Event>> = ranges
        .iter()
        .zip(&held)
        .map(|(r, l)| events(l, &picks[r.clone()], &index, &risk))
        .collect();
    let n_events = evs.iter().map(Vec::len).sum();
    let stays = resolve(&counts, &risk, &evs);
    let mut out = Vec::new();
    for ((r, l), st) in ranges.iter().zip(&held).zip(&stays) {
        let m = moves(l, &picks[r.clone()], slots, st);
        out.extend(m.into_iter().map(|(i, f, t)| (r.start + i, f, t)));
    }
    let leaving: usize = proposals.iter().map(|p| p.leaving).sum();
    let stayed: usize = stays.iter().map(Vec::len).sum();
    assert_eq!(out.len(), leaving - stayed, "the moves the leader counts");
    (out, n_events)
}

#[test]
fn a_pattern_whose_frames_all_want_to_leave_keeps_its_last_across_shards() {
    // Pattern (slot) 7 holds frames 1, 4 and 6, all drawn elsewhere; the shards cut it 0..3 |
    // 3..5 | 5..8. Frames 1 and 4 leave, frame 6 stays (its last).
    let slots = [7, 2];
    let labels = [2, 7, 2, 2, 7, 2, 7, 2];
    let picks = [1, 1, 1, 1, 1, 1, 1, 1];
    let (got, n) = by_shard(&labels, &picks, &slots, &[3, 2, 3]);
    assert_eq!(got, vec![(1, 7, 2), (4, 7, 2)]);
    assert_eq!(got, sequential(&labels, &picks, &slots));
    assert_eq!(n, 3, "only the at-risk pattern's departures cross");
}

#[test]
fn an_arrival_in_an_earlier_shard_lets_the_last_frame_go() {
    // Frame 0 (pattern 2, kept by frame 3) arrives in pattern 7 before either of 7's frames is
    // walked: both of 7's frames may then leave (for pattern 5, kept by frame 5).
    let slots = [7, 2, 5];
    let labels = [2, 7, 2, 2, 7, 5];
    let picks = [0, 2, 0, 1, 2, 2];
    let want = sequential(&labels, &picks, &slots);
    assert_eq!(want, vec![(0, 2, 7), (1, 7, 5), (2, 2, 7), (4, 7, 5)]);
    for sizes in [&[1, 5][..], &[2, 2, 2], &[6], &[1, 1, 1, 1, 1, 1]] {
        assert_eq!(
            by_shard(&labels, &picks, &slots, sizes).0,
            want,
            "{sizes:?}"
        );
    }
}

#[test]
fn at_risk_patterns_feeding_each_other_are_walked_in_frame_order() {
    // Patterns 0 and 1 (slots 3, 4) both at risk, each frame drawn into the other: a chain of
    // refusals and arrivals that only the walk in frame order gets right.
    let slots = [3, 4];
    let labels = [3, 4, 4, 3, 4, 3];
    let picks = [1, 0, 0, 1, 0, 1];
    let want = sequential(&labels, &picks, &slots);
    for sizes in [&[3, 3][..], &[1, 2, 3], &[5, 1], &[6]] {
        assert_eq!(
            by_shard(&labels, &picks, &slots, sizes).0,
            want,
            "{sizes:?}"
        );
    }
}

#[test]
fn a_kept_pattern_never_refuses_and_sends_nothing() {
    let slots = [0, 1];
    let labels = [0, 0, 0, 1, 1];
    let picks = [1, 0, 1, 0, 1];
    let (got, n) = by_shard(&labels, &picks, &slots, &[2, 3]);
    assert_eq!(got, sequential(&labels, &picks, &slots));
    assert_eq!(got.len(), 3);
    assert_eq!(n, 0);
}

#[test]
fn random_passes_move_the_frames_the_sequential_walk_moves() {
    let mut u = crate::test_util::uniform(17u64);
    let mut at_risk_seen = 0;
    for case in 0..3000 {
        let n = 1 + (u() * 40.0) as usize;
        let k = 1 + (u() * 6.0) as usize;
        // Slots with gaps, in no particular order: as a sampler's live slots are.
        let slots: Vec<usize> = (0..k).map(|b| 3 * (k - b) + case % 2).collect();
        // Every pattern holds a frame; the rest anywhere.
        let mut labels: Vec<usize> = (0..n)
            .map(|i| {
                if i < k {
                    slots[i]
                } else {
                    slots[(u() * k as f64) as usize % k]
                }
            })
            .collect();
        for i in (1..n).rev() {
            labels.swap(i, (u() * (i + 1) as f64) as usize % (i + 1));
        }
        let k_live: Vec<usize> = slots
            .iter()
            .copied()
            .filter(|s| labels.contains(s))
            .collect();
        // Draws biased away from the frame's own pattern, so that patterns are often at risk.
        let picks: Vec<u32> = labels
            .iter()
            .map(|&l| {
                let own = slots.iter().position(|&s| s == l).unwrap();
                let p = (u() * k as f64) as usize % k;
                if p == own && u() < 0.8 {
                    ((p + 1) % k) as u32
                } else {
                    p as u32
                }
            })
            .collect();
        let mut sizes = Vec::new();
        let mut left = n;
        while left > 0 {
            let s = 1 + (u() * left as f64) as usize % left;
            sizes.push(s);
            left -= s;
        }
        assert_eq!(k_live.len(), k.min(n));
        let (got, events) = by_shard(&labels, &picks, &slots, &sizes);
        at_risk_seen += usize::from(events > 0);
        assert_eq!(got, sequential(&labels, &picks, &slots), "case {case}");
    }
    assert!(
        at_risk_seen > 1000,
        "{at_risk_seen} cases with at-risk patterns"
    );
}
