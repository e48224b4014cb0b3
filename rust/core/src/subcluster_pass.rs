//! The sub-cluster sampler's assignment pass: draw the patterns' weights and fields, give every
//! frame its label in parallel, and update the sums of the patterns frames moved between.
//!
//! **Fields at many points at once.** For a chunk of points, the features `Φ` (`n x M`, each
//! `φ_jk = s_j(x) t_k(y)` from per-axis values by recurrence) times the stacked weights `W`
//! (`M x 2K`: every pattern's two outputs) give every field at every point in one matrix product
//! whose inner dimension is `M`: `2 n M K` flops at matrix-product speed.

use std::time::Instant;

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use rayon::prelude::*;

use super::{Fit, SubclusterSampler, gamma};
use crate::basis::{AxisValues, Basis};
use crate::error::{Error, Result};
use crate::frame::Point;
use crate::gp::LN_2PI;
use crate::rng::{Phase, stream, uniform};
use crate::special::log_sum_exp;

/// Frames per parallel task of a pass.
pub(super) const TILE: usize = 128;
/// Doubles of a chunk's features held at once (a quarter of a core's L2 cache).
const FEATURE_DOUBLES: usize = 32 * 1024;

/// Several patterns' fields, stacked for one matrix product per chunk of points, with each
/// pattern's noise: what a frame's log-likelihood under each pattern needs.
pub(super) struct FieldBank {
    /// Patterns.
    k: usize,
    m: usize,
    /// `M x 2K`, column-major: field `2k + d` (pattern k, output d) in column `2k + d`.
    w: Vec<f64>,
    mean: [f64; 2],
    /// Per pattern: `1 / σ_n,d²`, and `−½ Σ_d log(2π σ_n,d²)` per point.
    inv_noise: Vec<[f64; 2]>,
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
        Self {
            k: weights.len(),
            m: basis.len(),
            w: weights.iter().flatten().flatten().copied().collect(),
            mean,
            inv_noise: noise.iter().map(|n| [1.0 / n[0], 1.0 / n[1]]).collect(),
            log_norm: noise
                .iter()
                .map(|n| -0.5 * (2.0 * LN_2PI + n[0].ln() + n[1].ln()))
                .collect(),
        }
    }

    /// Add to `out[f K + k]` the log-likelihood of frame `f`'s velocities under pattern `k`'s
    /// field and noise, for frames whose points are `xy`, `v` with frame `f` starting at
    /// `starts[f]` (`starts` ends with `xy.len()`).
    pub(super) fn frame_logliks(
        &self,
        basis: &Basis,
        xy: &[Point],
        v: &[[f64; 2]],
        starts: &[usize],
        out: &mut [f64],
    ) {
        let (kk, m) = (self.k, self.m);
        let fields = 2 * kk;
        let [mx, my] = basis.counts();
        let chunk = (FEATURE_DOUBLES / m).clamp(16, 512);
        let mut frame_of = Vec::with_capacity(xy.len());
        for (f, w) in starts.windows(2).enumerate() {
            frame_of.extend(std::iter::repeat_n(f, w[1] - w[0]));
        }
        let mut phi = vec![0.0; chunk * m];
        let mut mean = vec![0.0; chunk * fields];
        for c0 in (0..xy.len()).step_by(chunk) {
            let c1 = (c0 + chunk).min(xy.len());
            let n = c1 - c0;
            let vals = AxisValues::new(basis, &xy[c0..c1]);
            for k in 0..my {
                let t = &vals.sy[k * n..(k + 1) * n];
                for j in 0..mx {
                    let s = &vals.sx[j * n..(j + 1) * n];
                    let col = &mut phi[(j + mx * k) * n..(j + mx * k + 1) * n];
                    for ((c, s), t) in col.iter_mut().zip(s).zip(t) {
                        *c = s * t;
                    }
                }
            }
            let mean = &mut mean[..n * fields];
            matmul(
                MatMut::from_column_major_slice_mut(mean, n, fields),
                Accum::Replace,
                MatRef::from_column_major_slice(&phi[..n * m], n, m),
                MatRef::from_column_major_slice(&self.w, m, fields),
                1.0,
                Par::Seq,
            );
            for (i, p) in (c0..c1).enumerate() {
                let row = &mut out[frame_of[p] * kk..(frame_of[p] + 1) * kk];
                for k in 0..kk {
                    let mut ll = self.log_norm[k];
                    for d in 0..2 {
                        let r = v[p][d] - self.mean[d] - mean[(2 * k + d) * n + i];
                        ll -= 0.5 * r * r * self.inv_noise[k][d];
                    }
                    row[k] += ll;
                }
            }
        }
    }
}

impl SubclusterSampler {
    /// The pass: draw the weights and fields, then every frame's label (in parallel, a frame
    /// that is the last of its pattern staying), then the moved frames' sums. Returns how many
    /// frames moved.
    pub(super) fn assignment_pass(&mut self, stop: &dyn Fn() -> bool) -> Result<usize> {
        let t = Instant::now();
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
        let bank = FieldBank::new(&self.basis, &weights, &noise, self.settings.base.mean);
        self.timings.fields += t.elapsed().as_secs_f64();
        if stop() {
            return Err(Error::Interrupted);
        }

        let t = Instant::now();
        let proposed = self.propose_labels(&bank, &log_w, &slots, stop)?;
        // In frame order: a frame moves to its draw unless it is the last of its pattern.
        let mut counts = vec![0usize; self.slots.len()];
        for &k in &slots {
            counts[k] = self.part(k).sums.n_frames;
        }
        let mut moved: Vec<(usize, usize, usize)> = Vec::new();
        for (i, &to) in proposed.iter().enumerate() {
            let from = self.labels[i];
            if to != from && counts[from] > 1 {
                counts[from] -= 1;
                counts[to] += 1;
                self.labels[i] = to;
                moved.push((i, from, to));
            }
        }
        self.timings.assign += t.elapsed().as_secs_f64();

        let t = Instant::now();
        self.apply_moves(&moved);
        self.timings.sums += t.elapsed().as_secs_f64();
        Ok(moved.len())
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

    /// Every frame's drawn pattern (slots) given the bank, in parallel over tiles of frames.
    fn propose_labels(
        &self,
        bank: &FieldBank,
        log_w: &[f64],
        slots: &[usize],
        stop: &dyn Fn() -> bool,
    ) -> Result<Vec<usize>> {
        let n = self.data.len();
        let (xy, v) = self.data.points();
        let offsets = self.data.offsets();
        let kk = slots.len();
        let (seed, sweep, map) = (self.settings.seed, self.sweep, self.map());
        let tiles: Vec<Vec<usize>> = (0..n.div_ceil(TILE))
            .into_par_iter()
            .map(|t| {
                let (f0, f1) = (t * TILE, ((t + 1) * TILE).min(n));
                let (a, b) = (offsets[f0], offsets[f1]);
                let starts: Vec<usize> = offsets[f0..=f1].iter().map(|o| o - a).collect();
                let mut ll = vec![0.0; (f1 - f0) * kk];
                bank.frame_logliks(&self.basis, &xy[a..b], &v[a..b], &starts, &mut ll);
                (f0..f1)
                    .zip(ll.chunks(kk))
                    .map(|(i, l)| {
                        let lp: Vec<f64> = l.iter().zip(log_w).map(|(l, w)| l + w).collect();
                        let pick = if map {
                            argmax(&lp)
                        } else {
                            pick_log(&lp, uniform(seed, sweep, Phase::Labels, i as u64))
                        };
                        slots[pick]
                    })
                    .collect()
            })
            .collect();
        // The pass is seconds at most: Ctrl-C is honoured after it, before anything changes.
        if stop() {
            return Err(Error::Interrupted);
        }
        Ok(tiles.concat())
    }

    /// Move the sums of the `moved` frames `(frame, from, to)`: add each pattern's arrivals and
    /// subtract its departures (or, when most frames moved, rebuild every pattern's sums).
    fn apply_moves(&mut self, moved: &[(usize, usize, usize)]) {
        if moved.is_empty() {
            return;
        }
        let slots: Vec<usize> = self.live().map(|(k, _)| k).collect();
        if 2 * moved.len() > self.data.len() {
            let sets: Vec<Vec<usize>> = slots
                .iter()
                .map(|&k| {
                    (0..self.labels.len())
                        .filter(|&i| self.labels[i] == k)
                        .collect()
                })
                .collect();
            let sums = self.sums_of_sets(&sets.iter().map(|s| &s[..]).collect::<Vec<_>>());
            for (&k, s) in slots.iter().zip(sums) {
                let p = self.part_mut(k);
                p.sums = s;
                p.fit = None;
            }
            return;
        }
        let mut arrive: Vec<Vec<usize>> = vec![Vec::new(); self.slots.len()];
        let mut leave: Vec<Vec<usize>> = vec![Vec::new(); self.slots.len()];
        for &(i, from, to) in moved {
            arrive[to].push(i);
            leave[from].push(i);
        }
        let touched: Vec<usize> = slots
            .into_iter()
            .filter(|&k| !arrive[k].is_empty() || !leave[k].is_empty())
            .collect();
        let sets: Vec<&[usize]> = touched
            .iter()
            .flat_map(|&k| [&arrive[k][..], &leave[k][..]])
            .collect();
        let sums = self.sums_of_sets(&sets);
        for (j, &k) in touched.iter().enumerate() {
            let p = self.part_mut(k);
            p.sums.add(&sums[2 * j]);
            p.sums.sub(&sums[2 * j + 1]);
            p.fit = None;
        }
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
