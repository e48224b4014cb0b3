//! Joint placement of a generated scene's vehicles (docs/generation.md). Two ways, both keeping
//! no pair closer than the pattern's recorded spacing:
//!
//! - [`thin`]: a recorded configuration (one of the pattern's frames), each vehicle kept unless
//!   it stands closer than the spacing to one kept before it (what dpgp generates with: the
//!   counts, spacing and groups of the recordings, minus the overlaps of tracking noise);
//! - [`place`]: positions from a pattern's position histogram, drawn one after another and each
//!   redrawn while it lands closer than the spacing to one already placed (hard-core rejection,
//!   in the manner of a random sequential adsorption process). A vehicle that finds no room in
//!   [`TRIES`] draws is left out, so a crowded scene comes out with fewer vehicles rather than
//!   with an overlapping pair.

use rand::RngExt;
use rand_chacha::ChaCha8Rng;

use crate::error::{Error, Result};
use crate::frame::Point;
use crate::simulate::Roi;

/// Draws per vehicle before it is left out.
pub const TRIES: usize = 200;
/// Share of a bin kept clear of its edges by a draw.
const EDGE: f64 = 1e-5;

/// A histogram of positions over `roi`: `nx * ny` bins (x-major: bin `ix * ny + iy`), uniform
/// inside a bin; `cumulative` holds the running sums of the bin weights.
#[derive(Clone, Debug)]
pub struct Grid {
    roi: Roi,
    nx: usize,
    ny: usize,
    cumulative: Vec<f64>,
}

impl Grid {
    pub fn new(roi: Roi, nx: usize, ny: usize, weights: &[f64]) -> Result<Self> {
        if nx == 0 || ny == 0 || weights.len() != nx * ny {
            return Err(Error::Shape(format!(
                "a {nx} x {ny} position grid needs {} bin weights, got {}",
                nx * ny,
                weights.len()
            )));
        }
        if weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::InvalidInput(
                "bin weights must be finite and >= 0".into(),
            ));
        }
        let mut acc = 0.0;
        let cumulative: Vec<f64> = weights
            .iter()
            .map(|w| {
                acc += w;
                acc
            })
            .collect();
        if acc <= 0.0 {
            return Err(Error::InvalidInput(
                "the position histogram is empty".into(),
            ));
        }
        Ok(Self {
            roi,
            nx,
            ny,
            cumulative,
        })
    }

    /// One position: a bin by its weight, then uniformly inside it.
    pub fn draw(&self, rng: &mut ChaCha8Rng) -> Point {
        let total = *self.cumulative.last().unwrap_or(&1.0);
        let u = rng.random::<f64>() * total;
        let b = self
            .cumulative
            .partition_point(|&c| c <= u)
            .min(self.cumulative.len() - 1);
        let (ix, iy) = (b / self.ny, b % self.ny);
        let wx = (self.roi.x_max - self.roi.x_min) / self.nx as f64;
        let wy = (self.roi.y_max - self.roi.y_min) / self.ny as f64;
        // 1e-5 of a bin away from its edges, so that the bin a position falls in is never in
        // doubt (ψ's binning puts a point within 1e-6 of a bin below an edge in the upper bin)
        let inner = |u: f64| EDGE + (1.0 - 2.0 * EDGE) * u;
        [
            self.roi.x_min + (ix as f64 + inner(rng.random::<f64>())) * wx,
            self.roi.y_min + (iy as f64 + inner(rng.random::<f64>())) * wy,
        ]
    }
}

/// Up to `count` positions from `grid`, no two closer than `spacing`.
pub fn place(grid: &Grid, count: usize, spacing: f64, rng: &mut ChaCha8Rng) -> Vec<Point> {
    let mut out: Vec<Point> = Vec::with_capacity(count);
    for _ in 0..count {
        for _ in 0..TRIES {
            let p = grid.draw(rng);
            if out
                .iter()
                .all(|q| (p[0] - q[0]).hypot(p[1] - q[1]) >= spacing)
            {
                out.push(p);
                break;
            }
        }
    }
    out
}

/// The positions of `candidates` (in order) kept by the hard core: each unless it stands closer
/// than `spacing` to one kept before it.
pub fn thin(candidates: &[Point], spacing: f64) -> Vec<Point> {
    thin_kept(candidates, spacing)
        .into_iter()
        .map(|i| candidates[i])
        .collect()
}

/// The indices of the candidates [`thin`] keeps, in order.
pub fn thin_kept(candidates: &[Point], spacing: f64) -> Vec<usize> {
    let mut kept: Vec<usize> = Vec::with_capacity(candidates.len());
    for (i, &p) in candidates.iter().enumerate() {
        if kept.iter().all(|&k| {
            let q = candidates[k];
            (p[0] - q[0]).hypot(p[1] - q[1]) >= spacing
        }) {
            kept.push(i);
        }
    }
    kept
}

#[cfg(test)]
#[path = "tests/placement.rs"]
mod tests;
