//! The cheap score behind `proposal="informed"` (docs/engine.md, "Informed proposals"): per
//! pattern, counts, sums and sums of squares of its velocities over a grid of cells. A frame's
//! cheap log density under a pattern treats its vehicles as independent normals around their
//! cells' mean velocities:
//! `O(l)` per pattern, against `O(l n_k²)` (exact) or `O(l M²)` (hsgp) for the model's score.
//!
//! The statistics are sums over frames, so the score of a frame against its own pattern can
//! leave the frame out exactly. The proposal is then a function of the other frames' patterns
//! only, which is what makes the Metropolis–Hastings correction valid.

use std::sync::Arc;

use crate::frame::FrameRef;
use crate::frame::Point;
use crate::gp::{GpParams, LN_2PI};

/// Most cells along one axis.
const MAX_CELLS: usize = 64;
/// Pseudo-observations that pull a cell's mean and spread towards the pattern's.
const PRIOR_WEIGHT: f64 = 1.0;
/// The grid starts this fraction of a cell below the data. Exports quantise positions (NGSIM:
/// 0.1 ft), and with the grid starting at the lowest position, cell boundaries at simple
/// fractions of the extent fall exactly on data points, whose cells then depend on the last
/// bit of a division, so the same data in feet and in metres gave different proposals. An
/// irrational offset (1 − 1/φ) keeps every boundary off any decimal grid.
const GRID_OFFSET: f64 = 0.381_966_011_250_105_1;

/// A regular grid over the training positions (points outside fall into the edge cells, so the
/// last cell along an axis stretches over the grid's offset).
#[derive(Clone, Debug)]
pub struct CellGrid {
    origin: [f64; 2],
    size: [f64; 2],
    n: [usize; 2],
}

impl CellGrid {
    /// Cells of about `cell` per axis over the bounding box of `xy`, at most 64 per axis.
    pub fn new(xy: &[Point], cell: [f64; 2]) -> Self {
        let mut origin = [0.0; 2];
        let mut size = [1.0; 2];
        let mut n = [1; 2];
        for d in 0..2 {
            let lo = xy.iter().map(|p| p[d]).fold(f64::INFINITY, f64::min);
            let hi = xy.iter().map(|p| p[d]).fold(f64::NEG_INFINITY, f64::max);
            if !(lo.is_finite() && hi.is_finite()) {
                continue;
            }
            let extent = hi - lo;
            let want = if cell[d] > 0.0 && cell[d].is_finite() {
                (extent / cell[d]).ceil()
            } else {
                1.0
            };
            n[d] = (want as usize).clamp(1, MAX_CELLS);
            size[d] = if extent > 0.0 {
                extent / n[d] as f64
            } else {
                1.0
            };
            origin[d] = lo - GRID_OFFSET * size[d];
        }
        Self { origin, size, n }
    }

    pub fn len(&self) -> usize {
        self.n[0] * self.n[1]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn cell(&self, p: Point) -> usize {
        let idx = |d: usize| {
            let t = ((p[d] - self.origin[d]) / self.size[d]).floor();
            if t.is_nan() || t < 0.0 {
                0
            } else {
                (t as usize).min(self.n[d] - 1)
            }
        };
        idx(0) + self.n[0] * idx(1)
    }

    pub fn cells(&self, xy: &[Point]) -> Vec<usize> {
        xy.iter().map(|&p| self.cell(p)).collect()
    }
}

/// One pattern's per-cell velocity statistics.
#[derive(Clone, Debug)]
pub struct CellStats {
    grid: Arc<CellGrid>,
    count: Vec<f64>,
    sum: Vec<[f64; 2]>,
    sq: Vec<[f64; 2]>,
    total: f64,
    total_sum: [f64; 2],
}

impl CellStats {
    pub fn new(grid: Arc<CellGrid>) -> Self {
        let c = grid.len();
        Self {
            grid,
            count: vec![0.0; c],
            sum: vec![[0.0; 2]; c],
            sq: vec![[0.0; 2]; c],
            total: 0.0,
            total_sum: [0.0; 2],
        }
    }

    pub fn bytes(&self) -> usize {
        40 * self.count.len()
    }

    /// Add (`sign = 1`) or remove (`sign = −1`) a frame.
    pub fn add(&mut self, f: FrameRef<'_>, sign: f64) {
        for (p, v) in f.xy.iter().zip(f.v) {
            let c = self.grid.cell(*p);
            self.count[c] += sign;
            self.total += sign;
            for d in 0..2 {
                self.sum[c][d] += sign * v[d];
                self.sq[c][d] += sign * v[d] * v[d];
                self.total_sum[d] += sign * v[d];
            }
        }
    }

    /// Cheap `log p(V_f)` under this pattern; with `exclude`, the frame (a member) is left out
    /// of the statistics first.
    pub fn score(&self, f: FrameRef<'_>, cells: &[usize], exclude: bool, p: &GpParams) -> f64 {
        let sign = if exclude { 1.0 } else { 0.0 };
        let mut total = self.total - sign * f.xy.len() as f64;
        let mut tsum = self.total_sum;
        if exclude {
            for v in f.v {
                tsum[0] -= v[0];
                tsum[1] -= v[1];
            }
        }
        if total < 0.5 {
            total = 0.0;
        }
        let pattern_mean = [0, 1].map(|d| {
            if total > 0.0 {
                tsum[d] / total
            } else {
                p.mean[d]
            }
        });
        let mut out = 0.0;
        for (&c, v) in cells.iter().zip(f.v) {
            // This cell's statistics without the frame's own vehicles in it.
            let (mut n, mut s, mut q) = (self.count[c], self.sum[c], self.sq[c]);
            if exclude {
                for (&c2, v2) in cells.iter().zip(f.v) {
                    if c2 == c {
                        n -= 1.0;
                        for d in 0..2 {
                            s[d] -= v2[d];
                            q[d] -= v2[d] * v2[d];
                        }
                    }
                }
            }
            let n = if n < 0.5 { 0.0 } else { n };
            for d in 0..2 {
                let mean = (s[d] + PRIOR_WEIGHT * pattern_mean[d]) / (n + PRIOR_WEIGHT);
                let spread = if n > 0.0 {
                    (q[d] - s[d] * s[d] / n).max(0.0)
                } else {
                    0.0
                };
                let prior_var = p.signal_var[d] + p.noise_var[d];
                let var =
                    ((spread + PRIOR_WEIGHT * prior_var) / (n + PRIOR_WEIGHT)).max(p.noise_var[d]);
                let r = v[d] - mean;
                out -= 0.5 * (LN_2PI + var.ln() + r * r / var);
            }
        }
        out
    }
}

/// Cheap `log p(V_f)` under a new pattern: each component `N(μ, σ² + σ_n²)` independently.
pub fn prior_score(f: FrameRef<'_>, p: &GpParams) -> f64 {
    let mut out = 0.0;
    for v in f.v {
        for d in 0..2 {
            let var = p.signal_var[d] + p.noise_var[d];
            let r = v[d] - p.mean[d];
            out -= 0.5 * (LN_2PI + var.ln() + r * r / var);
        }
    }
    out
}

#[cfg(test)]
#[path = "tests/proposal.rs"]
mod tests;
