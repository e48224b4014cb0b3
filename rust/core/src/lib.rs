//! dpgp-core: the numerical core of dpgp — a Dirichlet-process mixture of Gaussian-process
//! velocity fields (Guo, Kalidindi et al.). Pure Rust; the Python bindings live in `rust/py`.

pub mod error;
pub mod gp;
pub mod kernel;
pub mod linalg;
pub mod motion;
pub mod placement;
pub mod vexp;

pub use error::{Error, Result};
pub use gp::GpParams;
pub use kernel::{LengthScales, Point};
pub mod factor;
pub mod gibbs;
pub mod hsgp;
pub mod pattern;
pub mod pattern_model;
pub mod proposal;
pub mod rng;
pub mod simulate;
pub mod slice;
pub mod small;
pub mod special;

#[cfg(test)]
#[path = "tests/util.rs"]
mod test_util;
