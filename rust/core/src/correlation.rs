//! A pattern's correlation function, exact or reduced-rank: the one type through which the
//! exact GP (`kernel`) and the HSGP basis (`hsgp`) are chosen. It sits above both, so that
//! neither imports the other.

use std::sync::Arc;

use crate::frame::{LengthScales, Point};
use crate::hsgp::Basis;
use crate::kernel::cross;

/// The correlation function of a pattern's GP: the squared exponential, or its reduced-rank
/// (HSGP) approximation `k̃` on a fixed basis, assembled densely for small patterns.
#[derive(Clone, Debug, Default)]
pub enum Correlation {
    #[default]
    SquaredExp,
    Reduced(Arc<Basis>),
}

impl Correlation {
    /// `scale * r(a, b)`, column-major `a.len() x b.len()` (single-threaded: callers run inside
    /// parallel loops).
    pub fn cross(&self, a: &[Point], b: &[Point], ls: LengthScales, scale: f64) -> Vec<f64> {
        self.cross_par(a, b, ls, scale, false)
    }

    /// [`Correlation::cross`], with the squared exponential's columns spread over rayon when
    /// `parallel` (a standalone GP, not inside the sampler's parallel loops); the entries are the
    /// same either way.
    pub fn cross_par(
        &self,
        a: &[Point],
        b: &[Point],
        ls: LengthScales,
        scale: f64,
        parallel: bool,
    ) -> Vec<f64> {
        match self {
            Self::SquaredExp => cross(a, b, ls, scale, parallel),
            Self::Reduced(basis) => basis.correlation(a, b, ls, scale),
        }
    }

    /// `scale * r(a, a) + noise * I`.
    pub fn gram(&self, a: &[Point], ls: LengthScales, scale: f64, noise: f64) -> Vec<f64> {
        self.gram_par(a, ls, scale, noise, false)
    }

    /// [`Correlation::gram`], parallel as [`Correlation::cross_par`].
    pub fn gram_par(
        &self,
        a: &[Point],
        ls: LengthScales,
        scale: f64,
        noise: f64,
        parallel: bool,
    ) -> Vec<f64> {
        let n = a.len();
        let mut k = self.cross_par(a, a, ls, scale, parallel);
        for i in 0..n {
            k[i * n + i] += noise;
        }
        k
    }

    /// Whether the correlation has no support at `p` (outside a reduced-rank basis's box).
    pub fn unsupported(&self, p: Point) -> bool {
        match self {
            Self::SquaredExp => false,
            Self::Reduced(basis) => !basis.contains(p),
        }
    }

    /// `r(p, p)` for each point.
    pub fn diag(&self, q: &[Point], ls: LengthScales) -> Vec<f64> {
        match self {
            Self::SquaredExp => vec![1.0; q.len()],
            Self::Reduced(basis) => q
                .iter()
                .map(|p| {
                    basis.correlation(std::slice::from_ref(p), std::slice::from_ref(p), ls, 1.0)[0]
                })
                .collect(),
        }
    }
}
