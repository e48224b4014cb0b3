//! The plain data types every layer shares: a position, a frame's vehicles, the length scales.
//! The bottom of the core: it imports nothing of the crate but `error`.

use crate::error::{Error, Result};

/// A position in the plane.
pub type Point = [f64; 2];

/// A frame's vehicles: positions and velocities, row for row.
#[derive(Clone, Copy, Debug)]
pub struct FrameRef<'a> {
    pub xy: &'a [Point],
    pub v: &'a [[f64; 2]],
}

/// The per-pattern length scales `(w_x, w_y)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LengthScales {
    pub wx: f64,
    pub wy: f64,
}

impl LengthScales {
    pub fn new(wx: f64, wy: f64) -> Result<Self> {
        for (name, w) in [("w_x", wx), ("w_y", wy)] {
            if !(w.is_finite() && w > 0.0) {
                return Err(Error::InvalidInput(format!(
                    "length scale {name} must be a positive finite number, got {w}"
                )));
            }
        }
        Ok(Self { wx, wy })
    }

    /// `(1 / (2 wx^2), 1 / (2 wy^2))`: the factors the squared distances are scaled by.
    #[inline]
    pub(crate) fn inv2(self) -> (f64, f64) {
        (0.5 / (self.wx * self.wx), 0.5 / (self.wy * self.wy))
    }
}
