//! A road's free speeds (long scenarios by signal stage): how fast the recorded vehicles drove
//! where they moved, by lane cell and heading, raising a field's speed to it.
//!
//! A pattern's field is the mean velocity of its frames' vehicles: where vehicles queue or start
//! from a stop line, and where a lane runs beside the opposite one, that mean is slow (on the SUMO
//! junction 8 m/s where recorded vehicles drove 12.4, 4–7 m/s in the junction box). Followed as a
//! driver's desired speed it made generated vehicles crawl. Once queues come from the stop lines
//! and the car-following rule, the desired speed is the free one; the field keeps the direction.

use crate::error::{Error, Result};
use crate::frame::Point;
use crate::simulate::{Field, StepInfo};

/// Heading sectors of a [`FreeSpeeds`] map: sector `i` is centred on the angle `i · 2π / 8`.
pub const SECTORS: usize = 8;

/// Free speeds on a grid of square cells of side `cell` from `origin` (`nx` by `ny` cells), per
/// cell and heading sector (row-major `(ix, iy, sector)`); NaN where none was recorded.
#[derive(Clone, Debug, PartialEq)]
pub struct FreeSpeeds {
    origin: Point,
    cell: f64,
    nx: usize,
    ny: usize,
    speeds: Vec<f64>,
}

impl FreeSpeeds {
    pub fn new(origin: Point, cell: f64, nx: usize, ny: usize, speeds: Vec<f64>) -> Result<Self> {
        if !(origin.iter().all(|v| v.is_finite()) && cell.is_finite() && cell > 0.0) {
            return Err(Error::InvalidInput(format!(
                "a free-speed map needs a finite origin and a positive cell, got {origin:?} and {cell}"
            )));
        }
        if nx.checked_mul(ny).and_then(|n| n.checked_mul(SECTORS)) != Some(speeds.len()) {
            return Err(Error::Shape(format!(
                "{} free speeds for {nx} x {ny} cells and {SECTORS} headings",
                speeds.len()
            )));
        }
        if speeds
            .iter()
            .any(|&s| !(s.is_nan() || (s.is_finite() && s >= 0.0)))
        {
            return Err(Error::InvalidInput(
                "free speeds must be non-negative and finite (NaN: not recorded)".into(),
            ));
        }
        Ok(Self {
            origin,
            cell,
            nx,
            ny,
            speeds,
        })
    }

    /// The free speed at `p` heading along `dir` (any length but zero), if one was recorded there.
    pub fn at(&self, p: Point, dir: [f64; 2]) -> Option<f64> {
        let ix = ((p[0] - self.origin[0]) / self.cell).floor();
        let iy = ((p[1] - self.origin[1]) / self.cell).floor();
        if !(ix >= 0.0 && iy >= 0.0 && ix < self.nx as f64 && iy < self.ny as f64) {
            return None;
        }
        let turn = std::f64::consts::TAU / SECTORS as f64;
        let sector = (dir[1].atan2(dir[0]) / turn)
            .round()
            .rem_euclid(SECTORS as f64) as usize;
        let s = self.speeds[((ix as usize) * self.ny + iy as usize) * SECTORS + sector];
        (!s.is_nan()).then_some(s)
    }
}

/// A field whose mean velocity is raised, where it is slower, to the free speed recorded there in
/// its direction (kept where none was recorded, or the field has no direction); what it says of
/// draws and of its support is the inner field's.
pub struct AtFreeSpeed<'a> {
    pub inner: Box<dyn Field + 'a>,
    pub speeds: &'a FreeSpeeds,
}

impl Field for AtFreeSpeed<'_> {
    fn velocity(&mut self, q: &[Point]) -> Result<Vec<[f64; 2]>> {
        let mut v = self.inner.velocity(q)?;
        for (m, p) in v.iter_mut().zip(q) {
            let speed = m[0].hypot(m[1]);
            if speed > 0.0
                && let Some(free) = self.speeds.at(*p, *m).filter(|&f| f > speed)
            {
                *m = [m[0] * free / speed, m[1] * free / speed];
            }
        }
        Ok(v)
    }

    fn step_start(&mut self, step: usize, q: &[Point]) -> Result<StepInfo> {
        self.inner.step_start(step, q)
    }

    fn deferred_low_data(&mut self) -> Result<Vec<bool>> {
        self.inner.deferred_low_data()
    }

    fn support(&mut self, q: &[Point]) -> Result<Option<Vec<f64>>> {
        self.inner.support(q)
    }

    fn start_headings(&self) -> Option<(&[f64], f64)> {
        self.inner.start_headings()
    }

    fn set_headings(&mut self, h: &[f64]) {
        self.inner.set_headings(h)
    }
}

#[cfg(test)]
#[path = "tests/free_speed.rs"]
mod tests;
