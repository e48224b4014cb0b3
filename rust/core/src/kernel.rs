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
    columns(a.len(), b.len(), parallel, |j, col| {
        fill_column(a, b[j], ls, scale, col)
    })
}

/// An `n x m` column-major buffer whose column `j` is `fill(j, column)`: over rayon in blocks of
/// columns when `parallel` and large, else in order; each column is filled the same way either
/// way, so the result does not depend on the thread count.
fn columns(
    n: usize,
    m: usize,
    parallel: bool,
    fill: impl Fn(usize, &mut [f64]) + Sync,
) -> Vec<f64> {
    let mut out = vec![0.0; n * m];
    if n == 0 {
        return out;
    }
    if parallel && n * m >= PAR_MIN_ENTRIES {
        let cols_per_block = (PAR_MIN_ENTRIES / 8 / n).max(1);
        out.par_chunks_mut(n * cols_per_block)
            .enumerate()
            .for_each(|(blk, block)| {
                for (c, col) in block.chunks_mut(n).enumerate() {
                    fill(blk * cols_per_block + c, col);
                }
            });
    } else {
        for (j, col) in out.chunks_mut(n).enumerate() {
            fill(j, col);
        }
    }
    out
}

/// Per point, its heading as `(cos h, sin h, 1)`, or `(0, 0, 0)` when it is unknown.
fn heading_terms(x: Inputs<'_>) -> Vec<[f64; 3]> {
    (0..x.len())
        .map(|i| {
            let h = x.heading(i);
            if h.is_nan() {
                [0.0; 3]
            } else {
                let (s, c) = h.sin_cos();
                [c, s, 1.0]
            }
        })
        .collect()
}

/// What a column of the headed kernel needs besides the points: `(ix, iy)` of the position part,
/// the heading kernel's concentration `z = 1 / w_h²` and `ln q_0²` (either heading unknown).
#[derive(Clone, Copy)]
struct Headed {
    ix: f64,
    iy: f64,
    z: f64,
    log_q0: f64,
}

/// One column of the headed kernel in a single exponential: `exp(−r² + z (cos(h − h') − 1))` with
/// `cos(h − h') = cos h cos h' + sin h sin h'`, or `exp(−r² + ln q_0²)` when a heading is unknown
/// (the product of the two factors, without a trigonometric call per entry).
#[inline(always)]
fn fill_headed_generic(
    a: &[Point],
    ah: &[[f64; 3]],
    q: Point,
    qh: [f64; 3],
    k: Headed,
    scale: f64,
    col: &mut [f64],
) {
    for ((c, p), g) in col.iter_mut().zip(a).zip(ah) {
        let dx = p[0] - q[0];
        let dy = p[1] - q[1];
        let both = g[2] * qh[2];
        let turn = (k.z * (g[0] * qh[0] + g[1] * qh[1] - 1.0)).min(0.0);
        let arg = -(dx * dx * k.ix + dy * dy * k.iy) + both * turn + (1.0 - both) * k.log_q0;
        *c = scale * exp_nonpos(arg);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn fill_headed_avx2(
    a: &[Point],
    ah: &[[f64; 3]],
    q: Point,
    qh: [f64; 3],
    k: Headed,
    scale: f64,
    col: &mut [f64],
) {
    fill_headed_generic(a, ah, q, qh, k, scale, col)
}

#[inline]
fn fill_headed(
    a: &[Point],
    ah: &[[f64; 3]],
    q: Point,
    qh: [f64; 3],
    k: Headed,
    scale: f64,
    col: &mut [f64],
) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the required CPU features were detected at run time.
            unsafe { fill_headed_avx2(a, ah, q, qh, k, scale, col) };
            return;
        }
    }
    fill_headed_generic(a, ah, q, qh, k, scale, col)
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
    if !heading::is_headed(ls.wh) || a.is_empty() {
        return cross(a.xy, b.xy, ls, scale, parallel);
    }
    let (ix, iy) = ls.inv2();
    let z = 1.0 / (ls.wh * ls.wh);
    let k = Headed {
        ix,
        iy,
        z,
        log_q0: heading::bessel_q0(z).ln(),
    };
    let (ah, bh) = (heading_terms(a), heading_terms(b));
    columns(a.len(), b.len(), parallel, |j, col| {
        fill_headed(a.xy, &ah, b.xy[j], bh[j], k, scale, col)
    })
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
