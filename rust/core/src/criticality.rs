//! Criticality measures of a scene: how near its vehicles come to colliding (issue 35).
//!
//! A scene is a rollout's grid: `steps + 1` times by `l` vehicles, time-major, each cell a
//! position, a velocity and whether the vehicle is there (inside the ROI). Each vehicle is a
//! rectangle, its length along its heading and its width across, centred on its position. Its
//! heading is its velocity's direction when that is at least `min_speed` fast, else its recorded
//! heading when the scene gives one (recorded frames' `prev_heading`: the heading it last moved
//! with), else the last such direction (before any, the first one after; a vehicle that never
//! moves and has no recorded heading faces +x: a standing queue's vehicles faced across their
//! lanes and touched their neighbours').
//!
//! Per pair of vehicles, over the times both are there:
//! - **time to collision**: how long until their rectangles would touch if both kept their
//!   velocities (0 when they touch now, ∞ when they never would), the least over the times;
//! - **gap**: the distance between the rectangles (0 when they touch), the least over the times;
//! - **collision**: the rectangles touch at one of the times;
//! - **post-encroachment time**: where the two centre paths cross, the time from the first
//!   vehicle's rear leaving the crossing point to the second's front reaching it (0 when both
//!   are on it at once), the least over the crossings; ∞ without a crossing both reach.
//!
//! Per vehicle, the **hardest deceleration**: the largest drop of its speed per second between
//! consecutive times it is there (0 when it never slows).

use crate::error::{Error, Result};
use crate::frame::Point;

/// A vehicle's rectangle: centre, unit heading, half its length and half its width.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rect {
    pub c: Point,
    pub u: [f64; 2],
    pub half: [f64; 2],
}

fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

impl Rect {
    /// The rectangle of a vehicle of `size` (length, width) at `c` heading `h` radians.
    pub fn new(c: Point, h: f64, size: [f64; 2]) -> Self {
        let (s, co) = h.sin_cos();
        Self {
            c,
            u: [co, s],
            half: [0.5 * size[0], 0.5 * size[1]],
        }
    }

    fn axes(&self) -> [[f64; 2]; 2] {
        [self.u, [-self.u[1], self.u[0]]]
    }

    /// Half the rectangle's extent along the unit direction `n`.
    fn reach(&self, n: [f64; 2]) -> f64 {
        let [a, b] = self.axes();
        self.half[0] * dot(a, n).abs() + self.half[1] * dot(b, n).abs()
    }

    fn corners(&self) -> [Point; 4] {
        let [a, b] = self.axes();
        let at = |i: f64, j: f64| {
            [
                self.c[0] + i * self.half[0] * a[0] + j * self.half[1] * b[0],
                self.c[1] + i * self.half[0] * a[1] + j * self.half[1] * b[1],
            ]
        };
        [at(1.0, 1.0), at(-1.0, 1.0), at(-1.0, -1.0), at(1.0, -1.0)]
    }
}

/// How long until `a` and `b`, moving at `va` and `vb`, touch: 0 when they touch now, ∞ when
/// they never would. Two convex shapes overlap exactly when no edge normal of either separates
/// them, so the times of contact are the intersection, over the four normals, of the times at
/// which the centres' distance along the normal is within the two half extents.
pub fn time_to_collision(a: &Rect, va: [f64; 2], b: &Rect, vb: [f64; 2]) -> f64 {
    let d = [b.c[0] - a.c[0], b.c[1] - a.c[1]];
    let w = [vb[0] - va[0], vb[1] - va[1]];
    let (mut lo, mut hi) = (0.0f64, f64::INFINITY);
    for n in a.axes().into_iter().chain(b.axes()) {
        let r = a.reach(n) + b.reach(n);
        let (p, q) = (dot(n, d), dot(n, w));
        if q == 0.0 {
            if p.abs() > r {
                return f64::INFINITY;
            }
            continue;
        }
        let (t1, t2) = ((-r - p) / q, (r - p) / q);
        lo = lo.max(t1.min(t2));
        hi = hi.min(t1.max(t2));
        if lo > hi {
            return f64::INFINITY;
        }
    }
    lo
}

fn point_segment(p: Point, a: Point, b: Point) -> f64 {
    let (e, f) = ([b[0] - a[0], b[1] - a[1]], [p[0] - a[0], p[1] - a[1]]);
    let ee = dot(e, e);
    let t = if ee > 0.0 {
        (dot(e, f) / ee).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (f[0] - t * e[0]).hypot(f[1] - t * e[1])
}

/// The distance between `a` and `b`, 0 when they touch. Between two convex polygons apart,
/// the nearest points include a corner of one of them.
pub fn gap(a: &Rect, b: &Rect) -> f64 {
    if time_to_collision(a, [0.0; 2], b, [0.0; 2]) == 0.0 {
        return 0.0;
    }
    let (ca, cb) = (a.corners(), b.corners());
    let mut best = f64::INFINITY;
    for (p, q) in [(&ca, &cb), (&cb, &ca)] {
        for &corner in p {
            for k in 0..4 {
                best = best.min(point_segment(corner, q[k], q[(k + 1) % 4]));
            }
        }
    }
    best
}

/// One scene's grid (see the module's comment); rows are time-major, `t * vehicles + j`.
#[derive(Clone, Copy, Debug)]
pub struct Scene<'a> {
    pub vehicles: usize,
    pub positions: &'a [Point],
    pub velocities: &'a [[f64; 2]],
    pub present: &'a [bool],
    /// Per vehicle, its length and width.
    pub sizes: &'a [[f64; 2]],
    pub dt: f64,
    pub min_speed: f64,
    /// Per row, the heading (radians) a vehicle slower than `min_speed` faces, NaN where not
    /// known; `None`: none known.
    pub headings: Option<&'a [f64]>,
}

/// The measures of the pair of vehicles `a < b`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pair {
    pub a: usize,
    pub b: usize,
    pub ttc: f64,
    pub gap: f64,
    pub pet: f64,
    pub collision: bool,
}

/// A scene's measures: each pair of vehicles that are there together at some time (in order of
/// `a`, then `b`), and each vehicle's hardest deceleration.
#[derive(Clone, Debug, PartialEq)]
pub struct Measures {
    pub pairs: Vec<Pair>,
    pub deceleration: Vec<f64>,
}

impl Scene<'_> {
    fn times(&self) -> usize {
        self.present.len() / self.vehicles.max(1)
    }

    fn validate(&self) -> Result<()> {
        let rows = self.present.len();
        if self.positions.len() != rows
            || self.velocities.len() != rows
            || self.sizes.len() != self.vehicles
            || (self.vehicles == 0 && rows != 0)
            || (self.vehicles > 0 && !rows.is_multiple_of(self.vehicles))
        {
            return Err(Error::Shape(format!(
                "a scene of {} vehicles needs a size per vehicle and positions, velocities and presence for each time and vehicle; got {} sizes and {}, {}, {} rows",
                self.vehicles,
                self.sizes.len(),
                self.positions.len(),
                self.velocities.len(),
                rows
            )));
        }
        if let Some(h) = self.headings {
            let infinite = h.iter().any(|x| x.is_infinite());
            if h.len() != rows || infinite {
                return Err(Error::InvalidInput(format!(
                    "headings need one finite value or NaN per row ({rows}), got {} values{}",
                    h.len(),
                    if infinite { ", some infinite" } else { "" }
                )));
            }
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(Error::InvalidInput(format!(
                "dt must be a positive number of seconds, got {}",
                self.dt
            )));
        }
        if !(self.min_speed.is_finite() && self.min_speed >= 0.0) {
            return Err(Error::InvalidInput(format!(
                "the heading speed must be a finite speed >= 0, got {}",
                self.min_speed
            )));
        }
        if let Some(s) = self
            .sizes
            .iter()
            .find(|s| !s.iter().all(|x| x.is_finite() && *x > 0.0))
        {
            return Err(Error::InvalidInput(format!(
                "vehicle sizes (length, width) must be positive, got {s:?}"
            )));
        }
        let bad = (0..rows).find(|&r| {
            self.present[r]
                && !(self.positions[r].iter())
                    .chain(&self.velocities[r])
                    .all(|x| x.is_finite())
        });
        if let Some(r) = bad {
            return Err(Error::InvalidInput(format!(
                "vehicle {} at time {} has a non-finite position or velocity",
                r % self.vehicles,
                r / self.vehicles
            )));
        }
        Ok(())
    }

    /// Vehicle `j`'s heading at every time (see the module's comment).
    fn headings(&self, j: usize) -> Vec<f64> {
        let l = self.vehicles;
        let own: Vec<Option<f64>> = (0..self.times())
            .map(|t| {
                let (r, v) = (t * l + j, self.velocities[t * l + j]);
                if !self.present[r] {
                    None
                } else if v[0].hypot(v[1]) >= self.min_speed.max(f64::MIN_POSITIVE) {
                    Some(v[1].atan2(v[0]))
                } else {
                    self.headings.map(|h| h[r]).filter(|h| h.is_finite())
                }
            })
            .collect();
        let first = own.iter().flatten().next().copied().unwrap_or(0.0);
        let mut last = first;
        own.iter()
            .map(|h| {
                if let Some(h) = h {
                    last = *h;
                }
                last
            })
            .collect()
    }

    /// The measures (checked: shapes, finite rows where present, positive sizes and `dt`).
    pub fn measures(&self) -> Result<Measures> {
        self.validate()?;
        let (l, times) = (self.vehicles, self.times());
        let heads: Vec<Vec<f64>> = (0..l).map(|j| self.headings(j)).collect();
        // each vehicle's rectangle at each time, built once (a pair's loop reads them l times)
        let rects: Vec<Rect> = (0..times * l)
            .map(|r| Rect::new(self.positions[r], heads[r % l][r / l], self.sizes[r % l]))
            .collect();
        let paths: Vec<Path> = (0..l).map(|j| Path::of(self, j)).collect();
        let mut pairs = Vec::new();
        for a in 0..l {
            for b in a + 1..l {
                let mut pair = Pair {
                    a,
                    b,
                    ttc: f64::INFINITY,
                    gap: f64::INFINITY,
                    pet: f64::INFINITY,
                    collision: false,
                };
                let mut together = false;
                for t in 0..times {
                    let (ra, rb) = (t * l + a, t * l + b);
                    if !(self.present[ra] && self.present[rb]) {
                        continue;
                    }
                    together = true;
                    let (x, y) = (&rects[ra], &rects[rb]);
                    let ttc = time_to_collision(x, self.velocities[ra], y, self.velocities[rb]);
                    pair.ttc = pair.ttc.min(ttc);
                    pair.collision |= ttc == 0.0;
                    pair.gap = pair.gap.min(gap(x, y));
                }
                if together {
                    pair.pet = paths[a].encroachment(&paths[b]);
                    pairs.push(pair);
                }
            }
        }
        let deceleration = (0..l)
            .map(|j| {
                (0..times.saturating_sub(1))
                    .filter(|&t| self.present[t * l + j] && self.present[(t + 1) * l + j])
                    .map(|t| {
                        let s = |r: usize| self.velocities[r][0].hypot(self.velocities[r][1]);
                        (s(t * l + j) - s((t + 1) * l + j)) / self.dt
                    })
                    .fold(0.0, f64::max)
            })
            .collect();
        Ok(Measures {
            pairs,
            deceleration,
        })
    }
}

/// A vehicle's centre path: its positions at the times it is there, with the time and the
/// distance driven so far at each, and its length.
struct Path {
    t: Vec<f64>,
    p: Vec<Point>,
    s: Vec<f64>,
    /// Whether the segment from point `i` to `i + 1` was driven (consecutive times).
    joined: Vec<bool>,
    length: f64,
}

impl Path {
    fn of(scene: &Scene<'_>, j: usize) -> Self {
        let l = scene.vehicles;
        let mut path = Path {
            t: Vec::new(),
            p: Vec::new(),
            s: Vec::new(),
            joined: Vec::new(),
            length: scene.sizes[j][0],
        };
        let mut last: Option<usize> = None;
        for t in 0..scene.times() {
            if !scene.present[t * l + j] {
                continue;
            }
            let p = scene.positions[t * l + j];
            let s = match path.p.last() {
                Some(q) => path.s[path.s.len() - 1] + (p[0] - q[0]).hypot(p[1] - q[1]),
                None => 0.0,
            };
            if !path.p.is_empty() {
                path.joined.push(last == Some(t - 1));
            }
            path.t.push(t as f64 * scene.dt);
            path.p.push(p);
            path.s.push(s);
            last = Some(t);
        }
        path
    }

    /// The first time the distance driven reaches `s` (linear between the times): the first
    /// time when it is there already, ∞ when it never gets there.
    fn time_at(&self, s: f64) -> f64 {
        if self.s.is_empty() {
            return f64::INFINITY;
        }
        if s <= self.s[0] {
            return self.t[0];
        }
        let i = self.s.partition_point(|&x| x < s);
        if i == self.s.len() {
            return f64::INFINITY;
        }
        let (s0, s1) = (self.s[i - 1], self.s[i]);
        self.t[i - 1] + (self.t[i] - self.t[i - 1]) * (s - s0) / (s1 - s0)
    }

    /// When the vehicle occupies the point at distance `s` along its path: from its front
    /// reaching it to its rear leaving it.
    fn occupies(&self, s: f64) -> (f64, f64) {
        (
            self.time_at(s - 0.5 * self.length),
            self.time_at(s + 0.5 * self.length),
        )
    }

    /// The least post-encroachment time over the crossings of the two paths (∞ without one).
    fn encroachment(&self, other: &Path) -> f64 {
        let mut best = f64::INFINITY;
        for i in 0..self.joined.len() {
            if !self.joined[i] {
                continue;
            }
            for k in 0..other.joined.len() {
                if !other.joined[k] {
                    continue;
                }
                let Some((u, w)) = crossing(self.p[i], self.p[i + 1], other.p[k], other.p[k + 1])
                else {
                    continue;
                };
                let sa = self.s[i] + u * (self.s[i + 1] - self.s[i]);
                let sb = other.s[k] + w * (other.s[k + 1] - other.s[k]);
                let (a, b) = (self.occupies(sa), other.occupies(sb));
                if a.0.is_infinite() || b.0.is_infinite() {
                    continue; // one of them never reaches it
                }
                // the time between one leaving and the other arriving; 0 when both are on it
                let pet = (b.0 - a.1).max(a.0 - b.1).max(0.0);
                best = best.min(pet);
            }
        }
        best
    }
}

/// Where segments `p0 p1` and `q0 q1` (both of positive length) cross: the fractions along each,
/// or `None` (parallel segments do not cross: collinear ones share no single point).
fn crossing(p0: Point, p1: Point, q0: Point, q1: Point) -> Option<(f64, f64)> {
    let r = [p1[0] - p0[0], p1[1] - p0[1]];
    let s = [q1[0] - q0[0], q1[1] - q0[1]];
    let den = r[0] * s[1] - r[1] * s[0];
    if den == 0.0 {
        return None;
    }
    let d = [q0[0] - p0[0], q0[1] - p0[1]];
    let u = (d[0] * s[1] - d[1] * s[0]) / den;
    let w = (d[0] * r[1] - d[1] * r[0]) / den;
    ((0.0..=1.0).contains(&u) && (0.0..=1.0).contains(&w)).then_some((u, w))
}

#[cfg(test)]
#[path = "tests/criticality.rs"]
mod tests;
