//! Labels held by the shards: each shard keeps its frames' labels per chain, and an assignment
//! pass runs as a few rounds in which the leader sends the bank and receives per-pattern
//! statistics, never a label per frame (issue 33, "Labels stay on the workers").
//!
//! **Rounds of a pass** ([`Store::held_pass`]):
//! 1. [`Request::Pass`]: every shard draws its frames' labels under the bank, keeps the draws,
//!    and answers with a [`Proposal`] (which patterns one of its frames keeps, how many leave).
//! 2. Only when some pattern is at risk (no shard keeps it: rare), [`Request::Events`]: each shard
//!    lists its frames moving from or into those patterns, and the leader resolves the "last
//!    frame" rule over them (`subcluster_stays.rs`).
//! 3. [`Request::Move`]: every shard moves its frames but those that stay, and answers with the
//!    sums of its moved frames per (from, to) pair of patterns, or, when most frames moved, with
//!    every pattern's sums. The leader adds them up in shard order: the numbers the leader's own
//!    pass computes from the labels (`Store::sums_of_sets`, `Store::sums_of_groups`), bitwise.
//!
//! A shard's labels are state a lost worker loses: the leader must be able to set them again
//! ([`Request::SetLabels`], from a checkpoint or a copy kept since the last finished sweep).

use std::collections::BTreeMap;

use super::super::stays::{self, Event, Proposal};
use super::{Bank, DrawKey, Reply, Request, Shard, Store, wrong_reply};
use crate::basis::Basis;
use crate::error::{Error, Result};
use crate::hsgp_sums::Sums;

/// A chain's state on a shard: each frame's label (a slot), and the last pass's draws (indices
/// into `slots`, the bank's patterns) until they are applied.
#[derive(Clone, Debug, Default)]
pub(super) struct Held {
    labels: Vec<u32>,
    picks: Vec<u32>,
    slots: Vec<u32>,
    /// The labels when they were set or last marked ([`Request::Table`]).
    mark: Vec<u32>,
}

/// What the leader learns from a pass over held labels.
#[derive(Clone, Debug, PartialEq)]
pub enum Moved {
    /// The frames that moved, and the sums of each (from, to) pair's moved frames.
    Pairs {
        moved: usize,
        sums: BTreeMap<(usize, usize), Sums>,
    },
    /// Most frames moved: every pattern's sums (in the order of the bank's slots).
    Rebuilt { moved: usize, sums: Vec<Sums> },
}

impl Shard {
    fn held<T>(&self, chain: u64, f: impl FnOnce(&mut Held) -> Result<T>) -> Result<T> {
        let mut all = self.held.lock().unwrap_or_else(|e| e.into_inner());
        match all.get_mut(&chain) {
            Some(h) => f(h),
            None => Err(Error::LabelsLost(format!(
                "a shard holds no labels of chain {chain} (a replaced worker: set them again)"
            ))),
        }
    }

    /// Answer a request about held labels (`None`: not one).
    pub(super) fn handle_held(&self, request: &Request) -> Result<Option<Reply>> {
        let n = self.len();
        Ok(Some(match request {
            Request::SetLabels { chain, labels } => {
                if labels.len() != n {
                    return Err(Error::Shape(format!(
                        "{} labels for a shard of {n} frames",
                        labels.len()
                    )));
                }
                let held = Held {
                    labels: labels.clone(),
                    mark: labels.clone(),
                    ..Held::default()
                };
                let mut all = self.held.lock().unwrap_or_else(|e| e.into_inner());
                all.insert(*chain, held);
                Reply::Done
            }
            Request::Pass {
                chain,
                basis,
                bank,
                log_w,
                slots,
                key,
            } => {
                let k = slots.len();
                let picks = self.draw(basis, bank, log_w, 0..n as u32, *key)?;
                self.held(*chain, |h| {
                    let index = slot_index(slots, &h.labels)?;
                    let p = stays::propose(&h.labels, &picks, &index, k);
                    h.picks = picks;
                    h.slots = slots.clone();
                    Ok(Reply::Proposal {
                        keeps: p.keeps,
                        leaving: p.leaving as u64,
                    })
                })?
            }
            Request::Events { chain, risk } => self.held(*chain, |h| {
                check_drawn(h, risk.len())?;
                let index = slot_index(&h.slots, &h.labels)?;
                Ok(Reply::Events(stays::events(
                    &h.labels, &h.picks, &index, risk,
                )))
            })?,
            Request::Move {
                chain,
                basis,
                stays: kept,
                rebuild,
            } => {
                // The moves are made under the lock; the sums, the long part, after it.
                let sets = self.held(*chain, |h| {
                    check_drawn(h, h.slots.len())?;
                    if kept.windows(2).any(|w| w[0] >= w[1]) || kept.last() >= Some(&(n as u32)) {
                        return Err(Error::InvalidInput(
                            "the frames that stay must be increasing frames of the shard".into(),
                        ));
                    }
                    let slots: Vec<usize> = h.slots.iter().map(|&s| s as usize).collect();
                    let moves = stays::moves(&h.labels, &h.picks, &slots, kept);
                    for &(i, _, to) in &moves {
                        h.labels[i] = to as u32;
                    }
                    h.picks = Vec::new();
                    Ok(if *rebuild {
                        let index = slot_index(&h.slots, &h.labels)?;
                        let mut sets = vec![(Vec::new(), Vec::new()); slots.len()];
                        for (b, s) in sets.iter_mut().enumerate() {
                            s.0 = vec![h.slots[b]; 2];
                        }
                        for (i, &l) in h.labels.iter().enumerate() {
                            sets[index[l as usize] as usize].1.push(i as u32);
                        }
                        sets
                    } else {
                        let mut groups: BTreeMap<(u32, u32), Vec<u32>> = BTreeMap::new();
                        for (i, from, to) in moves {
                            groups
                                .entry((from as u32, to as u32))
                                .or_default()
                                .push(i as u32);
                        }
                        groups
                            .into_iter()
                            .map(|((f, t), g)| (vec![f, t], g))
                            .collect()
                    })
                })?;
                let (pairs, frames): (Vec<Vec<u32>>, Vec<Vec<u32>>) = sets.into_iter().unzip();
                Reply::Moved {
                    pairs: pairs.into_iter().map(|p| [p[0], p[1]]).collect(),
                    sums: self.sums(basis, &frames),
                }
            }
            Request::Labels { chain } => {
                self.held(*chain, |h| Ok(Reply::Labels(h.labels.clone())))?
            }
            Request::Forget { chain } => {
                let mut all = self.held.lock().unwrap_or_else(|e| e.into_inner());
                all.remove(chain);
                Reply::Done
            }
            Request::LabelsOf { chain, frames } => self.held(*chain, |h| {
                let labels = frames
                    .iter()
                    .map(|&f| {
                        h.labels
                            .get(f as usize)
                            .copied()
                            .ok_or_else(|| outside(f, n))
                    })
                    .collect::<Result<_>>()?;
                Ok(Reply::Labels(labels))
            })?,
            Request::Members { chain, slots } => self.held(*chain, |h| {
                let (mut frames, mut which) = (Vec::new(), Vec::new());
                for (i, l) in h.labels.iter().enumerate() {
                    if let Some(w) = slots.iter().position(|s| s == l) {
                        frames.push(i as u32);
                        which.push(w as u32);
                    }
                }
                Ok(Reply::Members { frames, which })
            })?,
            Request::Find { chain, slots, nth } => self.held(*chain, |h| {
                let inside = mask(slots, &h.labels);
                let mut count = 0u64;
                let mut hit = None;
                for (i, &l) in h.labels.iter().enumerate() {
                    if inside[l as usize] {
                        if count == *nth {
                            hit = Some([i as u32, l]);
                        }
                        count += 1;
                    }
                }
                Ok(Reply::Found { count, hit })
            })?,
            Request::Relabel {
                chain,
                map,
                frames,
                to,
            } => self.held(*chain, |h| {
                if let Some(&f) = frames.iter().find(|&&f| f as usize >= n) {
                    return Err(outside(f, n));
                }
                if !map.is_empty() {
                    for l in h.labels.iter_mut() {
                        if let Some(m) = map.iter().find(|m| m[0] == *l) {
                            *l = m[1];
                        }
                    }
                }
                for &f in frames {
                    h.labels[f as usize] = *to;
                }
                Ok(Reply::Done)
            })?,
            Request::Regroup {
                chain,
                basis,
                map,
                n: groups,
            } => {
                let sets = self.held(*chain, |h| {
                    let new: Vec<u32> = h
                        .labels
                        .iter()
                        .map(|&l| match map.get(l as usize) {
                            Some(&g) if g < *groups => Ok(g),
                            _ => Err(Error::InvalidInput(
                                "a regrouping leaves a frame's label without a group".into(),
                            )),
                        })
                        .collect::<Result<_>>()?;
                    let mut sets = vec![Vec::new(); *groups as usize];
                    for (i, &g) in new.iter().enumerate() {
                        sets[g as usize].push(i as u32);
                    }
                    h.labels = new;
                    h.picks = Vec::new();
                    Ok(sets)
                })?;
                Reply::Sums(self.sums(basis, &sets))
            }
            Request::Table { chain } => self.held(*chain, |h| {
                let mut table: BTreeMap<(u32, u32), u32> = BTreeMap::new();
                for (&a, &b) in h.mark.iter().zip(&h.labels) {
                    *table.entry((a, b)).or_default() += 1;
                }
                h.mark = h.labels.clone();
                Ok(Reply::Table(
                    table.into_iter().map(|((a, b), c)| [a, b, c]).collect(),
                ))
            })?,
            _ => return Ok(None),
        }))
    }
}

/// Each slot's index among `slots` (`u32::MAX` for others), refusing labels of other slots.
fn slot_index(slots: &[u32], labels: &[u32]) -> Result<Vec<u32>> {
    let top = slots
        .iter()
        .chain(labels)
        .max()
        .map_or(0, |&m| m as usize + 1);
    let mut index = vec![u32::MAX; top];
    for (b, &s) in slots.iter().enumerate() {
        index[s as usize] = b as u32;
    }
    if labels.iter().any(|&l| index[l as usize] == u32::MAX) {
        return Err(Error::InvalidInput(
            "a shard holds a label that is not one of the pass's patterns".into(),
        ));
    }
    Ok(index)
}

/// Whether each label up to the largest of `slots` and `labels` is one of `slots`.
fn mask(slots: &[u32], labels: &[u32]) -> Vec<bool> {
    let top = slots
        .iter()
        .chain(labels)
        .max()
        .map_or(0, |&m| m as usize + 1);
    let mut inside = vec![false; top];
    for &s in slots {
        inside[s as usize] = true;
    }
    inside
}

fn outside(f: u32, n: usize) -> Error {
    Error::InvalidInput(format!(
        "a shard request names frame {f} of a shard of {n} frames"
    ))
}

fn check_drawn(h: &Held, k: usize) -> Result<()> {
    if h.picks.len() != h.labels.len() || h.slots.len() != k {
        return Err(Error::InvalidInput(
            "a shard was asked to resolve a pass it has not drawn".into(),
        ));
    }
    Ok(())
}

impl Store {
    /// Give each shard its frames' labels (slots) for `chain`: `labels` over all frames.
    pub fn set_held_labels(&self, chain: u64, labels: &[usize]) -> Result<()> {
        if labels.len() != self.len() {
            return Err(Error::Shape(format!(
                "{} labels for {} frames",
                labels.len(),
                self.len()
            )));
        }
        let jobs = self
            .shard_ranges()
            .enumerate()
            .map(|(s, r)| {
                let labels = labels[r].iter().map(|&l| l as u32).collect();
                (s, Request::SetLabels { chain, labels })
            })
            .collect();
        for reply in self.link.run(jobs)? {
            let Reply::Done = reply else {
                return Err(wrong_reply("labels set"));
            };
        }
        Ok(())
    }

    /// Every frame's label as held by the shards.
    pub fn held_labels(&self, chain: u64) -> Result<Vec<usize>> {
        let jobs = (0..self.n_shards())
            .map(|s| (s, Request::Labels { chain }))
            .collect();
        let mut out = Vec::with_capacity(self.len());
        for (reply, r) in self.link.run(jobs)?.into_iter().zip(self.shard_ranges()) {
            let Reply::Labels(l) = reply else {
                return Err(wrong_reply("labels"));
            };
            if l.len() != r.len() {
                return Err(wrong_reply("labels"));
            }
            out.extend(l.into_iter().map(|l| l as usize));
        }
        Ok(out)
    }

    /// An assignment pass over the labels the shards hold for `chain`: every frame drawn under
    /// `bank` (whose patterns are `slots`, holding `counts` frames before the pass), the "last
    /// frame" rule resolved, the moves made on the shards. Returns the moved frames' sums.
    #[allow(clippy::too_many_arguments)]
    pub fn held_pass(
        &self,
        chain: u64,
        basis: &Basis,
        bank: &Bank,
        log_w: &[f64],
        slots: &[usize],
        counts: &[usize],
        key: DrawKey,
    ) -> Result<Moved> {
        let k = slots.len();
        if bank.weights.len() != k || log_w.len() != k || counts.len() != k {
            return Err(Error::Shape(format!(
                "a pass over {k} patterns needs a field, a weight and a count for each"
            )));
        }
        let all = |make: &dyn Fn() -> Request| -> Result<Vec<Reply>> {
            self.link
                .run((0..self.n_shards()).map(|s| (s, make())).collect())
        };
        let slots32: Vec<u32> = slots.iter().map(|&s| s as u32).collect();
        let proposals = all(&|| Request::Pass {
            chain,
            basis: basis.clone(),
            bank: bank.clone(),
            log_w: log_w.to_vec(),
            slots: slots32.clone(),
            key,
        })?
        .into_iter()
        .map(|r| match r {
            Reply::Proposal { keeps, leaving } if keeps.len() == k => Ok(Proposal {
                keeps,
                leaving: leaving as usize,
            }),
            _ => Err(wrong_reply("a pass")),
        })
        .collect::<Result<Vec<_>>>()?;
        let risk = stays::at_risk(&proposals);
        let kept: Vec<Vec<u32>> = if risk.contains(&true) {
            let events = all(&|| Request::Events {
                chain,
                risk: risk.clone(),
            })?
            .into_iter()
            .map(|r| match r {
                Reply::Events(e) if valid_events(&e, k) => Ok(e),
                _ => Err(wrong_reply("events")),
            })
            .collect::<Result<Vec<Vec<Event>>>>()?;
            stays::resolve(counts, &risk, &events)
        } else {
            vec![Vec::new(); self.n_shards()]
        };
        let leaving: usize = proposals.iter().map(|p| p.leaving).sum();
        let moved = leaving - kept.iter().map(Vec::len).sum::<usize>();
        // As the leader's own pass: most frames moved, every pattern's sums are rebuilt.
        let rebuild = 2 * moved > self.len();
        let jobs = kept
            .into_iter()
            .enumerate()
            .map(|(s, stays)| {
                let req = Request::Move {
                    chain,
                    basis: basis.clone(),
                    stays,
                    rebuild,
                };
                (s, req)
            })
            .collect();
        let mut pairs: BTreeMap<(usize, usize), Sums> = BTreeMap::new();
        for reply in self.link.run(jobs)? {
            let Reply::Moved { pairs: p, sums } = reply else {
                return Err(wrong_reply("moves"));
            };
            if p.len() != sums.len()
                || sums
                    .iter()
                    .any(|s| !super::same_shape(s, &Sums::zeros(basis)))
            {
                return Err(wrong_reply("moves"));
            }
            // Shard by shard from zeros: the order the leader's sums of sets add them in.
            for (pair, s) in p.into_iter().zip(sums) {
                pairs
                    .entry((pair[0] as usize, pair[1] as usize))
                    .or_insert_with(|| Sums::zeros(basis))
                    .add(&s);
            }
        }
        if !rebuild {
            return Ok(Moved::Pairs { moved, sums: pairs });
        }
        let sums = slots
            .iter()
            .map(|&s| pairs.remove(&(s, s)).unwrap_or_else(|| Sums::zeros(basis)))
            .collect();
        Ok(Moved::Rebuilt { moved, sums })
    }
}

fn valid_events(events: &[Event], k: usize) -> bool {
    events.windows(2).all(|w| w[0].0 < w[1].0)
        && events
            .iter()
            .all(|&(_, f, t)| (f as usize) < k && (t as usize) < k && f != t)
}

/// A chain number for labels held by shards: unique among the chains of this process and, with
/// the process id and the clock mixed in, practically among the leaders sharing workers.
pub fn fresh_chain_id() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(1);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    let mut h = (u64::from(std::process::id()) << 32) ^ nanos.rotate_left(17) ^ n;
    // splitmix64's finaliser: nearby inputs give unrelated numbers.
    h = (h ^ (h >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    h = (h ^ (h >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    h ^ (h >> 31)
}

impl Store {
    /// The labels the shards hold for `chain` of the frames `frames` (any order).
    pub fn held_labels_of(&self, chain: u64, frames: &[usize]) -> Result<Vec<usize>> {
        self.check_frames(frames)?;
        let parts = self.split(frames);
        let jobs = parts
            .iter()
            .map(|(s, local)| {
                let frames = local.clone();
                (*s, Request::LabelsOf { chain, frames })
            })
            .collect();
        let mut by_shard: Vec<Vec<u32>> = vec![Vec::new(); self.n_shards()];
        for ((s, local), reply) in parts.iter().zip(self.link.run(jobs)?) {
            match reply {
                Reply::Labels(l) if l.len() == local.len() => by_shard[*s] = l,
                _ => return Err(wrong_reply("labels")),
            }
        }
        let mut cursor = vec![0usize; self.n_shards()];
        Ok(frames
            .iter()
            .map(|&f| {
                let s = self.shard_of(f);
                cursor[s] += 1;
                by_shard[s][cursor[s] - 1] as usize
            })
            .collect())
    }

    fn check_frames(&self, frames: &[usize]) -> Result<()> {
        match frames.iter().find(|&&f| f >= self.len()) {
            Some(f) => Err(Error::InvalidInput(format!(
                "frame {f} of {} frames",
                self.len()
            ))),
            None => Ok(()),
        }
    }

    /// The frames (in frame order) whose held label is one of `slots`, and for each its index
    /// in `slots`.
    pub fn held_members(&self, chain: u64, slots: &[usize]) -> Result<(Vec<usize>, Vec<u32>)> {
        let slots: Vec<u32> = slots.iter().map(|&s| s as u32).collect();
        let jobs = (0..self.n_shards())
            .map(|s| {
                let slots = slots.clone();
                (s, Request::Members { chain, slots })
            })
            .collect();
        let (mut frames, mut which) = (Vec::new(), Vec::new());
        for (reply, r) in self.link.run(jobs)?.into_iter().zip(self.shard_ranges()) {
            let Reply::Members {
                frames: f,
                which: w,
            } = reply
            else {
                return Err(wrong_reply("members"));
            };
            if f.iter().any(|&i| i as usize >= r.len())
                || w.iter().any(|&k| k as usize >= slots.len())
            {
                return Err(wrong_reply("members"));
            }
            frames.extend(f.into_iter().map(|i| r.start + i as usize));
            which.extend(w);
        }
        Ok((frames, which))
    }

    /// The `nth` frame (in frame order) whose held label is one of `slots`, and its label.
    pub fn held_find(&self, chain: u64, slots: &[usize], nth: usize) -> Result<(usize, usize)> {
        let slots: Vec<u32> = slots.iter().map(|&s| s as u32).collect();
        let ask = |shards: Vec<usize>, nth: u64| -> Result<Vec<(u64, Option<[u32; 2]>)>> {
            let jobs = shards
                .into_iter()
                .map(|s| {
                    let slots = slots.clone();
                    (s, Request::Find { chain, slots, nth })
                })
                .collect();
            self.link
                .run(jobs)?
                .into_iter()
                .map(|r| match r {
                    Reply::Found { count, hit } => Ok((count, hit)),
                    _ => Err(wrong_reply("a frame found")),
                })
                .collect()
        };
        // Each shard's count, then the frame from the shard that holds it.
        let counts = ask((0..self.n_shards()).collect(), u64::MAX)?;
        let mut rest = nth as u64;
        for (s, (count, _)) in counts.into_iter().enumerate() {
            if rest < count {
                let (_, hit) = ask(vec![s], rest)?
                    .pop()
                    .ok_or_else(|| wrong_reply("a frame found"))?;
                let [f, l] = hit.ok_or_else(|| wrong_reply("a frame found"))?;
                if f as usize >= self.starts[s + 1] - self.starts[s] {
                    return Err(wrong_reply("a frame found"));
                }
                return Ok((self.starts[s] + f as usize, l as usize));
            }
            rest -= count;
        }
        Err(Error::InvalidInput(format!(
            "the shards hold fewer than {} frames of those patterns",
            nth + 1
        )))
    }

    /// Relabel the held labels: every frame labelled `map[j].0` takes `map[j].1`, then `frames`
    /// take `to`.
    pub fn held_relabel(
        &self,
        chain: u64,
        map: &[(usize, usize)],
        frames: &[usize],
        to: usize,
    ) -> Result<()> {
        self.check_frames(frames)?;
        let map: Vec<[u32; 2]> = map.iter().map(|&(a, b)| [a as u32, b as u32]).collect();
        let mut local: Vec<Vec<u32>> = vec![Vec::new(); self.n_shards()];
        for (s, l) in self.split(frames) {
            local[s] = l;
        }
        let jobs: Vec<(usize, Request)> = local
            .into_iter()
            .enumerate()
            .filter(|(_, f)| !map.is_empty() || !f.is_empty())
            .map(|(s, frames)| {
                let req = Request::Relabel {
                    chain,
                    map: map.clone(),
                    frames,
                    to: to as u32,
                };
                (s, req)
            })
            .collect();
        for reply in self.link.run(jobs)? {
            let Reply::Done = reply else {
                return Err(wrong_reply("a relabelling"));
            };
        }
        Ok(())
    }

    /// Relabel every held label `l` as `map[l]` (each below `n`) and return the sums of the
    /// frames of each new label: [`Store::sums_of_groups`] of the relabelled frames, bitwise.
    pub fn held_regroup(
        &self,
        chain: u64,
        basis: &Basis,
        map: &[usize],
        n: usize,
    ) -> Result<Vec<Sums>> {
        let map: Vec<u32> = map
            .iter()
            .map(|&g| if g < n { g as u32 } else { u32::MAX })
            .collect();
        let jobs = (0..self.n_shards())
            .map(|s| {
                let req = Request::Regroup {
                    chain,
                    basis: basis.clone(),
                    map: map.clone(),
                    n: n as u32,
                };
                (s, req)
            })
            .collect();
        let mut out: Vec<Sums> = (0..n).map(|_| Sums::zeros(basis)).collect();
        for reply in self.link.run(jobs)? {
            let Reply::Sums(parts) = reply else {
                return Err(wrong_reply("sums"));
            };
            if parts.len() != n
                || parts
                    .iter()
                    .any(|p| !super::same_shape(p, &Sums::zeros(basis)))
            {
                return Err(wrong_reply("sums"));
            }
            for (o, p) in out.iter_mut().zip(&parts) {
                o.add(p);
            }
        }
        Ok(out)
    }

    /// The counts of (marked label, label) pairs over every frame since the last mark, in
    /// increasing order; the shards then mark their labels.
    pub fn held_table(&self, chain: u64) -> Result<Vec<[u64; 3]>> {
        let jobs = (0..self.n_shards())
            .map(|s| (s, Request::Table { chain }))
            .collect();
        let mut table: BTreeMap<(u32, u32), u64> = BTreeMap::new();
        for reply in self.link.run(jobs)? {
            let Reply::Table(t) = reply else {
                return Err(wrong_reply("a table"));
            };
            for [a, b, c] in t {
                *table.entry((a, b)).or_default() += u64::from(c);
            }
        }
        if table.values().sum::<u64>() != self.len() as u64 {
            return Err(wrong_reply("a table"));
        }
        Ok(table
            .into_iter()
            .map(|((a, b), c)| [u64::from(a), u64::from(b), c])
            .collect())
    }

    /// Drop `chain`'s labels from every shard.
    pub fn forget_held(&self, chain: u64) -> Result<()> {
        let jobs = (0..self.n_shards())
            .map(|s| (s, Request::Forget { chain }))
            .collect();
        self.link.run(jobs).map(|_| ())
    }
}
