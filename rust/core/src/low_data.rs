//! The low-data flags of a pattern's field, decided by a bound where it can.
//!
//! A rollout flags a point whose latent posterior variance exceeds a fraction `f` of the prior's
//! (the field there is mostly the prior). That variance is a triangular solve per point and step,
//! `M²` over a reduced-rank pattern's statistics and `n²` over a dense factor: most of a
//! generation with flags (95 % over heading, `M` 1,084). Conditioning on fewer observations never
//! lowers a Gaussian posterior variance, so the variance given the point's few nearest training
//! points (a `k x k` system under the pattern's own kernel) bounds the full one from above: where
//! that bound is below the threshold the flag is off, exactly. Points the bound cannot decide
//! (near or over the threshold, no neighbours, outside a reduced basis's box) take the full solve.
//! A rollout asks for the flags of all its steps at once, after its last step (they move no
//! vehicle: `simulate::LateFlags`), so those solves are one with many right-hand sides: asked step
//! by step, each read the pattern's whole factor (9 MB at `M` 1,084) for a few points.

use crate::correlation::Correlation;
use crate::frame::{Inputs, Point};
use crate::gp::GpParams;
use crate::small;

/// Training points the bound conditions on.
const NEIGHBOURS: usize = 8;
/// Points looked at to choose them, spread over the query's cell and then the rings around it.
const CANDIDATES: usize = 48;
/// Grid cells per axis over the training points' bounding box: at most this many, and about
/// [`PER_CELL`] points a cell on average (sparse patterns get coarse cells).
const MAX_CELLS: usize = 64;
const PER_CELL: f64 = 4.0;
/// Rings of cells searched around a query's own.
const RINGS: usize = 2;
/// A bound decides "not low-data" only this far (a share of the prior variance) below the
/// threshold, so that rounding in the two computations never clears a flag the full solve would
/// set (and at a threshold of 0, where any variance is a flag, it decides nothing).
const MARGIN: f64 = 1e-9;

/// A pattern's training points by grid cell over their bounding box (CSR: `starts` per cell).
#[derive(Debug, Clone)]
pub(crate) struct PointGrid {
    cells: usize,
    lo: [f64; 2],
    cell: [f64; 2],
    starts: Vec<usize>,
    idx: Vec<usize>,
}

impl PointGrid {
    pub(crate) fn new(xy: &[Point]) -> Self {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for p in xy {
            for d in 0..2 {
                lo[d] = lo[d].min(p[d]);
                hi[d] = hi[d].max(p[d]);
            }
        }
        let cells = ((xy.len() as f64 / PER_CELL).sqrt().ceil() as usize).clamp(1, MAX_CELLS);
        // a degenerate (or empty) extent is one cell along that axis
        let cell = [0, 1].map(|d| {
            let c = (hi[d] - lo[d]) / cells as f64;
            if c.is_normal() { c } else { f64::MAX }
        });
        let mut grid = Self {
            cells,
            lo,
            cell,
            starts: vec![0; cells * cells + 1],
            idx: vec![0; xy.len()],
        };
        let of: Vec<usize> = xy.iter().map(|&p| grid.cell_of(p)).collect();
        for &c in &of {
            grid.starts[c + 1] += 1;
        }
        for i in 0..cells * cells {
            grid.starts[i + 1] += grid.starts[i];
        }
        let mut fill = grid.starts.clone();
        for (i, &c) in of.iter().enumerate() {
            grid.idx[fill[c]] = i;
            fill[c] += 1;
        }
        grid
    }

    pub(crate) fn bytes(&self) -> usize {
        8 * (self.starts.len() + self.idx.len())
    }

    /// The cell of `p` along axis `d`, clamped to the grid (a point beyond the box searches
    /// from its nearest cells).
    fn axis_cell(&self, p: Point, d: usize) -> usize {
        let t = ((p[d] - self.lo[d]) / self.cell[d]).floor();
        if t.is_nan() {
            0
        } else {
            t.clamp(0.0, (self.cells - 1) as f64) as usize
        }
    }

    fn cell_of(&self, p: Point) -> usize {
        self.axis_cell(p, 0) + self.cells * self.axis_cell(p, 1)
    }

    /// Up to [`CANDIDATES`] training points from the query's cell outwards, ring by ring; within
    /// a crowded ring, spread evenly over its points rather than its first ones.
    fn candidates(&self, p: Point, out: &mut Vec<usize>) {
        out.clear();
        let (cx, cy) = (self.axis_cell(p, 0), self.axis_cell(p, 1));
        let mut ring_cells = Vec::new();
        for ring in 0..=RINGS {
            ring_cells.clear();
            let last = self.cells - 1;
            let (x0, x1) = (cx.saturating_sub(ring), (cx + ring).min(last));
            let (y0, y1) = (cy.saturating_sub(ring), (cy + ring).min(last));
            for y in y0..=y1 {
                for x in x0..=x1 {
                    // this ring's cells only: the inner ones were taken before
                    if x.abs_diff(cx) == ring || y.abs_diff(cy) == ring {
                        ring_cells.push(x + self.cells * y);
                    }
                }
            }
            let total: usize = (ring_cells.iter())
                .map(|&c| self.starts[c + 1] - self.starts[c])
                .sum();
            let room = CANDIDATES - out.len();
            let stride = total.div_ceil(room).max(1);
            let mut k = 0;
            for &c in &ring_cells {
                for &i in &self.idx[self.starts[c]..self.starts[c + 1]] {
                    if k % stride == 0 && out.len() < CANDIDATES {
                        out.push(i);
                    }
                    k += 1;
                }
            }
            if out.len() >= NEIGHBOURS {
                return;
            }
        }
    }
}

/// Whether latent variances `v` exceed `f` times the prior's `s2` in either output: the
/// low-data flag of one point.
pub(crate) fn is_low(v: [f64; 2], s2: [f64; 2], f: f64) -> bool {
    (0..2).any(|d| v[d] > f * s2[d])
}

/// What the bound needs of a pattern: its training inputs, hyperparameters and kernel, and per
/// output group `(outputs, σ², σ_n²)`.
pub(crate) struct Model<'a> {
    pub train: Inputs<'a>,
    pub params: &'a GpParams,
    pub corr: &'a Correlation,
    pub groups: Vec<(&'static [usize], f64, f64)>,
}

/// The low-data flags at `q` (threshold `f` of the prior variance per output): the bound where
/// it decides, `full` (each point's exact latent variances) for the rest.
pub(crate) fn flags(
    m: &Model<'_>,
    grid: &PointGrid,
    q: Inputs<'_>,
    f: f64,
    full: impl Fn(Inputs<'_>) -> Vec<[f64; 2]>,
) -> Vec<bool> {
    let s2 = m.params.signal_var;
    let mut out = vec![false; q.len()];
    let mut open: Vec<usize> = Vec::new();
    let mut cand = Vec::new();
    for j in 0..q.len() {
        let p = q.xy[j];
        let decided = !m.corr.unsupported(p)
            && bound_at(m, grid, p, q.heading(j), &mut cand).is_some_and(|var| {
                (m.groups.iter().zip(&var))
                    .all(|(g, v)| g.0.iter().all(|&d| *v <= (f - MARGIN) * s2[d]))
            });
        if !decided {
            open.push(j);
        }
    }
    if open.is_empty() {
        return out;
    }
    let xy: Vec<Point> = open.iter().map(|&j| q.xy[j]).collect();
    let h: Vec<f64> = if q.h.is_empty() {
        Vec::new()
    } else {
        open.iter().map(|&j| q.h[j]).collect()
    };
    let var = full(Inputs { xy: &xy, h: &h });
    for (&j, v) in open.iter().zip(&var) {
        out[j] = is_low(*v, s2, f);
    }
    out
}

/// Per group, the latent variance at `(p, h)` given only its nearest training points' noisy
/// velocities: an upper bound on the full posterior's. `None` without neighbours.
fn bound_at(
    m: &Model<'_>,
    grid: &PointGrid,
    p: Point,
    h: f64,
    cand: &mut Vec<usize>,
) -> Option<Vec<f64>> {
    grid.candidates(p, cand);
    if cand.is_empty() {
        return None;
    }
    let ls = m.params.length_scales;
    let dist = |i: usize| {
        let (x, hi) = (m.train.xy[i], m.train.heading(i));
        let dx = (x[0] - p[0]) / ls.wx;
        let dy = (x[1] - p[1]) / ls.wy;
        let dh = if (hi - h).is_finite() && ls.wh.is_finite() {
            2.0 * (1.0 - (hi - h).cos()) / (ls.wh * ls.wh)
        } else {
            0.0
        };
        dx * dx + dy * dy + dh
    };
    let k = cand.len().min(NEIGHBOURS);
    if cand.len() > k {
        cand.select_nth_unstable_by(k - 1, |&a, &b| dist(a).total_cmp(&dist(b)));
    }
    // The neighbours, then the query.
    let mut xy: Vec<Point> = cand[..k].iter().map(|&i| m.train.xy[i]).collect();
    xy.push(p);
    let hs: Vec<f64> = if m.train.h.is_empty() && h.is_nan() {
        Vec::new()
    } else {
        let mut hs: Vec<f64> = cand[..k].iter().map(|&i| m.train.heading(i)).collect();
        hs.push(h);
        hs
    };
    let pts = Inputs { xy: &xy, h: &hs };
    let n = k + 1;
    let c = m.corr.cross(pts, pts, ls, 1.0);
    let mut out = Vec::with_capacity(m.groups.len());
    for &(_, s2, noise) in &m.groups {
        let mut knn: Vec<f64> = (0..k * k).map(|e| s2 * c[(e / k) * n + e % k]).collect();
        for i in 0..k {
            knn[i * k + i] += noise;
        }
        // (a jittered factor adds noise: the bound stays an upper bound)
        small::cholesky(&mut knn, k).ok()?;
        let mut kq: Vec<f64> = (0..k).map(|i| s2 * c[k * n + i]).collect();
        small::solve_lower(&knn, k, &mut kq);
        let explained: f64 = kq.iter().map(|x| x * x).sum();
        out.push(s2 * c[k * n + k] - explained);
    }
    Some(out)
}

#[cfg(test)]
#[path = "tests/low_data.rs"]
mod tests;
