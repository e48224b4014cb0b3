//! The sub-cluster sampler's assignment pass: draw the patterns' weights and fields, give every
//! frame its label in parallel, and update the sums of the patterns frames moved between.
//!
//! Every pattern's two fields are evaluated at a frame's points by the fused kernel of
//! [`crate::field_blocks`] (`2 M` multiply–adds per field and point; a field over heading is
//! `2J + 1` position fields, combined at each point by its heading functions).

use std::ops::Range;
use std::time::Instant;

use rayon::prelude::*;

use super::shard::{Bank, DrawKey, Moved};
use super::stays::{self, Event, Proposal};
use super::{Fit, SubclusterSampler, gamma};
use crate::basis::Basis;
use crate::error::{Error, Result};
use crate::field_blocks::{FieldBlocks, LANES};
use crate::frame::Inputs;
use crate::gp::LN_2PI;
use crate::heading;
use crate::rng::{Phase, stream};
use crate::special::log_sum_exp;

/// Frames per parallel task of a pass.
pub(super) const TILE: usize = 128;

/// Several patterns' fields, with each pattern's noise: what a frame's log-likelihood under each
/// pattern needs.
pub(super) struct FieldBank {
    /// Patterns.
    k: usize,
    /// Heading functions per position field (`2J + 1`; 1 over position).
    nc: usize,
    /// Field `(2k + d) nc + c`: heading function `c`'s position field of pattern k's output d.
    blocks: FieldBlocks,
    mean: [f64; 2],
    /// Per pattern: `½ / σ_n,d²`, and `−½ Σ_d log(2π σ_n,d²)` per point.
    half_inv: Vec<[f64; 2]>,
    log_norm: Vec<f64>,
}

impl FieldBank {
    /// The bank of fields with weights `weights[k] = [a_x, a_y]` (feature order) and noise pairs
    /// `noise[k]`.
    pub(super) fn new(
        basis: &Basis,
        weights: &[[Vec<f64>; 2]],
        noise: &[[f64; 2]],
        mean: [f64; 2],
    ) -> Self {
        // A field over heading is `Σ_c ψ_c(h) f_c(x, y)`: its position fields, one per heading
        // function, evaluated by the same kernel and combined per point.
        // A heading block on fewer position functions is its position field with zeros there.
        let (nc, mp) = (basis.n_heading(), basis.positions_len());
        let tensor: Vec<Vec<f64>> = if basis.is_tensor() {
            Vec::new()
        } else {
            weights
                .iter()
                .flatten()
                .map(|a| basis.to_tensor(a))
                .collect()
        };
        let fields: Box<dyn Iterator<Item = &[f64]>> = if tensor.is_empty() {
            Box::new(weights.iter().flatten().flat_map(|a| a.chunks(mp)))
        } else {
            Box::new(tensor.iter().flat_map(|a| a.chunks(mp)))
        };
        Self {
            k: weights.len(),
            nc,
            blocks: FieldBlocks::new(basis, fields),
            mean,
            half_inv: noise
                .iter()
                .map(|n| [0.5 * (1.0 / n[0]), 0.5 * (1.0 / n[1])])
                .collect(),
            log_norm: noise
                .iter()
                .map(|n| -0.5 * (2.0 * LN_2PI + n[0].ln() + n[1].ln()))
                .collect(),
        }
    }

    /// The number of fields' patterns.
    pub(super) fn len(&self) -> usize {
        self.k
    }

    /// Add to `out[f K + k]` the log-likelihood of frame `f`'s velocities under pattern `k`'s
    /// field and noise, for frames whose points are `pts` (positions and previous headings),
    /// `v` with frame `f` starting at `starts[f]` (`starts` ends with the number of points).
    pub(super) fn frame_logliks(
        &self,
        pts: Inputs<'_>,
        v: &[[f64; 2]],
        starts: &[usize],
        out: &mut [f64],
    ) {
        let (kk, nc, xy) = (self.k, self.nc, pts.xy);
        let mut psi = vec![0.0; nc];
        let mut psi_lanes = vec![[0.0; LANES]; nc];
        let mut f = [[0.0; LANES]; 2];
        let mut frame_of = Vec::with_capacity(xy.len());
        for (f, w) in starts.windows(2).enumerate() {
            frame_of.extend(std::iter::repeat_n(f, w[1] - w[0]));
        }
        self.blocks.for_blocks(xy, &mut |b0, vals| {
            // Per pattern, the block's points' terms as 8-lane arithmetic, then each added to its
            // frame in point order (the same sums as point after point).
            let n = (xy.len() - b0).min(LANES);
            let mut r = [[0.0; LANES]; 2];
            for l in 0..n {
                r[0][l] = v[b0 + l][0] - self.mean[0];
                r[1][l] = v[b0 + l][1] - self.mean[1];
            }
            if nc > 1 {
                for l in 0..n {
                    heading::features(pts.heading(b0 + l), &mut psi);
                    for (lanes, p) in psi_lanes.iter_mut().zip(&psi) {
                        lanes[l] = *p;
                    }
                }
            }
            for (k, h) in self.half_inv.iter().enumerate() {
                let (fx, fy) = if nc == 1 {
                    (&vals[2 * k], &vals[2 * k + 1])
                } else {
                    for (d, fd) in f.iter_mut().enumerate() {
                        let fields = &vals[(2 * k + d) * nc..(2 * k + d + 1) * nc];
                        *fd = [0.0; LANES];
                        for (val, p) in fields.iter().zip(&psi_lanes) {
                            for l in 0..LANES {
                                fd[l] = p[l].mul_add(val[l], fd[l]);
                            }
                        }
                    }
                    (&f[0], &f[1])
                };
                let mut ll = [0.0; LANES];
                for l in 0..LANES {
                    let (e0, e1) = (r[0][l] - fx[l], r[1][l] - fy[l]);
                    ll[l] = self.log_norm[k] - e0 * e0 * h[0] - e1 * e1 * h[1];
                }
                for (l, t) in ll[..n].iter().enumerate() {
                    out[frame_of[b0 + l] * kk + k] += t;
                }
            }
        });
    }
}

impl SubclusterSampler {
    /// The pass: draw the weights and fields, then every frame's label (in parallel, a frame
    /// that is the last of its pattern staying), then the moved frames' sums. Returns how many
    /// frames moved.
    pub(super) fn assignment_pass(&mut self, stop: &dyn Fn() -> bool) -> Result<usize> {
        let t = Instant::now();
        let (slots, bank, log_w) = self.pass_bank()?;
        self.timings.fields += t.elapsed().as_secs_f64();
        if stop() {
            return Err(Error::Interrupted);
        }
        if let Some(chain) = self.held {
            return self.held_assignment_pass(chain, &slots, &bank, &log_w);
        }

        let t = Instant::now();
        let proposed = self.propose_labels(&bank, &log_w, stop)?;
        let moved = self.resolve_moves(&slots, &proposed);
        drop(proposed);
        for &(i, _, to) in &moved {
            self.labels[i] = to;
        }
        self.timings.assign += t.elapsed().as_secs_f64();

        let t = Instant::now();
        self.apply_moves(&moved)?;
        self.timings.sums += t.elapsed().as_secs_f64();
        Ok(moved.len())
    }

    /// The pass over labels the shards hold: they draw, resolve the "last frame" rule with the
    /// leader and move their frames, and return the moved frames' sums per pair of patterns (or
    /// every pattern's, when most frames moved), which are added and taken here in the order of
    /// [`Self::apply_moves`]: the same sums, bitwise. Once the shards have drawn, the pass runs
    /// to its end (Ctrl-C is honoured before it).
    fn held_assignment_pass(
        &mut self,
        chain: u64,
        slots: &[usize],
        bank: &Bank,
        log_w: &[f64],
    ) -> Result<usize> {
        let t = Instant::now();
        let counts: Vec<usize> = slots.iter().map(|&k| self.part(k).sums.n_frames).collect();
        let key = self.draw_key(self.sweep, Phase::Labels);
        let moved = self
            .store
            .held_pass(chain, &self.basis, bank, log_w, slots, &counts, key)?;
        self.timings.assign += t.elapsed().as_secs_f64();
        Ok(match moved {
            Moved::Pairs { moved, sums } => {
                for (&(from, to), s) in &sums {
                    self.move_sums(from, to, s);
                }
                moved
            }
            Moved::Rebuilt { moved, sums } => {
                for (&k, s) in slots.iter().zip(sums) {
                    let p = self.part_mut(k);
                    p.sums = s;
                    p.fit = None;
                }
                moved
            }
        })
    }

    /// The live slots, and the bank and log mixture weights a pass draws under: the patterns'
    /// drawn weights and fields.
    pub(super) fn pass_bank(&mut self) -> Result<(Vec<usize>, Bank, Vec<f64>)> {
        self.refresh_fits()?;
        let slots: Vec<usize> = self.live().map(|(k, _)| k).collect();
        let drawn: Vec<Result<(f64, [Vec<f64>; 2])>> =
            slots.par_iter().map(|&k| self.draw_pattern(k)).collect();
        let (mut log_w, mut weights) = (Vec::new(), Vec::new());
        for d in drawn {
            let (lw, w) = d?;
            log_w.push(lw);
            weights.push(w);
        }
        let noise: Vec<[f64; 2]> = slots
            .iter()
            .map(|&k| self.part(k).params.noise_var)
            .collect();
        let bank = Bank {
            weights,
            noise,
            mean: self.settings.base.mean,
        };
        Ok((slots, bank, log_w))
    }

    /// The moves `(frame, from, to)` of a pass whose draws are `picks` (indices into `slots`):
    /// a frame moves to its draw unless it is the last of its pattern, in frame order. Decided
    /// shard by shard from each shard's labels and draws, the leader walking only the frames of
    /// at-risk patterns (`subcluster_stays.rs`): the moves of the walk over all frames.
    fn resolve_moves(&self, slots: &[usize], picks: &[u32]) -> Vec<(usize, usize, usize)> {
        let k = slots.len();
        let mut index = vec![u32::MAX; self.slots.len()];
        for (b, &s) in slots.iter().enumerate() {
            index[s] = b as u32;
        }
        let ranges: Vec<Range<usize>> = self.store.shard_ranges().collect();
        let shard = |r: &Range<usize>| (&self.labels[r.clone()], &picks[r.clone()]);
        let proposals: Vec<Proposal> = ranges
            .iter()
            .map(|r| {
                let (l, p) = shard(r);
                stays::propose(l, p, &index, k)
            })
            .collect();
        let risk = stays::at_risk(&proposals);
        let kept: Vec<Vec<u32>> = if risk.contains(&true) {
            let counts: Vec<usize> = slots.iter().map(|&s| self.part(s).sums.n_frames).collect();
            let events: Vec<Vec<Event>> = ranges
                .iter()
                .map(|r| {
                    let (l, p) = shard(r);
                    stays::events(l, p, &index, &risk)
                })
                .collect();
            stays::resolve(&counts, &risk, &events)
        } else {
            vec![Vec::new(); ranges.len()]
        };
        let mut moved = Vec::new();
        for (r, st) in ranges.iter().zip(&kept) {
            let (l, p) = shard(r);
            let m = stays::moves(l, p, slots, st);
            moved.extend(m.into_iter().map(|(i, from, to)| (r.start + i, from, to)));
        }
        moved
    }

    /// Pattern `k`'s log mixture weight (up to a constant shared by all patterns) and basis
    /// weights: a draw of `Γ(n_k)` and of the weights' posterior, or (map) `log n_k` and the
    /// posterior mean.
    fn draw_pattern(&self, k: usize) -> Result<(f64, [Vec<f64>; 2])> {
        let id = self.id(k);
        let p = self.part(k);
        let fit: &Fit = p.fit.as_ref().expect("fits refreshed before the pass");
        let n = p.sums.n_frames as f64;
        if self.map() {
            return Ok((n.ln(), fit.post.weights(None)));
        }
        let mut rng = stream(self.settings.seed, self.sweep, Phase::Weights, id);
        let lw = gamma(n, &mut rng)?.ln();
        let mut rng = stream(self.settings.seed, self.sweep, Phase::Fields, id);
        Ok((lw, fit.post.weights(Some(&mut rng))))
    }

    /// Every frame's drawn pattern (an index into the bank's patterns) given the bank, in
    /// parallel over tiles of frames. Kept as 4-byte indices: at 10M frames, slot numbers would
    /// double the largest transient of a sweep.
    fn propose_labels(
        &self,
        bank: &Bank,
        log_w: &[f64],
        stop: &dyn Fn() -> bool,
    ) -> Result<Vec<u32>> {
        let out = self.draw_picks(
            bank,
            log_w,
            0..self.store.len(),
            (self.sweep, Phase::Labels),
        )?;
        // The pass is seconds at most: Ctrl-C is honoured after it, before anything changes.
        if stop() {
            return Err(Error::Interrupted);
        }
        Ok(out)
    }

    /// The drawn (map: most probable) entry of the bank for each frame of `frames`, given the
    /// bank and the log mixture weights, with the uniform of (seed, `key`, frame).
    pub(super) fn draw_picks(
        &self,
        bank: &Bank,
        log_w: &[f64],
        frames: std::ops::Range<usize>,
        (sweep, phase): (u64, Phase),
    ) -> Result<Vec<u32>> {
        let key = self.draw_key(sweep, phase);
        self.store.draw(&self.basis, bank, log_w, frames, key)
    }

    /// The key of the uniforms of a draw at `sweep` in `phase`.
    pub(super) fn draw_key(&self, sweep: u64, phase: Phase) -> DrawKey {
        DrawKey {
            seed: self.settings.seed,
            sweep,
            phase: phase as u64,
            map: self.map(),
        }
    }

    /// Groups of the frames after the first `groups.len()`, drawn by the instantiated conditional
    /// over the groups the first frames form (their length scales `ls` and noise pairs `noise`):
    /// the second half of [`Self::initialize_sequential`].
    pub(super) fn place_later(
        &self,
        groups: &[usize],
        ls: &[crate::frame::LengthScales],
        noise: &[[f64; 2]],
        stop: &dyn Fn() -> bool,
    ) -> Result<Vec<usize>> {
        let k = ls.len();
        let mut members: Vec<Vec<usize>> = vec![Vec::new(); k];
        for (i, &g) in groups.iter().enumerate() {
            members[g].push(i);
        }
        let sums = self.sums_of_sets(&members.iter().map(|m| &m[..]).collect::<Vec<_>>())?;
        let drawn: Vec<Result<(f64, [Vec<f64>; 2])>> = (0..k)
            .into_par_iter()
            .map(|g| {
                let mut params = self.settings.pattern_params(ls[g]);
                params.noise_var = noise[g];
                let post = crate::hsgp_sums::Posterior::new(
                    &self.basis,
                    &sums[g],
                    &sums[g].gram(&self.basis),
                    params,
                )?;
                let n = sums[g].n_frames as f64;
                if self.map() {
                    return Ok((n.ln(), post.weights(None)));
                }
                let mut rng = stream(self.settings.seed, 0, Phase::Init, (1 << 40) + g as u64);
                let lw = gamma(n, &mut rng)?.ln();
                Ok((lw, post.weights(Some(&mut rng))))
            })
            .collect();
        let (mut log_w, mut weights) = (Vec::new(), Vec::new());
        for d in drawn {
            let (lw, w) = d?;
            log_w.push(lw);
            weights.push(w);
        }
        let bank = Bank {
            weights,
            noise: noise.to_vec(),
            mean: self.settings.base.mean,
        };
        if stop() {
            return Err(Error::Interrupted);
        }
        let picks = self.draw_picks(
            &bank,
            &log_w,
            groups.len()..self.store.len(),
            (0, Phase::Init),
        )?;
        Ok(picks.into_iter().map(|p| p as usize).collect())
    }

    /// Move the sums of the `moved` frames `(frame, from, to)`: add each pattern's arrivals and
    /// subtract its departures (or, when most frames moved, rebuild every pattern's sums).
    fn apply_moves(&mut self, moved: &[(usize, usize, usize)]) -> Result<()> {
        if moved.is_empty() {
            return Ok(());
        }
        let slots: Vec<usize> = self.live().map(|(k, _)| k).collect();
        if 2 * moved.len() > self.store.len() {
            let mut index = vec![usize::MAX; self.slots.len()];
            for (j, &k) in slots.iter().enumerate() {
                index[k] = j;
            }
            let sums = self
                .store
                .sums_of_groups(&self.basis, &self.labels, &index, slots.len())?;
            for (&k, s) in slots.iter().zip(sums) {
                let p = self.part_mut(k);
                p.sums = s;
                p.fit = None;
            }
            return Ok(());
        }
        // Each moved frame's sums are computed once, in a group per (from, to) pair, and added
        // to one pattern and taken from the other.
        let mut groups: std::collections::BTreeMap<(usize, usize), Vec<usize>> =
            std::collections::BTreeMap::new();
        for &(i, from, to) in moved {
            groups.entry((from, to)).or_default().push(i);
        }
        let sets: Vec<&[usize]> = groups.values().map(|g| &g[..]).collect();
        let sums = self.sums_of_sets(&sets)?;
        for (&(from, to), s) in groups.keys().zip(&sums) {
            self.move_sums(from, to, s);
        }
        Ok(())
    }
}

/// The index of the largest entry.
pub(super) fn argmax(v: &[f64]) -> usize {
    v.iter()
        .enumerate()
        .fold(
            (0, f64::NEG_INFINITY),
            |b, (i, &x)| if x > b.1 { (i, x) } else { b },
        )
        .0
}

/// The index drawn with probability `∝ exp(logw)` by the uniform `u`.
pub(super) fn pick_log(logw: &[f64], u: f64) -> usize {
    let z = log_sum_exp(logw);
    let mut t = u;
    for (i, w) in logw.iter().enumerate() {
        t -= (w - z).exp();
        if t < 0.0 {
            return i;
        }
    }
    logw.iter()
        .rposition(|w| w.is_finite())
        .unwrap_or(logw.len() - 1)
}
