//! Assembly of the anisotropic squared-exponential kernel
//! `k(p, q) = s * exp(-(px-qx)^2 / (2 wx^2) - (py-qy)^2 / (2 wy^2))`, and of its product with
//! the periodic kernel over the vehicles' previous headings (`heading`).
//!
//! Matrices are column-major `Vec<f64>` buffers so that faer views them without copying and the
//! sampler can grow them in place. Columns are filled as arguments first, then exponentiated in
//! one vectorised pass (`vexp`).

use rayon::prelude::*;

pub use crate::frame::{Inputs, LengthScales, Point};
use crate::heading;
use crate::vexp::exp_nonpos;

/// Below this many kernel entries, threads cost more than they save.
const PAR_MIN_ENTRIES: usize = 1 << 17;

/// Fill one column: `col[i] = scale * r(a[i], q)`.
#[inline(always)]
fn fill_column_generic(a: &[Point], q: Point, ix: f64, iy: f64, scale: f64, col: &mut [f64]) {
    for (c, p) in col.iter_mut().zip(a) {
        let dx = p[0] - q[0];
        let dy = p[1] - q[1];
        *c = scale * exp_nonpos(-(dx * dx * ix + dy * dy * iy));
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn fill_column_avx2(a: &[Point], q: Point, ix: f64, iy: f64, scale: f64, col: &mut [f64]) {
    fill_column_generic(a, q, ix, iy, scale, col)
}

/// Fill one column: `col[i] = scale * r(a[i], q)`, vectorised where the CPU allows.
#[inline]
fn fill_column(a: &[Point], q: Point, ls: LengthScales, scale: f64, col: &mut [f64]) {
    let (ix, iy) = ls.inv2();
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the required CPU features were detected at run time.
            unsafe { fill_column_avx2(a, q, ix, iy, scale, col) };
            return;
        }
    }
    fill_column_generic(a, q, ix, iy, scale, col)
}

/// `scale * R(a, b)` as a column-major `a.len() x b.len()` buffer.
///
/// With `parallel`, large matrices are split over rayon in blocks of columns; every entry is
/// computed the same way either way, so the result does not depend on the thread count.
pub fn cross(a: &[Point], b: &[Point], ls: LengthScales, scale: f64, parallel: bool) -> Vec<f64> {
    let n = a.len();
    let mut out = vec![0.0; n * b.len()];
    if n == 0 {
        return out;
    }
    if parallel && n * b.len() >= PAR_MIN_ENTRIES {
        let cols_per_block = (PAR_MIN_ENTRIES / 8 / n).max(1);
        out.par_chunks_mut(n * cols_per_block)
            .zip(b.par_chunks(cols_per_block))
            .for_each(|(block, qs)| {
                for (col, &q) in block.chunks_mut(n).zip(qs) {
                    fill_column(a, q, ls, scale, col);
                }
            });
    } else {
        for (col, &q) in out.chunks_mut(n).zip(b) {
            fill_column(a, q, ls, scale, col);
        }
    }
    out
}

/// `scale * R(a, b)` for the field over position and previous heading (`heading`): the squared
/// exponential times `k_h(h_a, h_b)` (an unknown heading: the field averaged over heading). With
/// `ls.wh = ∞` the headings are not read and this is [`cross`], bit for bit.
pub fn cross_headed(
    a: Inputs<'_>,
    b: Inputs<'_>,
    ls: LengthScales,
    scale: f64,
    parallel: bool,
) -> Vec<f64> {
    let mut out = cross(a.xy, b.xy, ls, scale, parallel);
    if !heading::is_headed(ls.wh) || a.is_empty() {
        return out;
    }
    let k = heading::HeadingKernel::new(ls.wh);
    let ha: Vec<f64> = (0..a.len()).map(|i| a.heading(i)).collect();
    let apply = |col: &mut [f64], h: f64| {
        for (c, &g) in col.iter_mut().zip(&ha) {
            *c *= k.eval(g, h);
        }
    };
    let n = a.len();
    if parallel && n * b.len() >= PAR_MIN_ENTRIES {
        out.par_chunks_mut(n)
            .enumerate()
            .for_each(|(j, col)| apply(col, b.heading(j)));
    } else {
        for (j, col) in out.chunks_mut(n).enumerate() {
            apply(col, b.heading(j));
        }
    }
    out
}

/// `scale * R(a, a) + noise * I` as a column-major `n x n` buffer (both triangles filled).
pub fn gram(a: &[Point], ls: LengthScales, scale: f64, noise: f64, parallel: bool) -> Vec<f64> {
    let n = a.len();
    let mut k = cross(a, a, ls, scale, parallel);
    for i in 0..n {
        k[i * n + i] += noise;
    }
    k
}

#[cfg(test)]
#[path = "tests/kernel.rs"]
mod tests;
