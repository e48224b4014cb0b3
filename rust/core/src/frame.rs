//! The plain data types every layer shares: a position, a frame's vehicles, the length scales.
//! The bottom of the core: it imports nothing of the crate but `error`.

use crate::error::{Error, Result};

/// A position in the plane.
pub type Point = [f64; 2];

/// A frame's vehicles: positions and velocities, row for row, and each vehicle's previous
/// heading (`NaN` where it has none) when the fit's fields depend on heading, else empty.
#[derive(Clone, Copy, Debug)]
pub struct FrameRef<'a> {
    pub xy: &'a [Point],
    pub v: &'a [[f64; 2]],
    pub h: &'a [f64],
}

impl<'a> FrameRef<'a> {
    /// A frame without headings.
    pub fn new(xy: &'a [Point], v: &'a [[f64; 2]]) -> Self {
        Self { xy, v, h: &[] }
    }

    pub fn inputs(&self) -> Inputs<'a> {
        Inputs {
            xy: self.xy,
            h: self.h,
        }
    }
}

/// The inputs of a field at some points: positions and previous headings (`NaN`: unknown; an
/// empty `h`: every heading unknown, which a field over position alone never reads).
#[derive(Clone, Copy, Debug)]
pub struct Inputs<'a> {
    pub xy: &'a [Point],
    pub h: &'a [f64],
}

impl<'a> Inputs<'a> {
    /// Positions whose headings are unknown.
    pub fn positions(xy: &'a [Point]) -> Self {
        Self { xy, h: &[] }
    }

    /// The heading of point `i` (`NaN` when unknown).
    #[inline]
    pub fn heading(&self, i: usize) -> f64 {
        if self.h.is_empty() {
            f64::NAN
        } else {
            self.h[i]
        }
    }

    pub fn len(&self) -> usize {
        self.xy.len()
    }

    pub fn is_empty(&self) -> bool {
        self.xy.is_empty()
    }

    /// The inputs in consecutive blocks of `size` points.
    pub fn chunks(self, size: usize) -> impl Iterator<Item = Inputs<'a>> {
        let n = self.len();
        (0..n).step_by(size).map(move |a| {
            let b = (a + size).min(n);
            Inputs {
                xy: &self.xy[a..b],
                h: if self.h.is_empty() {
                    &[]
                } else {
                    &self.h[a..b]
                },
            }
        })
    }
}

/// The headings of `frames` one after another, as [`extend_headings`] keeps them: empty when
/// no frame has any.
pub fn concat_headings<'a>(frames: impl IntoIterator<Item = FrameRef<'a>>) -> Vec<f64> {
    let (mut h, mut n) = (Vec::new(), 0);
    for f in frames {
        extend_headings(&mut h, n, f.h, f.xy.len());
        n += f.xy.len();
    }
    h
}

/// Append the headings of a frame of `l` points to `h`, the headings of the `n` points before it:
/// `h` stays empty while no frame has headings, and is filled with `NaN` (unknown) for frames
/// without them once one has.
pub fn extend_headings(h: &mut Vec<f64>, n: usize, frame_h: &[f64], l: usize) {
    if frame_h.is_empty() && h.is_empty() {
        return;
    }
    if h.is_empty() {
        h.resize(n, f64::NAN);
    }
    if frame_h.is_empty() {
        h.resize(n + l, f64::NAN);
    } else {
        h.extend_from_slice(frame_h);
    }
}

/// The per-pattern length scales `(w_x, w_y)` in position and `w_h` in the previous heading
/// (radians; `∞`, the default, is the paper's field over position alone: see `heading`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LengthScales {
    pub wx: f64,
    pub wy: f64,
    pub wh: f64,
}

impl LengthScales {
    /// Position length scales of a field that does not depend on heading.
    pub fn new(wx: f64, wy: f64) -> Result<Self> {
        for (name, w) in [("w_x", wx), ("w_y", wy)] {
            if !(w.is_finite() && w > 0.0) {
                return Err(Error::InvalidInput(format!(
                    "length scale {name} must be a positive finite number, got {w}"
                )));
            }
        }
        Ok(Self {
            wx,
            wy,
            wh: f64::INFINITY,
        })
    }

    /// The same position length scales with heading length scale `wh` (positive; `∞` for none).
    pub fn with_heading(self, wh: f64) -> Result<Self> {
        if !(wh > 0.0) {
            return Err(Error::InvalidInput(format!(
                "the heading length scale w_h must be positive (radians; inf for a field over \
                 position only), got {wh}"
            )));
        }
        Ok(Self { wh, ..self })
    }

    /// Length scale `i` of `(w_x, w_y, w_h)`: the coordinates the samplers update one by one.
    pub fn coord(self, i: usize) -> f64 {
        [self.wx, self.wy, self.wh][i]
    }

    /// The same length scales with coordinate `i` of `(w_x, w_y, w_h)` set to `w`.
    pub fn with_coord(self, i: usize, w: f64) -> Self {
        match i {
            0 => Self { wx: w, ..self },
            1 => Self { wy: w, ..self },
            _ => Self { wh: w, ..self },
        }
    }

    /// `(1 / (2 wx^2), 1 / (2 wy^2))`: the factors the squared distances are scaled by.
    #[inline]
    pub(crate) fn inv2(self) -> (f64, f64) {
        (0.5 / (self.wx * self.wx), 0.5 / (self.wy * self.wy))
    }
}

/// For every vehicle of a frame of two or more (frames given by `offsets` into `xy`, in row
/// order), the squared distance to its nearest neighbour in the same frame: what the
/// length-scale prior's data spacing is the median of. In parallel over frames; the same numbers
/// whatever the thread count.
pub fn nearest_neighbour_sq(xy: &[Point], offsets: &[usize]) -> Vec<f64> {
    use rayon::prelude::*;
    let frames: Vec<&[Point]> = offsets
        .windows(2)
        .map(|w| &xy[w[0]..w[1]])
        .filter(|f| f.len() >= 2)
        .collect();
    frames
        .par_iter()
        .flat_map_iter(|f| {
            f.iter().enumerate().map(move |(i, p)| {
                f.iter()
                    .enumerate()
                    .filter(|&(j, _)| j != i)
                    .map(|(_, q)| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2))
                    .fold(f64::INFINITY, f64::min)
            })
        })
        .collect()
}
