//! A pattern's correlation function, exact or reduced-rank: the one type through which the
//! exact GP (`kernel`) and the HSGP basis (`hsgp`) are chosen. It sits above both, so that
//! neither imports the other.

use std::sync::Arc;

use crate::basis::Basis;
use crate::frame::{Inputs, LengthScales, Point};
use crate::heading::HeadingKernel;
use crate::kernel::cross_headed;

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
    pub fn cross(&self, a: Inputs<'_>, b: Inputs<'_>, ls: LengthScales, scale: f64) -> Vec<f64> {
        self.cross_par(a, b, ls, scale, false)
    }

    /// [`Correlation::cross`], with the squared exponential's columns spread over rayon when
    /// `parallel` (a standalone GP, not inside the sampler's parallel loops); the entries are the
    /// same either way.
    pub fn cross_par(
        &self,
        a: Inputs<'_>,
        b: Inputs<'_>,
        ls: LengthScales,
        scale: f64,
        parallel: bool,
    ) -> Vec<f64> {
        match self {
            Self::SquaredExp => cross_headed(a, b, ls, scale, parallel),
            Self::Reduced(basis) => basis.correlation(a, b, ls, scale),
        }
    }

    /// `scale * r(a, a) + noise * I`.
    pub fn gram(&self, a: Inputs<'_>, ls: LengthScales, scale: f64, noise: f64) -> Vec<f64> {
        self.gram_par(a, ls, scale, noise, false)
    }

    /// [`Correlation::gram`], parallel as [`Correlation::cross_par`].
    pub fn gram_par(
        &self,
        a: Inputs<'_>,
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
    pub fn diag(&self, q: Inputs<'_>, ls: LengthScales) -> Vec<f64> {
        match self {
            Self::SquaredExp => {
                let k = HeadingKernel::new(ls.wh);
                (0..q.len())
                    .map(|i| k.eval(q.heading(i), q.heading(i)))
                    .collect()
            }
            Self::Reduced(basis) => (0..q.len())
                .map(|i| {
                    let h = [q.heading(i)];
                    let one = Inputs {
                        xy: std::slice::from_ref(&q.xy[i]),
                        h: &h,
                    };
                    basis.correlation(one, one, ls, 1.0)[0]
                })
                .collect(),
        }
    }
}
