//! dpgp-core: the numerical core of dpgp — a Dirichlet-process mixture of Gaussian-process
//! velocity fields (Guo, Kalidindi et al.). Pure Rust; the Python bindings live in `rust/py`.

// Numeric code indexes parallel arrays by one loop variable (clippy::needless_range_loop), and
// `!(x > 0.0)` is how a check also refuses NaN (clippy::neg_cmp_op_on_partial_ord); tuples of
// result arrays are clearer than one-use type aliases (clippy::type_complexity).
#![allow(
    clippy::needless_range_loop,
    clippy::neg_cmp_op_on_partial_ord,
    clippy::type_complexity
)]

// Module layers, bottom to top; a module uses only modules of a lower layer (checked by
// tests/test_layout_rust.py, which fails on any circle):
//   1. error, special, vexp, rng, slice        (no crate imports but error)
//   2. frame, heading, turning                 (Point, LengthScales, FrameRef; the periodic
//                                              kernel over the previous heading; the turning
//                                              limit of pure-field rollouts)
//   3. linalg, small, factor, kernel           (dense algebra, the squared-exponential kernel)
//      criticality                             (how near a scene's vehicles come to colliding)
//   4. gp                                      (a pattern's GP parameters)
//   5. basis, hsgp_sums, hsgp                  (the reduced-rank basis, its sums, its patterns)
//   6. correlation                             (exact or reduced: the choice of the two)
//   7. pattern, pattern_model, proposal        (a pattern's sufficient state; the model types)
//   8. gibbs (+ hyper, noise, split_merge, sticky), subcluster (+ its pass and moves), simulate
//                                              (the samplers; rollouts)
//   9. placement, motion, free_speed           (scene generation over simulate)
pub mod basis;
pub mod correlation;
pub mod criticality;
pub mod error;
pub mod field_blocks;
pub mod frame;
pub mod free_speed;
pub mod gp;
pub mod heading;
pub mod kernel;
pub mod linalg;
pub(crate) mod low_data;
pub mod motion;
pub mod placement;
pub mod vexp;

pub use error::{Error, Result};
pub use frame::{FrameRef, Inputs, LengthScales, Point};
pub use gp::GpParams;
pub mod factor;
pub mod gibbs;
pub mod hsgp;
pub mod hsgp_sums;
pub mod pattern;
pub mod pattern_model;
pub mod proposal;
pub mod rng;
pub mod simulate;
pub mod slice;
pub mod small;
pub mod special;
pub mod subcluster;
pub mod turning;

#[cfg(test)]
#[path = "tests/util.rs"]
mod test_util;
