//! The sub-cluster sampler's frames, wherever they are: the few operations its steps need from
//! the data ([`Request`]), answered by a [`Shard`] of consecutive frames, and the leader's view of
//! all shards ([`Store`]) that splits each operation by shard and adds the replies up in shard
//! order.
//!
//! **Why this shape.** Every data-touching step of the sampler is one of: the sums of sets of
//! frames, the log-likelihoods of some frames under a bank of fields, every frame's label drawn
//! under a bank, each frame's mean velocity, and a few frames' points. None of them needs a
//! frame's label, so a shard holds nothing but its frames (a lost worker is replaced by reading
//! its shard again) and the labels stay with the leader, which runs every other step on sums.
//! A shard can also keep a chain's labels and run the pass on them (`subcluster_held.rs`: the
//! requests from `SetLabels` on), returning per-pattern statistics instead of a label a frame.
//!
//! **The same chain however the shards are served.** A shard's reply depends only on its frames
//! and the request (uniforms keyed by the global frame index, parallel work reduced in a fixed
//! order), and the leader reduces replies in shard order; so a chain over `S` shards gives the
//! same numbers whether they are served in this process ([`InProcess`]) or by workers elsewhere
//! ([`Link`] over [`Request::encode`] bytes), for any thread count. One shard computes exactly
//! what the sampler computed over all frames before shards existed.

use std::collections::HashMap;
use std::ops::Range;
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use super::pass::{FieldBank, TILE, argmax, pick_log};
use crate::basis::Basis;
use crate::error::{Error, Result};
use crate::frame::{Inputs, Point};
use crate::gibbs::Data;
use crate::hsgp_sums::{Sums, VecSums};
use crate::rng::uniform_code;

/// Fields for a bank: each pattern's basis weights (`[a_x, a_y]`, feature order) and noise pair,
/// and the prior mean velocity.
#[derive(Clone, Debug, PartialEq)]
pub struct Bank {
    pub weights: Vec<[Vec<f64>; 2]>,
    pub noise: Vec<[f64; 2]>,
    pub mean: [f64; 2],
}

/// How a draw is keyed and made: the uniform of (seed, sweep, phase code, global frame), or the
/// most probable label (`map`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DrawKey {
    pub seed: u64,
    pub sweep: u64,
    pub phase: u64,
    pub map: bool,
}

/// One operation on a shard's frames (frame numbers local to the shard).
#[derive(Clone, Debug, PartialEq)]
pub enum Request {
    /// The sums of each set of frames.
    Sums { basis: Basis, sets: Vec<Vec<u32>> },
    /// Each frame's log-likelihood under every field of the bank, `K` per frame.
    Logliks {
        basis: Basis,
        bank: Bank,
        frames: Vec<u32>,
    },
    /// Each frame of `frames`' entry of the bank drawn with probability `∝ w_k f(V | a_k)`.
    Draw {
        basis: Basis,
        bank: Bank,
        log_w: Vec<f64>,
        frames: Range<u32>,
        key: DrawKey,
    },
    /// Every frame's mean velocity.
    Means,
    /// The points of some frames.
    Points { frames: Vec<u32> },
    /// Hold these labels (slots) of the shard's frames for chain `chain` (`subcluster_held.rs`).
    SetLabels { chain: u64, labels: Vec<u32> },
    /// Draw every frame's entry of the bank (whose patterns are `slots`) and keep the draws.
    Pass {
        chain: u64,
        basis: Basis,
        bank: Bank,
        log_w: Vec<f64>,
        slots: Vec<u32>,
        key: DrawKey,
    },
    /// The frames drawn from or into the at-risk patterns `risk` (by bank index).
    Events { chain: u64, risk: Vec<bool> },
    /// Move every drawn frame but `stays`; the moved frames' sums per pair (or, `rebuild`,
    /// every pattern's sums).
    Move {
        chain: u64,
        basis: Basis,
        stays: Vec<u32>,
        rebuild: bool,
    },
    /// The held labels.
    Labels { chain: u64 },
    /// Drop the chain's labels.
    Forget { chain: u64 },
    /// The held labels of some frames.
    LabelsOf { chain: u64, frames: Vec<u32> },
    /// The frames (in order) whose label is one of `slots`, and for each its index in `slots`.
    Members { chain: u64, slots: Vec<u32> },
    /// How many frames hold a label among `slots`, and the `nth` of them (in frame order) with
    /// its label, if the shard has that many.
    Find {
        chain: u64,
        slots: Vec<u32>,
        nth: u64,
    },
    /// Relabel: every frame labelled `map[j][0]` becomes `map[j][1]`, then `frames` become `to`.
    Relabel {
        chain: u64,
        map: Vec<[u32; 2]>,
        frames: Vec<u32>,
        to: u32,
    },
    /// Label every frame `map[label]` (all below `n`), and answer with the sums of the frames
    /// of each new label `0..n`.
    Regroup {
        chain: u64,
        basis: Basis,
        map: Vec<u32>,
        n: u32,
    },
    /// The counts of (marked label, label) pairs since the last mark (frames' labels when they
    /// were set or last marked), then mark the labels.
    Table { chain: u64 },
}

/// A shard's answer to a [`Request`] of the same kind.
#[derive(Clone, Debug, PartialEq)]
pub enum Reply {
    Sums(Vec<Sums>),
    Logliks(Vec<f64>),
    Draw(Vec<u32>),
    Means(Vec<[f64; 2]>),
    Points {
        xy: Vec<Point>,
        v: Vec<[f64; 2]>,
        /// Each point's previous heading, or empty: frames without headings.
        h: Vec<f64>,
        sizes: Vec<u32>,
    },
    Done,
    Proposal {
        keeps: Vec<bool>,
        leaving: u64,
    },
    Events(Vec<super::stays::Event>),
    Moved {
        pairs: Vec<[u32; 2]>,
        sums: Vec<Sums>,
    },
    Labels(Vec<u32>),
    Members {
        frames: Vec<u32>,
        which: Vec<u32>,
    },
    Found {
        count: u64,
        hit: Option<[u32; 2]>,
    },
    /// `(marked label, label, count)` triples, increasing.
    Table(Vec<[u32; 3]>),
}

/// Consecutive frames of the data, the first being frame `first` of all, and the labels of its
/// frames that chains left with it (`subcluster_held.rs`; shared by clones).
#[derive(Clone, Debug)]
pub struct Shard {
    data: Arc<Data>,
    first: usize,
    held: Arc<Mutex<HashMap<u64, held::Held>>>,
}

#[path = "subcluster_held.rs"]
mod held;
pub use held::{Moved, fresh_chain_id};

/// Frames summed per parallel task (the sums of a set are those of its chunks, in order).
const SUM_CHUNK: usize = 64;

impl Shard {
    pub fn new(data: Arc<Data>, first: usize) -> Self {
        Self {
            data,
            first,
            held: Arc::default(),
        }
    }

    pub fn len(&self) -> usize {
        self.data.len()
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// The number of this shard's first frame among all frames.
    pub fn first(&self) -> usize {
        self.first
    }

    /// Answer `request`.
    pub fn handle(&self, request: &Request) -> Result<Reply> {
        if let Some(reply) = self.handle_held(request)? {
            return Ok(reply);
        }
        let n = self.data.len();
        let check = |mut frames: std::iter::Copied<std::slice::Iter<'_, u32>>| -> Result<()> {
            match frames.find(|&f| f as usize >= n) {
                Some(f) => Err(Error::InvalidInput(format!(
                    "a shard request names frame {f} of a shard of {n} frames"
                ))),
                None => Ok(()),
            }
        };
        Ok(match request {
            Request::Sums { basis, sets } => {
                for set in sets {
                    check(set.iter().copied())?;
                }
                Reply::Sums(self.sums(basis, sets))
            }
            Request::Logliks {
                basis,
                bank,
                frames,
            } => {
                check(frames.iter().copied())?;
                Reply::Logliks(self.logliks(basis, bank, frames)?)
            }
            Request::Draw {
                basis,
                bank,
                log_w,
                frames,
                key,
            } => {
                if frames.end as usize > n || frames.start > frames.end {
                    return Err(Error::InvalidInput(format!(
                        "a shard request names frames {frames:?} of a shard of {n} frames"
                    )));
                }
                Reply::Draw(self.draw(basis, bank, log_w, frames.clone(), *key)?)
            }
            Request::Means => Reply::Means(crate::gibbs::frame_means(&self.data)),
            Request::Points { frames } => {
                check(frames.iter().copied())?;
                let (xy, v, h, starts) = gather(&self.data, frames);
                let sizes = starts.windows(2).map(|w| (w[1] - w[0]) as u32).collect();
                Reply::Points { xy, v, h, sizes }
            }
            _ => unreachable!("requests about held labels are answered above"),
        })
    }

    /// The sums of each set, in parallel over fixed chunks of frames added in chunk order.
    fn sums(&self, basis: &Basis, sets: &[Vec<u32>]) -> Vec<Sums> {
        let jobs: Vec<(usize, &[u32])> = sets
            .iter()
            .enumerate()
            .flat_map(|(s, frames)| frames.chunks(SUM_CHUNK).map(move |c| (s, c)))
            .collect();
        let parts: Vec<Sums> = jobs
            .par_iter()
            .map(|(_, frames)| {
                let (xy, v, h, _) = gather(&self.data, frames);
                Sums::of_inputs(basis, Inputs { xy: &xy, h: &h }, &v, frames.len())
            })
            .collect();
        let mut out: Vec<Sums> = sets.iter().map(|_| Sums::zeros(basis)).collect();
        for ((s, _), p) in jobs.iter().zip(&parts) {
            out[*s].add(p);
        }
        out
    }

    fn logliks(&self, basis: &Basis, bank: &Bank, frames: &[u32]) -> Result<Vec<f64>> {
        let bank = field_bank(basis, bank)?;
        let kk = bank.len();
        let tiles: Vec<Vec<f64>> = frames
            .par_chunks(TILE)
            .map(|tile| {
                let (xy, v, h, starts) = gather(&self.data, tile);
                let mut ll = vec![0.0; kk * tile.len()];
                bank.frame_logliks(Inputs { xy: &xy, h: &h }, &v, &starts, &mut ll);
                ll
            })
            .collect();
        Ok(tiles.concat())
    }

    fn draw(
        &self,
        basis: &Basis,
        bank: &Bank,
        log_w: &[f64],
        frames: Range<u32>,
        key: DrawKey,
    ) -> Result<Vec<u32>> {
        let fields = field_bank(basis, bank)?;
        let kk = fields.len();
        if log_w.len() != kk {
            return Err(Error::Shape(format!(
                "a draw has {} mixture weights for {kk} fields",
                log_w.len()
            )));
        }
        let (xy, v) = self.data.points();
        let h = self.data.headings();
        let offsets = self.data.offsets();
        let (start, end) = (frames.start as usize, frames.end as usize);
        let tiles: Vec<Vec<u32>> = (start..end)
            .step_by(TILE)
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|f0| {
                let f1 = (f0 + TILE).min(end);
                let (a, b) = (offsets[f0], offsets[f1]);
                let starts: Vec<usize> = offsets[f0..=f1].iter().map(|o| o - a).collect();
                let mut ll = vec![0.0; (f1 - f0) * kk];
                let pts = Inputs {
                    xy: &xy[a..b],
                    h: if h.is_empty() { h } else { &h[a..b] },
                };
                fields.frame_logliks(pts, &v[a..b], &starts, &mut ll);
                (f0..f1)
                    .zip(ll.chunks(kk))
                    .map(|(i, l)| {
                        let lp: Vec<f64> = l.iter().zip(log_w).map(|(l, w)| l + w).collect();
                        let global = (self.first + i) as u64;
                        let pick = if key.map {
                            argmax(&lp)
                        } else {
                            pick_log(&lp, uniform_code(key.seed, key.sweep, key.phase, global))
                        };
                        pick as u32
                    })
                    .collect()
            })
            .collect();
        Ok(tiles.concat())
    }
}

fn field_bank(basis: &Basis, bank: &Bank) -> Result<FieldBank> {
    let m = basis.len();
    if bank.noise.len() != bank.weights.len() || bank.weights.iter().flatten().any(|a| a.len() != m)
    {
        return Err(Error::Shape(format!(
            "a bank's fields need {m} weights per output and one noise pair each"
        )));
    }
    Ok(FieldBank::new(basis, &bank.weights, &bank.noise, bank.mean))
}

/// The points of `frames` one after another: positions, velocities, previous headings (empty
/// when the frames have none), and where each frame starts (ending with the total).
pub(super) type Gathered = (Vec<Point>, Vec<[f64; 2]>, Vec<f64>, Vec<usize>);

/// The points of `frames` one after another ([`Gathered`]).
pub(super) fn gather<F: Copy + Into<u64>>(data: &Data, frames: &[F]) -> Gathered {
    let (mut xy, mut v, mut h, mut starts) = (Vec::new(), Vec::new(), Vec::new(), vec![0]);
    for &f in frames {
        let fr = data.frame(f.into() as usize);
        xy.extend_from_slice(fr.xy);
        v.extend_from_slice(fr.v);
        h.extend_from_slice(fr.h);
        starts.push(xy.len());
    }
    (xy, v, h, starts)
}

/// Runs requests on shards, wherever they are served.
pub trait Link: Send + Sync + std::fmt::Debug {
    /// Answer each `(shard, request)`; the replies in the same order.
    fn run(&self, jobs: Vec<(usize, Request)>) -> Result<Vec<Reply>>;
}

/// Shards served in this process, one after another (each one's work is parallel).
#[derive(Debug)]
pub struct InProcess(pub Vec<Shard>);

impl Link for InProcess {
    fn run(&self, jobs: Vec<(usize, Request)>) -> Result<Vec<Reply>> {
        jobs.iter().map(|(s, r)| self.0[*s].handle(r)).collect()
    }
}

/// The leader's view of the frames: how many each shard holds, and the link that serves them.
#[derive(Debug, Clone)]
pub struct Store {
    /// Global number of each shard's first frame, then the total.
    starts: Vec<usize>,
    link: Arc<dyn Link>,
    /// The frames, when they are all in this process as one shard.
    data: Option<Arc<Data>>,
}

impl Store {
    /// All frames in this process, as one shard.
    pub fn local(data: Arc<Data>) -> Self {
        Self {
            starts: vec![0, data.len()],
            link: Arc::new(InProcess(vec![Shard::new(Arc::clone(&data), 0)])),
            data: Some(data),
        }
    }

    /// Shards of `sizes[s]` frames each, served by `link`.
    pub fn sharded(sizes: &[usize], link: Arc<dyn Link>) -> Result<Self> {
        if sizes.is_empty() || sizes.contains(&0) {
            return Err(Error::InvalidInput(
                "sharded frames need at least one shard and no empty shard".into(),
            ));
        }
        if let Some(n) = sizes.iter().find(|&&n| n > u32::MAX as usize) {
            return Err(Error::InvalidInput(format!(
                "a shard of {n} frames is too large (at most {}); write more shards",
                u32::MAX
            )));
        }
        let mut starts = vec![0];
        for s in sizes {
            starts.push(starts.last().unwrap() + s);
        }
        Ok(Self {
            starts,
            link,
            data: None,
        })
    }

    /// Shards of the given frames served in this process (the same chain as on workers).
    pub fn in_process(shards: Vec<Data>) -> Result<Self> {
        let mut first = 0;
        let mut served = Vec::new();
        for d in shards {
            let n = d.len();
            served.push(Shard::new(Arc::new(d), first));
            first += n;
        }
        Self::in_process_shards(served)
    }

    /// Shards served in this process; each must start where the one before it ends.
    pub fn in_process_shards(shards: Vec<Shard>) -> Result<Self> {
        let mut first = 0;
        for s in &shards {
            if s.first() != first {
                return Err(Error::InvalidInput(format!(
                    "shards must be given in order: a shard starts at frame {} where frame {first} was expected",
                    s.first()
                )));
            }
            first += s.len();
        }
        let sizes: Vec<usize> = shards.iter().map(Shard::len).collect();
        Self::sharded(&sizes, Arc::new(InProcess(shards)))
    }

    pub fn len(&self) -> usize {
        *self.starts.last().unwrap_or(&0)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn n_shards(&self) -> usize {
        self.starts.len() - 1
    }

    /// The frames, when this store holds them all in this process as one shard.
    pub fn data(&self) -> Option<&Arc<Data>> {
        self.data.as_ref()
    }

    /// Each shard's frames, as a range of all frames.
    pub fn shard_ranges(&self) -> impl Iterator<Item = Range<usize>> + '_ {
        self.starts.windows(2).map(|w| w[0]..w[1])
    }

    fn shard_of(&self, f: usize) -> usize {
        self.starts.partition_point(|&s| s <= f) - 1
    }

    /// `frames` split by shard, in their order, as local numbers; shards without any left out.
    fn split(&self, frames: &[usize]) -> Vec<(usize, Vec<u32>)> {
        let mut out: Vec<(usize, Vec<u32>)> = Vec::new();
        for &f in frames {
            let s = self.shard_of(f);
            let local = (f - self.starts[s]) as u32;
            match out.iter_mut().find(|(t, _)| *t == s) {
                Some((_, v)) => v.push(local),
                None => out.push((s, vec![local])),
            }
        }
        out.sort_by_key(|(s, _)| *s);
        out
    }

    /// The sums of each set of frames: each shard's part of every set, added in shard order.
    pub fn sums_of_sets(&self, basis: &Basis, sets: &[&[usize]]) -> Result<Vec<Sums>> {
        let mut per_shard: Vec<Vec<Vec<u32>>> = vec![vec![Vec::new(); sets.len()]; self.n_shards()];
        for (k, set) in sets.iter().enumerate() {
            for (s, local) in self.split(set) {
                per_shard[s][k] = local;
            }
        }
        self.sums_per_shard(basis, per_shard, sets.len())
    }

    /// The sums of `n_groups` groups of frames, frame `i` in group `group[labels[i]]` (none if
    /// that is `n_groups` or more): [`Self::sums_of_sets`] of the groups' members in frame order,
    /// without a list of every frame's number (a fit's canonical rebuild at 10M frames).
    pub fn sums_of_groups(
        &self,
        basis: &Basis,
        labels: &[usize],
        group: &[usize],
        n_groups: usize,
    ) -> Result<Vec<Sums>> {
        if labels.len() != self.len() {
            return Err(Error::Shape(format!(
                "{} labels for {} frames",
                labels.len(),
                self.len()
            )));
        }
        let per_shard: Vec<Vec<Vec<u32>>> = (0..self.n_shards())
            .map(|s| {
                let mut sets = vec![Vec::new(); n_groups];
                let first = self.starts[s];
                for (i, &l) in labels[first..self.starts[s + 1]].iter().enumerate() {
                    let g = group.get(l).copied().unwrap_or(usize::MAX);
                    if g < n_groups {
                        sets[g].push(i as u32);
                    }
                }
                sets
            })
            .collect();
        self.sums_per_shard(basis, per_shard, n_groups)
    }

    /// Each shard's sums of its sets (local frame numbers), added over shards in shard order.
    fn sums_per_shard(
        &self,
        basis: &Basis,
        per_shard: Vec<Vec<Vec<u32>>>,
        n_sets: usize,
    ) -> Result<Vec<Sums>> {
        let jobs: Vec<(usize, Request)> = per_shard
            .into_iter()
            .enumerate()
            .filter(|(_, sets)| sets.iter().any(|s| !s.is_empty()))
            .map(|(s, sets)| {
                let basis = basis.clone();
                (s, Request::Sums { basis, sets })
            })
            .collect();
        let mut out: Vec<Sums> = (0..n_sets).map(|_| Sums::zeros(basis)).collect();
        for reply in self.link.run(jobs)? {
            let Reply::Sums(parts) = reply else {
                return Err(wrong_reply("sums"));
            };
            if parts.len() != out.len() || parts.iter().any(|p| !same_shape(p, &out[0])) {
                return Err(wrong_reply("sums"));
            }
            for (o, p) in out.iter_mut().zip(&parts) {
                o.add(p);
            }
        }
        Ok(out)
    }

    /// Each of `frames`' log-likelihoods under every field of `bank` (`K` per frame, in order).
    pub fn logliks(&self, basis: &Basis, bank: &Bank, frames: &[usize]) -> Result<Vec<f64>> {
        let kk = bank.weights.len();
        let parts = self.split(frames);
        let jobs: Vec<(usize, Request)> = parts
            .iter()
            .map(|(s, local)| {
                let req = Request::Logliks {
                    basis: basis.clone(),
                    bank: bank.clone(),
                    frames: local.clone(),
                };
                (*s, req)
            })
            .collect();
        let replies = self.link.run(jobs)?;
        // Back into the order of `frames`: each shard's replies are in its frames' order.
        let mut cursor: Vec<usize> = vec![0; self.n_shards()];
        let mut by_shard: Vec<Vec<f64>> = vec![Vec::new(); self.n_shards()];
        for ((s, local), reply) in parts.iter().zip(replies) {
            let Reply::Logliks(ll) = reply else {
                return Err(wrong_reply("log-likelihoods"));
            };
            if ll.len() != kk * local.len() {
                return Err(wrong_reply("log-likelihoods"));
            }
            by_shard[*s] = ll;
        }
        let mut out = Vec::with_capacity(kk * frames.len());
        for &f in frames {
            let s = self.shard_of(f);
            out.extend_from_slice(&by_shard[s][cursor[s] * kk..(cursor[s] + 1) * kk]);
            cursor[s] += 1;
        }
        Ok(out)
    }

    /// Each frame of `frames`' drawn entry of the bank (an index into its fields).
    pub fn draw(
        &self,
        basis: &Basis,
        bank: &Bank,
        log_w: &[f64],
        frames: Range<usize>,
        key: DrawKey,
    ) -> Result<Vec<u32>> {
        let jobs: Vec<(usize, Request)> = (0..self.n_shards())
            .filter_map(|s| {
                let (a, b) = (
                    frames.start.max(self.starts[s]),
                    frames.end.min(self.starts[s + 1]),
                );
                (a < b).then(|| {
                    let local = (a - self.starts[s]) as u32..(b - self.starts[s]) as u32;
                    let req = Request::Draw {
                        basis: basis.clone(),
                        bank: bank.clone(),
                        log_w: log_w.to_vec(),
                        frames: local,
                        key,
                    };
                    (s, req)
                })
            })
            .collect();
        let mut out = Vec::with_capacity(frames.len());
        for reply in self.link.run(jobs)? {
            let Reply::Draw(d) = reply else {
                return Err(wrong_reply("labels"));
            };
            out.extend(d);
        }
        if out.len() != frames.len() || out.iter().any(|&k| k as usize >= bank.weights.len()) {
            return Err(wrong_reply("labels"));
        }
        Ok(out)
    }

    /// Every frame's mean velocity.
    pub fn means(&self) -> Result<Vec<[f64; 2]>> {
        let jobs = (0..self.n_shards()).map(|s| (s, Request::Means)).collect();
        let mut out = Vec::with_capacity(self.len());
        for reply in self.link.run(jobs)? {
            let Reply::Means(m) = reply else {
                return Err(wrong_reply("means"));
            };
            out.extend(m);
        }
        if out.len() != self.len() {
            return Err(wrong_reply("means"));
        }
        Ok(out)
    }

    /// The frames `frames` (in their order) as data of their own.
    pub fn frames(&self, frames: &[usize]) -> Result<Data> {
        let parts = self.split(frames);
        let jobs = parts
            .iter()
            .map(|(s, local)| {
                let frames = local.clone();
                (*s, Request::Points { frames })
            })
            .collect();
        let mut by_shard: Vec<Gathered> = vec![Default::default(); self.n_shards()];
        for ((s, local), reply) in parts.iter().zip(self.link.run(jobs)?) {
            let Reply::Points { xy, v, h, sizes } = reply else {
                return Err(wrong_reply("points"));
            };
            if sizes.len() != local.len()
                || xy.len() != v.len()
                || !(h.is_empty() || h.len() == xy.len())
            {
                return Err(wrong_reply("points"));
            }
            let mut starts = vec![0];
            for z in sizes {
                starts.push(starts.last().unwrap() + z as usize);
            }
            if *starts.last().unwrap() != xy.len() {
                return Err(wrong_reply("points"));
            }
            by_shard[*s] = (xy, v, h, starts);
        }
        let mut cursor = vec![0usize; self.n_shards()];
        let (mut xy, mut v, mut h, mut offsets) = (Vec::new(), Vec::new(), Vec::new(), vec![0]);
        for &f in frames {
            let s = self.shard_of(f);
            let (sxy, sv, sh, st) = &by_shard[s];
            let (a, b) = (st[cursor[s]], st[cursor[s] + 1]);
            crate::frame::extend_headings(
                &mut h,
                xy.len(),
                if sh.is_empty() { sh } else { &sh[a..b] },
                b - a,
            );
            xy.extend_from_slice(&sxy[a..b]);
            v.extend_from_slice(&sv[a..b]);
            offsets.push(xy.len());
            cursor[s] += 1;
        }
        let data = Data::new(xy, v, offsets)?;
        if h.is_empty() {
            Ok(data)
        } else {
            data.with_headings(h)
        }
    }
}

fn same_shape(a: &Sums, b: &Sums) -> bool {
    a.h.len() == b.h.len()
        && a.vecs.phi_sum.len() == b.vecs.phi_sum.len()
        && a.vecs.phi_v.len() == b.vecs.phi_v.len()
}

fn wrong_reply(what: &str) -> Error {
    Error::InvalidInput(format!(
        "a shard answered a request for {what} with a reply of the wrong kind or size"
    ))
}

// ---------------------------------------------------------------------------------------------
// Bytes: requests and replies as little-endian numbers, for links that cross processes.

const MAGIC: u32 = 0x6470_6731; // "dpg1"

struct Writer(Vec<u8>);

impl Writer {
    fn u64(&mut self, x: u64) {
        self.0.extend_from_slice(&x.to_le_bytes());
    }
    fn f64(&mut self, x: f64) {
        self.0.extend_from_slice(&x.to_le_bytes());
    }
    fn f64s(&mut self, xs: &[f64]) {
        self.u64(xs.len() as u64);
        for &x in xs {
            self.f64(x);
        }
    }
    fn pairs(&mut self, xs: &[[f64; 2]]) {
        self.u64(xs.len() as u64);
        for p in xs {
            self.f64(p[0]);
            self.f64(p[1]);
        }
    }
    fn u32s(&mut self, xs: &[u32]) {
        self.u64(xs.len() as u64);
        for &x in xs {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
    fn basis(&mut self, b: &Basis) {
        let (c, h, m) = (b.center(), b.half_widths(), b.counts());
        self.pairs(&[c, h]);
        self.u64(m[0] as u64);
        self.u64(m[1] as u64);
        self.u64(b.harmonics() as u64);
        let hm = b.heading_counts();
        self.u64(hm[0] as u64);
        self.u64(hm[1] as u64);
    }
    fn bank(&mut self, b: &Bank) {
        self.u64(b.weights.len() as u64);
        for [ax, ay] in &b.weights {
            self.f64s(ax);
            self.f64s(ay);
        }
        self.pairs(&b.noise);
        self.pairs(&[b.mean]);
    }
    fn bools(&mut self, xs: &[bool]) {
        self.u32s(&xs.iter().map(|&b| u32::from(b)).collect::<Vec<_>>());
    }
    fn key(&mut self, key: &DrawKey) {
        for x in [key.seed, key.sweep, key.phase, u64::from(key.map)] {
            self.u64(x);
        }
    }
    fn sums(&mut self, s: &Sums) {
        self.f64s(&s.h);
        self.f64s(&s.vecs.phi_sum);
        self.f64s(&s.vecs.phi_v);
        self.pairs(&[s.vecs.v_sum, s.vecs.v_sq]);
        self.u64(s.vecs.n_points as u64);
        self.u64(s.n_frames as u64);
    }
}

struct Reader<'a> {
    b: &'a [u8],
    at: usize,
}

fn malformed() -> Error {
    Error::InvalidInput("a shard message is malformed or truncated".into())
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8]> {
        let end = self.at.checked_add(n).ok_or_else(malformed)?;
        let s = self.b.get(self.at..end).ok_or_else(malformed)?;
        self.at = end;
        Ok(s)
    }
    fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn len(&mut self, item: usize) -> Result<usize> {
        let n = self.u64()? as usize;
        if n.checked_mul(item)
            .is_none_or(|b| b > self.b.len() - self.at)
        {
            return Err(malformed());
        }
        Ok(n)
    }
    fn u32_value(&mut self) -> Result<u32> {
        u32::try_from(self.u64()?).map_err(|_| malformed())
    }
    fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn f64s(&mut self) -> Result<Vec<f64>> {
        let n = self.len(8)?;
        (0..n).map(|_| self.f64()).collect()
    }
    fn pairs(&mut self) -> Result<Vec<[f64; 2]>> {
        let n = self.len(16)?;
        (0..n).map(|_| Ok([self.f64()?, self.f64()?])).collect()
    }
    fn pair(&mut self) -> Result<[f64; 2]> {
        let p = self.pairs()?;
        if p.len() != 1 {
            return Err(malformed());
        }
        Ok(p[0])
    }
    fn u32s(&mut self) -> Result<Vec<u32>> {
        let n = self.len(4)?;
        let bytes = self.take(4 * n)?;
        Ok(bytes
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
            .collect())
    }
    fn bools(&mut self) -> Result<Vec<bool>> {
        self.u32s()?
            .into_iter()
            .map(|x| match x {
                0 => Ok(false),
                1 => Ok(true),
                _ => Err(malformed()),
            })
            .collect()
    }
    fn key(&mut self) -> Result<DrawKey> {
        Ok(DrawKey {
            seed: self.u64()?,
            sweep: self.u64()?,
            phase: self.u64()?,
            map: self.u64()? != 0,
        })
    }
    fn basis(&mut self) -> Result<Basis> {
        let ch = self.pairs()?;
        if ch.len() != 2 {
            return Err(malformed());
        }
        let m = [self.u64()? as usize, self.u64()? as usize];
        let harmonics = self.u64()? as usize;
        let hm = [self.u64()? as usize, self.u64()? as usize];
        Basis::new(ch[0], ch[1], m)?.with_heading(harmonics, hm)
    }
    fn bank(&mut self) -> Result<Bank> {
        let k = self.len(16)?;
        let weights = (0..k)
            .map(|_| Ok([self.f64s()?, self.f64s()?]))
            .collect::<Result<_>>()?;
        Ok(Bank {
            weights,
            noise: self.pairs()?,
            mean: self.pair()?,
        })
    }
    fn sums(&mut self) -> Result<Sums> {
        let h = self.f64s()?;
        let phi_sum = self.f64s()?;
        let phi_v = self.f64s()?;
        let vs = self.pairs()?;
        if vs.len() != 2 {
            return Err(malformed());
        }
        let n_points = self.u64()? as usize;
        let n_frames = self.u64()? as usize;
        Ok(Sums {
            h,
            vecs: VecSums {
                phi_sum,
                phi_v,
                v_sum: vs[0],
                v_sq: vs[1],
                n_points,
            },
            n_frames,
        })
    }
    fn done(&self) -> Result<()> {
        if self.at == self.b.len() {
            Ok(())
        } else {
            Err(malformed())
        }
    }
}

fn header(w: &mut Writer, tag: u64) {
    w.0.extend_from_slice(&MAGIC.to_le_bytes());
    w.u64(tag);
}

fn read_header(bytes: &[u8]) -> Result<(Reader<'_>, u64)> {
    let mut r = Reader { b: bytes, at: 0 };
    if r.take(4)? != MAGIC.to_le_bytes() {
        return Err(malformed());
    }
    let tag = r.u64()?;
    Ok((r, tag))
}

impl Request {
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer(Vec::new());
        match self {
            Request::Sums { basis, sets } => {
                header(&mut w, 1);
                w.basis(basis);
                w.u64(sets.len() as u64);
                for s in sets {
                    w.u32s(s);
                }
            }
            Request::Logliks {
                basis,
                bank,
                frames,
            } => {
                header(&mut w, 2);
                w.basis(basis);
                w.bank(bank);
                w.u32s(frames);
            }
            Request::Draw {
                basis,
                bank,
                log_w,
                frames,
                key,
            } => {
                header(&mut w, 3);
                w.basis(basis);
                w.bank(bank);
                w.f64s(log_w);
                w.u32s(&[frames.start, frames.end]);
                w.key(key);
            }
            Request::Means => header(&mut w, 4),
            Request::Points { frames } => {
                header(&mut w, 5);
                w.u32s(frames);
            }
            Request::SetLabels { chain, labels } => {
                header(&mut w, 6);
                w.u64(*chain);
                w.u32s(labels);
            }
            Request::Pass {
                chain,
                basis,
                bank,
                log_w,
                slots,
                key,
            } => {
                header(&mut w, 7);
                w.u64(*chain);
                w.basis(basis);
                w.bank(bank);
                w.f64s(log_w);
                w.u32s(slots);
                w.key(key);
            }
            Request::Events { chain, risk } => {
                header(&mut w, 8);
                w.u64(*chain);
                w.bools(risk);
            }
            Request::Move {
                chain,
                basis,
                stays,
                rebuild,
            } => {
                header(&mut w, 9);
                w.u64(*chain);
                w.basis(basis);
                w.u32s(stays);
                w.u64(u64::from(*rebuild));
            }
            Request::Labels { chain } => {
                header(&mut w, 10);
                w.u64(*chain);
            }
            Request::Forget { chain } => {
                header(&mut w, 11);
                w.u64(*chain);
            }
            Request::LabelsOf { chain, frames } => {
                header(&mut w, 12);
                w.u64(*chain);
                w.u32s(frames);
            }
            Request::Members { chain, slots } => {
                header(&mut w, 13);
                w.u64(*chain);
                w.u32s(slots);
            }
            Request::Find { chain, slots, nth } => {
                header(&mut w, 14);
                w.u64(*chain);
                w.u32s(slots);
                w.u64(*nth);
            }
            Request::Relabel {
                chain,
                map,
                frames,
                to,
            } => {
                header(&mut w, 15);
                w.u64(*chain);
                w.u32s(&map.iter().flatten().copied().collect::<Vec<_>>());
                w.u32s(frames);
                w.u64(u64::from(*to));
            }
            Request::Regroup {
                chain,
                basis,
                map,
                n,
            } => {
                header(&mut w, 16);
                w.u64(*chain);
                w.basis(basis);
                w.u32s(map);
                w.u64(u64::from(*n));
            }
            Request::Table { chain } => {
                header(&mut w, 17);
                w.u64(*chain);
            }
        }
        w.0
    }

    pub fn decode(bytes: &[u8]) -> Result<Self> {
        let (mut r, tag) = read_header(bytes)?;
        let req = match tag {
            1 => {
                let basis = r.basis()?;
                let n = r.len(8)?;
                let sets = (0..n).map(|_| r.u32s()).collect::<Result<_>>()?;
                Request::Sums { basis, sets }
            }
            2 => Request::Logliks {
                basis: r.basis()?,
                bank: r.bank()?,
                frames: r.u32s()?,
            },
            3 => {
                let basis = r.basis()?;
                let bank = r.bank()?;
                let log_w = r.f64s()?;
                let range = r.u32s()?;
                if range.len() != 2 {
                    return Err(malformed());
                }
                let key = r.key()?;
                Request::Draw {
                    basis,
                    bank,
                    log_w,
                    frames: range[0]..range[1],
                    key,
                }
            }
            4 => Request::Means,
            5 => Request::Points { frames: r.u32s()? },
            6 => Request::SetLabels {
                chain: r.u64()?,
                labels: r.u32s()?,
            },
            7 => Request::Pass {
                chain: r.u64()?,
                basis: r.basis()?,
                bank: r.bank()?,
                log_w: r.f64s()?,
                slots: r.u32s()?,
                key: r.key()?,
            },
            8 => Request::Events {
                chain: r.u64()?,
                risk: r.bools()?,
            },
            9 => Request::Move {
                chain: r.u64()?,
                basis: r.basis()?,
                stays: r.u32s()?,
                rebuild: r.u64()? != 0,
            },
            10 => Request::Labels { chain: r.u64()? },
            11 => Request::Forget { chain: r.u64()? },
            12 => Request::LabelsOf {
                chain: r.u64()?,
                frames: r.u32s()?,
            },
            13 => Request::Members {
                chain: r.u64()?,
                slots: r.u32s()?,
            },
            14 => Request::Find {
                chain: r.u64()?,
                slots: r.u32s()?,
                nth: r.u64()?,
            },
            15 => {
                let chain = r.u64()?;
                let flat = r.u32s()?;
                if flat.len() % 2 != 0 {
                    return Err(malformed());
                }
                Request::Relabel {
                    chain,
                    map: flat.chunks(2).map(|c| [c[0], c[1]]).collect(),
                    frames: r.u32s()?,
                    to: r.u32_value()?,
                }
            }
            16 => Request::Regroup {
                chain: r.u64()?,
                basis: r.basis()?,
                map: r.u32s()?,
                n: r.u32_value()?,
            },
            17 => Request::Table { chain: r.u64()? },
            _ => return Err(malformed()),
        };
        r.done()?;
        Ok(req)
    }
}

impl Reply {
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer(Vec::new());
        match self {
            Reply::Sums(sums) => {
                header(&mut w, 1);
                w.u64(sums.len() as u64);
                for s in sums {
                    w.sums(s);
                }
            }
            Reply::Logliks(ll) => {
                header(&mut w, 2);
                w.f64s(ll);
            }
            Reply::Draw(d) => {
                header(&mut w, 3);
                w.u32s(d);
            }
            Reply::Means(m) => {
                header(&mut w, 4);
                w.pairs(m);
            }
            Reply::Points { xy, v, h, sizes } => {
                header(&mut w, 5);
                w.pairs(xy);
                w.pairs(v);
                w.f64s(h);
                w.u32s(sizes);
            }
            Reply::Done => header(&mut w, 6),
            Reply::Proposal { keeps, leaving } => {
                header(&mut w, 7);
                w.bools(keeps);
                w.u64(*leaving);
            }
            Reply::Events(e) => {
                header(&mut w, 8);
                let flat: Vec<u32> = e.iter().flat_map(|&(i, f, t)| [i, f, t]).collect();
                w.u32s(&flat);
            }
            Reply::Moved { pairs, sums } => {
                header(&mut w, 9);
                let flat: Vec<u32> = pairs.iter().flatten().copied().collect();
                w.u32s(&flat);
                w.u64(sums.len() as u64);
                for s in sums {
                    w.sums(s);
                }
            }
            Reply::Labels(l) => {
                header(&mut w, 10);
                w.u32s(l);
            }
            Reply::Members { frames, which } => {
                header(&mut w, 11);
                w.u32s(frames);
                w.u32s(which);
            }
            Reply::Found { count, hit } => {
                header(&mut w, 12);
                w.u64(*count);
                w.u32s(hit.as_ref().map_or(&[][..], |h| &h[..]));
            }
            Reply::Table(t) => {
                header(&mut w, 13);
                w.u32s(&t.iter().flatten().copied().collect::<Vec<_>>());
            }
        }
        w.0
    }

    pub fn decode(bytes: &[u8]) -> Result<Self> {
        let (mut r, tag) = read_header(bytes)?;
        let reply = match tag {
            1 => {
                let n = r.len(8)?;
                Reply::Sums((0..n).map(|_| r.sums()).collect::<Result<_>>()?)
            }
            2 => Reply::Logliks(r.f64s()?),
            3 => Reply::Draw(r.u32s()?),
            4 => Reply::Means(r.pairs()?),
            5 => Reply::Points {
                xy: r.pairs()?,
                v: r.pairs()?,
                h: r.f64s()?,
                sizes: r.u32s()?,
            },
            6 => Reply::Done,
            7 => Reply::Proposal {
                keeps: r.bools()?,
                leaving: r.u64()?,
            },
            8 => {
                let flat = r.u32s()?;
                if flat.len() % 3 != 0 {
                    return Err(malformed());
                }
                Reply::Events(flat.chunks(3).map(|c| (c[0], c[1], c[2])).collect())
            }
            9 => {
                let flat = r.u32s()?;
                let n = r.len(8)?;
                if flat.len() != 2 * n {
                    return Err(malformed());
                }
                Reply::Moved {
                    pairs: flat.chunks(2).map(|c| [c[0], c[1]]).collect(),
                    sums: (0..n).map(|_| r.sums()).collect::<Result<_>>()?,
                }
            }
            10 => Reply::Labels(r.u32s()?),
            11 => {
                let frames = r.u32s()?;
                let which = r.u32s()?;
                if frames.len() != which.len() {
                    return Err(malformed());
                }
                Reply::Members { frames, which }
            }
            12 => {
                let count = r.u64()?;
                let hit = match r.u32s()?[..] {
                    [] => None,
                    [f, l] => Some([f, l]),
                    _ => return Err(malformed()),
                };
                Reply::Found { count, hit }
            }
            13 => {
                let flat = r.u32s()?;
                if flat.len() % 3 != 0 {
                    return Err(malformed());
                }
                Reply::Table(flat.chunks(3).map(|c| [c[0], c[1], c[2]]).collect())
            }
            _ => return Err(malformed()),
        };
        r.done()?;
        Ok(reply)
    }
}

#[cfg(test)]
#[path = "tests/subcluster_shard.rs"]
mod tests;
