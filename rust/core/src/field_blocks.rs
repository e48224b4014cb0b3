//! Many reduced-rank fields at eight points at once, fused: the sine values of the block's points,
//! then every field `s(x)ᵀ A t(y)` from them, with no feature vector or product matrix written.
//!
//! **Why a kernel of its own.** The assignment pass evaluates every pattern's two fields at every
//! point of every frame: `2 K M` multiply–adds a point, the sweep's whole cost at scale. As a
//! matrix product (`T [A_1ᵀ … A_Fᵀ]`, inner dimension the longer axis's count) it ran at a third of
//! the machine's peak: the inner dimension is short (10–30), and the product's output is written
//! and read back to reduce it against the other axis. Here a block of eight points is a set of
//! 8-lane vectors held in registers, the inner sums for four outer functions run side by side
//! (eight independent multiply–add chains), and the reduction against the outer axis is one more
//! multiply–add per outer function.
//!
//! **Same bits everywhere.** The body is one generic function. On x86-64 with AVX2 and FMA it is
//! compiled for those features and chosen at run time; elsewhere it runs as plain code.
//! `f64::mul_add` is a correctly rounded fused multiply–add on every target, and the order of
//! every sum is fixed, so both paths give the same values, whatever the thread count.

use std::f64::consts::PI;

use crate::basis::{Basis, sin_cos_0_pi};
use crate::frame::Point;

/// Points per block (one AVX-512 or two AVX2 registers of doubles).
pub const LANES: usize = 8;
type V = [f64; LANES];
/// Outer functions whose inner sums run side by side.
const WIDE: usize = 4;

/// Fields over one basis, with their coefficients arranged for the kernel.
#[derive(Clone, Debug)]
pub struct FieldBlocks {
    /// Per axis: the box's centre `c` and half-width `L`, and the functions' scale `1 / √L`.
    center: [f64; 2],
    half: [f64; 2],
    norm: [f64; 2],
    /// Whether the inner sums run over the y axis's functions.
    inner_y: bool,
    inner: usize,
    /// The outer axis's function count, padded to a multiple of [`WIDE`] (with zero functions).
    outer: usize,
    /// The outer axis's function count.
    n_outer: usize,
    /// Field `f`'s coefficients at `f · inner · outer`, in groups of WIDE outer functions: for
    /// each group, for each inner function, the group's WIDE coefficients (zeros for padding).
    w: Vec<f64>,
}

impl FieldBlocks {
    /// The fields with basis weights `fields[f]` (feature order, `j + m_x k` for `φ_j(x) φ_k(y)`).
    pub fn new<'a>(basis: &Basis, fields: impl IntoIterator<Item = &'a [f64]>) -> Self {
        let [mx, my] = basis.counts();
        // A field costs `(inner + 1) · outer` multiply–adds with `outer` padded to a multiple of
        // WIDE by zero rows: take the cheaper orientation.
        let cost = |inner: usize, outer: usize| (inner + 1) * outer.next_multiple_of(WIDE);
        let inner_y = cost(my, mx) <= cost(mx, my);
        let (inner, outer) = if inner_y { (my, mx) } else { (mx, my) };
        let padded = outer.next_multiple_of(WIDE);
        // Coefficient of inner function i and outer function o.
        let coef = |a: &[f64], i: usize, o: usize| match (o < outer, inner_y) {
            (false, _) => 0.0,
            (true, true) => a[o + mx * i],
            (true, false) => a[i + mx * o],
        };
        let mut w = Vec::new();
        for a in fields {
            debug_assert_eq!(a.len(), mx * my);
            for g in (0..padded).step_by(WIDE) {
                for i in 0..inner {
                    w.extend((g..g + WIDE).map(|o| coef(a, i, o)));
                }
            }
        }
        let (c, h) = (basis.center(), basis.half_widths());
        Self {
            center: c,
            half: h,
            norm: [h[0].sqrt().recip(), h[1].sqrt().recip()],
            inner_y,
            inner,
            outer: padded,
            n_outer: outer,
            w,
        }
    }

    /// The number of fields.
    pub fn len(&self) -> usize {
        self.w.len() / (self.inner * self.outer)
    }

    pub fn is_empty(&self) -> bool {
        self.w.is_empty()
    }

    /// For each block of up to eight consecutive points of `xy`, call `each(first, values)` with
    /// the block's first point and `values[f][l]`, field `f` at the block's point `l` (lanes past
    /// the end of `xy` hold the field at the box's centre: ignore them).
    pub fn for_blocks(&self, xy: &[Point], each: &mut dyn FnMut(usize, &[V])) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the features the function is compiled for were just detected.
            unsafe { self.blocks_avx2(xy, each) };
            return;
        }
        self.blocks_plain(xy, each);
    }

    /// [`Self::for_blocks`] without SIMD intrinsics (the same values).
    fn blocks_plain(&self, xy: &[Point], each: &mut dyn FnMut(usize, &[V])) {
        self.blocks(xy, each, |a, vin, vout| field(a, vin, vout, group));
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn blocks_avx2(&self, xy: &[Point], each: &mut dyn FnMut(usize, &[V])) {
        // The closure inherits this function's features, so the calls need no `unsafe`.
        self.blocks(xy, each, |a, vin, vout| {
            field(a, vin, vout, |acc, a, vin, out| {
                avx2::group(acc, a, vin, out)
            })
        });
    }

    #[inline(always)]
    fn blocks(
        &self,
        xy: &[Point],
        each: &mut dyn FnMut(usize, &[V]),
        field: impl Fn(&[f64], &[V], &[V]) -> V,
    ) {
        let (n_in, n_out) = (self.inner, self.outer);
        let mut vin = vec![[0.0; LANES]; n_in];
        let mut vout = vec![[0.0; LANES]; n_out];
        let mut vals = vec![[0.0; LANES]; self.len()];
        let (ax_in, ax_out) = if self.inner_y { (1, 0) } else { (0, 1) };
        for b0 in (0..xy.len()).step_by(LANES) {
            let b1 = (b0 + LANES).min(xy.len());
            let mut u = [[0.0; LANES]; 2];
            for d in 0..2 {
                for l in 0..LANES {
                    u[d][l] = if b0 + l < b1 {
                        xy[b0 + l][d]
                    } else {
                        self.center[d]
                    };
                }
            }
            self.sines(ax_in, &u[ax_in], &mut vin);
            self.sines(ax_out, &u[ax_out], &mut vout[..self.n_outer]);
            // Each field is `Σ_o out_o · (Σ_i in_i a[o, i])`, WIDE outer functions at a time.
            for (val, a) in vals.iter_mut().zip(self.w.chunks_exact(n_in * n_out)) {
                *val = field(a, &vin, &vout);
            }
            each(b0, &vals);
        }
    }

    /// `φ_j(u)` along axis `d` for the block's coordinates, `j < out.len()`: the Chebyshev
    /// recurrence from `sin θ` and `cos θ`, zero outside the box (as `AxisValues`).
    #[inline(always)]
    fn sines(&self, d: usize, u: &V, out: &mut [V]) {
        let mut c1 = [0.0; LANES];
        let mut cur = [0.0; LANES];
        let w = 2.0 * self.half[d];
        for l in 0..LANES {
            let t = u[l] - self.center[d] + self.half[d];
            if (0.0..=w).contains(&t) {
                let (s, c) = sin_cos_0_pi(PI * t / w);
                c1[l] = c;
                cur[l] = s;
            }
        }
        let mut prev = [0.0; LANES];
        let scale = self.norm[d];
        for o in out.iter_mut() {
            for l in 0..LANES {
                o[l] = scale * cur[l];
                let next = 2.0 * c1[l] * cur[l] - prev[l];
                prev[l] = cur[l];
                cur[l] = next;
            }
        }
    }
}

/// One field at the block's points, `Σ_o out_o · (Σ_i in_i a[o, i])`: WIDE outer functions at a
/// time by `group`, in order.
#[inline(always)]
fn field(a: &[f64], vin: &[V], vout: &[V], group: impl Fn(&mut V, &[f64], &[V], &[V; WIDE])) -> V {
    let mut acc = [0.0; LANES];
    for (a, out) in a
        .chunks_exact(WIDE * vin.len())
        .zip(vout.chunks_exact(WIDE))
    {
        group(&mut acc, a, vin, out.try_into().expect("chunks of WIDE"));
    }
    acc
}

/// Add to `acc` the terms of WIDE outer functions with coefficients `a` (for each inner function,
/// the WIDE functions' coefficients) and values `vout`: their inner sums side by side, then each
/// times its outer value, in order.
#[inline(always)]
fn group(acc: &mut V, a: &[f64], vin: &[V], vout: &[V; WIDE]) {
    let mut s = [[0.0; LANES]; WIDE];
    for (x, c) in vin.iter().zip(a.chunks_exact(WIDE)) {
        for q in 0..WIDE {
            for l in 0..LANES {
                s[q][l] = x[l].mul_add(c[q], s[q][l]);
            }
        }
    }
    for q in 0..WIDE {
        for l in 0..LANES {
            acc[l] = s[q][l].mul_add(vout[q][l], acc[l]);
        }
    }
}

/// [`group`] with AVX2 and FMA intrinsics: eight accumulators (four functions, two registers of
/// four lanes each), the same operations in the same order.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::{LANES, V, WIDE};

    #[target_feature(enable = "avx2,fma")]
    pub(super) fn group(acc: &mut V, a: &[f64], vin: &[V], vout: &[V; WIDE]) {
        const { assert!(LANES == 8) };
        // SAFETY: every load and store below is of a `[f64; 8]` half (4 doubles); unaligned
        // loads and stores are used throughout.
        unsafe {
            let mut s = [[_mm256_setzero_pd(); 2]; WIDE];
            for (x, c) in vin.iter().zip(a.chunks_exact(WIDE)) {
                let c: &[f64; WIDE] = c.try_into().expect("chunks of WIDE");
                let xl = _mm256_loadu_pd(x.as_ptr());
                let xh = _mm256_loadu_pd(x.as_ptr().add(4));
                for q in 0..WIDE {
                    let c = _mm256_set1_pd(c[q]);
                    s[q][0] = _mm256_fmadd_pd(xl, c, s[q][0]);
                    s[q][1] = _mm256_fmadd_pd(xh, c, s[q][1]);
                }
            }
            let mut al = _mm256_loadu_pd(acc.as_ptr());
            let mut ah = _mm256_loadu_pd(acc.as_ptr().add(4));
            for q in 0..WIDE {
                al = _mm256_fmadd_pd(s[q][0], _mm256_loadu_pd(vout[q].as_ptr()), al);
                ah = _mm256_fmadd_pd(s[q][1], _mm256_loadu_pd(vout[q].as_ptr().add(4)), ah);
            }
            _mm256_storeu_pd(acc.as_mut_ptr(), al);
            _mm256_storeu_pd(acc.as_mut_ptr().add(4), ah);
        }
    }
}

#[cfg(test)]
#[path = "tests/field_blocks.rs"]
mod tests;
