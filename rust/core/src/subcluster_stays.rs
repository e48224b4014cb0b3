//! The assignment pass's "last frame" rule resolved shard by shard, so that a shard can decide
//! its frames' moves from its own labels and draws, and the leader sees only the rare frames
//! whose fate depends on other shards.
//!
//! **The rule.** In frame order, a frame moves to its draw unless it would leave its pattern
//! empty (`subcluster.rs`, "Exact"). A frame that draws the pattern it is in never leaves, so a
//! pattern holding such a frame keeps at least that frame and at least one more while another
//! of its frames is leaving: no departure from it is ever refused. Only a pattern none of whose
//! frames draw it (*at risk*) can refuse one, and whether it does depends only on the departures
//! from it and the arrivals into it, in frame order. An arrival from a pattern not at risk always
//! happens; one from an at-risk pattern is that pattern's departure, decided by the same walk.
//!
//! **Rounds.** Each shard reports, per pattern, whether one of its frames drew its own pattern
//! ([`propose`]); the leader takes the patterns no shard keeps ([`at_risk`]). When there are any,
//! each shard lists its frames moving from or into them ([`events`]: integers, in frame order);
//! the leader walks those lists in shard order, which is frame order, with the counts of the
//! at-risk patterns, and returns the frames that stay ([`resolve`]). Every other frame moves to
//! its draw ([`moves`]). The frames that move are exactly those of the sequential walk.

/// A frame's label: the slot of its pattern.
pub trait Label: Copy {
    fn slot(self) -> usize;
}

impl Label for usize {
    fn slot(self) -> usize {
        self
    }
}

impl Label for u32 {
    fn slot(self) -> usize {
        self as usize
    }
}

/// One shard's draws as the leader needs them: for each of the bank's patterns, whether a frame
/// of the shard drew the pattern it is in, and how many of its frames drew another.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Proposal {
    pub keeps: Vec<bool>,
    pub leaving: usize,
}

/// A frame moving from or into an at-risk pattern: `(frame, from, to)`, the frame's number in
/// its shard and the two patterns as indices into the bank.
pub type Event = (u32, u32, u32);

/// The summary of a shard's draws `picks` (indices into a bank of `k` patterns) for frames with
/// `labels`, `index[slot]` being a slot's index in the bank.
pub fn propose<L: Label>(labels: &[L], picks: &[u32], index: &[u32], k: usize) -> Proposal {
    let mut keeps = vec![false; k];
    let mut leaving = 0;
    for (&l, &p) in labels.iter().zip(picks) {
        let from = index[l.slot()];
        if from == p {
            keeps[p as usize] = true;
        } else {
            leaving += 1;
        }
    }
    Proposal { keeps, leaving }
}

/// The patterns no shard keeps.
pub fn at_risk(proposals: &[Proposal]) -> Vec<bool> {
    let k = proposals.first().map_or(0, |p| p.keeps.len());
    (0..k)
        .map(|b| !proposals.iter().any(|p| p.keeps[b]))
        .collect()
}

/// A shard's frames whose draw moves them from or into an at-risk pattern, in frame order.
pub fn events<L: Label>(labels: &[L], picks: &[u32], index: &[u32], risk: &[bool]) -> Vec<Event> {
    labels
        .iter()
        .zip(picks)
        .enumerate()
        .filter_map(|(i, (&l, &to))| {
            let from = index[l.slot()];
            (from != to && (risk[from as usize] || risk[to as usize]))
                .then_some((i as u32, from, to))
        })
        .collect()
}

/// The sequential rule over every shard's events (in shard order, which is frame order), given
/// each pattern's frames before the pass (`counts`, by bank index): the frames that stay, per
/// shard, in frame order.
pub fn resolve(counts: &[usize], risk: &[bool], events: &[Vec<Event>]) -> Vec<Vec<u32>> {
    let mut counts = counts.to_vec();
    events
        .iter()
        .map(|shard| {
            let mut stays = Vec::new();
            for &(i, from, to) in shard {
                let (from, to) = (from as usize, to as usize);
                // A pattern not at risk always has another frame to keep it.
                if risk[from] && counts[from] <= 1 {
                    stays.push(i);
                } else {
                    counts[from] -= 1;
                    counts[to] += 1;
                }
            }
            stays
        })
        .collect()
}

/// A shard's moves `(frame, from slot, to slot)` in frame order: every frame whose draw is
/// another pattern, but `stays` (sorted), `slots[b]` being the slot of the bank's pattern `b`.
pub fn moves<L: Label>(
    labels: &[L],
    picks: &[u32],
    slots: &[usize],
    stays: &[u32],
) -> Vec<(usize, usize, usize)> {
    let mut stays = stays.iter().peekable();
    let mut out = Vec::new();
    for (i, (&l, &p)) in labels.iter().zip(picks).enumerate() {
        let (from, to) = (l.slot(), slots[p as usize]);
        if to == from {
            continue;
        }
        if stays.peek() == Some(&&(i as u32)) {
            stays.next();
            continue;
        }
        out.push((i, from, to));
    }
    out
}

#[cfg(test)]
#[path = "tests/subcluster_stays.rs"]
mod tests;
