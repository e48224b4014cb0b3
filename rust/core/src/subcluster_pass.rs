//! The sub-cluster sampler's assignment pass: draw the patterns' weights and fields, give every
//! frame its label in parallel, and update the sums of the patterns frames moved between.
//!
//! **Fields at many points at once.** A field is `φ(x)ᵀ a` with `φ_jk = s_j(x) t_k(y)`, so with the
//! weights as an `m_x x m_y` matrix `A` it is `s(x)ᵀ A t(y)`. For a chunk of points with per-axis
//! values `S` (`n x m_x`) and `T` (`n x m_y`), one matrix product `T [A_1ᵀ … A_Fᵀ]` (or
//! `S [A_1 … A_F]`, whichever axis has more functions is the inner dimension) gives every field `f`
//! as the row sums of `(T A_fᵀ) ∘ S`: `2 n M F` flops at matrix-product speed, and no `M`-long
//! feature vector is formed (writing those cost as much as the product).

use std::time::Instant;

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use rayon::prelude::*;

use super::shard::{Bank, DrawKey};
use super::{Fit, SubclusterSampler, gamma};
use crate::basis::{AxisValues, Basis};
use crate::error::{Error, Result};
use crate::frame::Point;
use crate::gp::LN_2PI;
use crate::rng::{Phase, stream};
use crate::special::log_sum_exp;

/// Frames per parallel task of a pass.
pub(super) const TILE: usize = 128;
/// Points per matrix product.
const CHUNK: usize = 256;
/// Doubles of a product's output held at once (a quarter of a core's L2 cache).
const PRODUCT_DOUBLES: usize = 32 * 1024;

/// Several patterns' fields, stacked for one matrix product per chunk of points, with each
/// pattern's noise: what a frame's log-likelihood under each pattern needs.
pub(super) struct FieldBank {
    /// Patterns.
    k: usize,
    /// Whether the product's inner dimension is the y axis (the axis with more functions).
    inner_y: bool,
    inner: usize,
    outer: usize,
    /// `inner x (2K outer)`, column-major: field `2k + d` (pattern k, output d) in columns
    /// `(2k + d) outer ..`; the weights `A[j, k]` of `φ_jk` arranged so that the product with one
    /// axis's values leaves a dot product with the other's.
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
        let [mx, my] = basis.counts();
        let inner_y = my >= mx;
        let (inner, outer) = if inner_y { (my, mx) } else { (mx, my) };
        let mut w = Vec::with_capacity(inner * outer * 2 * weights.len());
        for a in weights.iter().flatten() {
            for o in 0..outer {
                if inner_y {
                    w.extend((0..my).map(|k| a[o + mx * k])); // column j = o: A[j, ·]
                } else {
                    w.extend_from_slice(&a[mx * o..mx * (o + 1)]); // column k = o: A[·, k]
                }
            }
        }
        Self {
            k: weights.len(),
            inner_y,
            inner,
            outer,
            w,
            mean,
            inv_noise: noise.iter().map(|n| [1.0 / n[0], 1.0 / n[1]]).collect(),
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
        let kk = self.k;
        let fields = 2 * kk;
        let (inner, outer) = (self.inner, self.outer);
        let group = (PRODUCT_DOUBLES / (CHUNK * outer)).clamp(1, fields);
        let mut frame_of = Vec::with_capacity(xy.len());
        for (f, w) in starts.windows(2).enumerate() {
            frame_of.extend(std::iter::repeat_n(f, w[1] - w[0]));
        }
        let mut prod = vec![0.0; CHUNK * outer * group];
        let mut acc = vec![0.0; CHUNK];
        for c0 in (0..xy.len()).step_by(CHUNK) {
            let c1 = (c0 + CHUNK).min(xy.len());
            let n = c1 - c0;
            let vals = AxisValues::new(basis, &xy[c0..c1]);
            let (s_in, s_out) = if self.inner_y {
                (&vals.sy, &vals.sx)
            } else {
                (&vals.sx, &vals.sy)
            };
            for p in c0..c1 {
                let row = &mut out[frame_of[p] * kk..(frame_of[p] + 1) * kk];
                for (r, l) in row.iter_mut().zip(&self.log_norm) {
                    *r += l;
                }
            }
            for g0 in (0..fields).step_by(group) {
                let g1 = (g0 + group).min(fields);
                let cols = (g1 - g0) * outer;
                let prod = &mut prod[..n * cols];
                matmul(
                    MatMut::from_column_major_slice_mut(prod, n, cols),
                    Accum::Replace,
                    MatRef::from_column_major_slice(s_in, n, inner),
                    MatRef::from_column_major_slice(
                        &self.w[g0 * outer * inner..g1 * outer * inner],
                        inner,
                        cols,
                    ),
                    1.0,
                    Par::Seq,
                );
                for f in g0..g1 {
                    let acc = &mut acc[..n];
                    acc.fill(0.0);
                    let base = (f - g0) * outer;
                    for o in 0..outer {
                        let u = &prod[(base + o) * n..(base + o + 1) * n];
                        let t = &s_out[o * n..(o + 1) * n];
                        for ((a, u), t) in acc.iter_mut().zip(u).zip(t) {
                            *a += u * t;
                        }
                    }
                    let (k, d) = (f / 2, f % 2);
                    let (mu, half_inv) = (self.mean[d], 0.5 * self.inv_noise[k][d]);
                    for (i, a) in acc.iter().enumerate() {
                        let r = v[c0 + i][d] - mu - a;
                        out[frame_of[c0 + i] * kk + k] -= r * r * half_inv;
                    }
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
        let bank = Bank {
            weights,
            noise,
            mean: self.settings.base.mean,
        };
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
        self.apply_moves(&moved)?;
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
        bank: &Bank,
        log_w: &[f64],
        slots: &[usize],
        stop: &dyn Fn() -> bool,
    ) -> Result<Vec<usize>> {
        let out = self.draw_labels(
            bank,
            log_w,
            slots,
            0..self.store.len(),
            (self.sweep, Phase::Labels),
        )?;
        // The pass is seconds at most: Ctrl-C is honoured after it, before anything changes.
        if stop() {
            return Err(Error::Interrupted);
        }
        Ok(out)
    }

    /// The drawn (map: most probable) entry of `targets` for each frame of `frames`, given the
    /// bank and the log mixture weights, with the uniform of (seed, `key`, frame).
    pub(super) fn draw_labels(
        &self,
        bank: &Bank,
        log_w: &[f64],
        targets: &[usize],
        frames: std::ops::Range<usize>,
        (sweep, phase): (u64, Phase),
    ) -> Result<Vec<usize>> {
        let key = DrawKey {
            seed: self.settings.seed,
            sweep,
            phase: phase as u64,
            map: self.map(),
        };
        let picks = self.store.draw(&self.basis, bank, log_w, frames, key)?;
        Ok(picks.into_iter().map(|p| targets[p as usize]).collect())
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
        let targets: Vec<usize> = (0..k).collect();
        self.draw_labels(
            &bank,
            &log_w,
            &targets,
            groups.len()..self.store.len(),
            (0, Phase::Init),
        )
    }

    /// Move the sums of the `moved` frames `(frame, from, to)`: add each pattern's arrivals and
    /// subtract its departures (or, when most frames moved, rebuild every pattern's sums).
    fn apply_moves(&mut self, moved: &[(usize, usize, usize)]) -> Result<()> {
        if moved.is_empty() {
            return Ok(());
        }
        let slots: Vec<usize> = self.live().map(|(k, _)| k).collect();
        if 2 * moved.len() > self.store.len() {
            let sets: Vec<Vec<usize>> = slots
                .iter()
                .map(|&k| {
                    (0..self.labels.len())
                        .filter(|&i| self.labels[i] == k)
                        .collect()
                })
                .collect();
            let sums = self.sums_of_sets(&sets.iter().map(|s| &s[..]).collect::<Vec<_>>())?;
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
            let dest = self.part_mut(to);
            dest.sums.add(s);
            dest.fit = None;
            let src = self.part_mut(from);
            src.sums.sub(s);
            src.fit = None;
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
