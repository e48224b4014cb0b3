//! What a set of frames contributes to a pattern under the HSGP basis: sums over its points that
//! do not depend on the length scales or the noise, the marginal likelihood they give under any
//! hyperparameters, and the Gaussian posterior of the pattern's basis weights.
//!
//! **The Gram matrix in O(M) per point.** `G = Σ_p φ(p) φ(p)ᵀ` has `M²` entries, but with
//! `φ_jk(x, y) = sin(α θ_x) sin(γ θ_y) / √(L_x L_y)` (`α = j + 1`, `γ = k + 1`) and
//! `sin a sin b = ½ (cos(a − b) − cos(a + b))`, every entry is a signed sum of four entries of
//! the moment matrix `H[a, b] = Σ_p cos(a θ_x) cos(b θ_y)` (`a ≤ 2 m_x`, `b ≤ 2 m_y`):
//!
//! `G[(j,k), (j',k')] = (H[|α−β|, |γ−δ|] − H[|α−β|, γ+δ] − H[α+β, |γ−δ|] + H[α+β, γ+δ]) / (4 L_x L_y)`.
//!
//! `H` has about `4M` entries and a point adds its outer product `c_x c_yᵀ`; so the sums of any set
//! of frames cost `O(M)` per point (matrix products over the points), and `G` is assembled
//! (`M²`) only when a pattern is factored. This is exact algebra; the two ways differ by
//! round-off.
//!
//! **Heading.** With `J` heading harmonics the basis is `ψ_c(h) φ_jk(x, y)`, `ψ = 1, cos h, sin h,
//! …, cos Jh, sin Jh`, and a product `ψ_c ψ_c'` is a harmonic of degree at most `2J`
//! (`cos a cos b = ½ (cos(a − b) + cos(a + b))`, and the like). So `G` is assembled from
//! `4J + 2` moment slices, each `H` weighted per point: by 1 (every point), by 1 where the heading
//! is known, and by `cos m h`, `sin m h` (`m = 1..=2J`, zero where the heading is unknown: such a
//! point observes the field averaged over heading, only `ψ_0 = 1`). Still `O(M)` per point.
//!
//! **The posterior of the weights.** A pattern's field is `μ_d + φ(x)ᵀ a_d` per output, with
//! `a_d ~ N(0, σ_d² diag(s))`. With `D = σ diag(√s)` and `B = σ_n² I + D G D = R Rᵀ`, the weights
//! given the data are `a_d = D u`, `u ~ N(R⁻ᵀ z_d, σ_n² R⁻ᵀ R⁻¹)`, `z_d = R⁻¹ D b_d`,
//! `b_d = Φᵀ (v_d − μ_d)`; a draw is `D R⁻ᵀ (z_d + σ_n ε)`, one triangular solve.

use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::{Accum, MatMut, MatRef, Par};
use rand_distr::{Distribution, StandardNormal};

use crate::basis::{AxisValues, Basis};
use crate::error::Result;
use crate::frame::{Inputs, Point};
use crate::gp::{GpParams, LN_2PI};
use crate::heading;
use crate::linalg::Chol;

/// Points whose values are computed and summed in one block.
const BLOCK: usize = 256;

/// `buf` as a column-major `n x m` matrix.
fn col(buf: &[f64], n: usize, m: usize) -> MatRef<'_, f64> {
    MatRef::from_column_major_slice(buf, n, m)
}

/// The vector and scalar sums of a set of points: `Φᵀ1` (M), `Φᵀ v_d` (M per output, output `d`
/// at `d M`), `Σ v_d`, `Σ v_d²` and the number of points.
#[derive(Clone, Debug, PartialEq)]
pub struct VecSums {
    pub phi_sum: Vec<f64>,
    pub phi_v: Vec<f64>,
    pub v_sum: [f64; 2],
    pub v_sq: [f64; 2],
    pub n_points: usize,
}

impl VecSums {
    pub fn zeros(m: usize) -> Self {
        Self {
            phi_sum: vec![0.0; m],
            phi_v: vec![0.0; 2 * m],
            v_sum: [0.0; 2],
            v_sq: [0.0; 2],
            n_points: 0,
        }
    }

    /// `b_d = Φᵀ (v_d − μ_d)`.
    pub fn b(&self, d: usize, mu: f64) -> Vec<f64> {
        let m = self.phi_sum.len();
        self.phi_v[d * m..(d + 1) * m]
            .iter()
            .zip(&self.phi_sum)
            .map(|(a, s)| a - mu * s)
            .collect()
    }

    /// `Σ (v_d − μ_d)²`.
    pub fn yy(&self, d: usize, mu: f64) -> f64 {
        self.v_sq[d] - 2.0 * mu * self.v_sum[d] + self.n_points as f64 * mu * mu
    }

    fn add_scaled(&mut self, other: &Self, sign: f64) {
        for (a, b) in self.phi_sum.iter_mut().zip(&other.phi_sum) {
            *a += sign * b;
        }
        for (a, b) in self.phi_v.iter_mut().zip(&other.phi_v) {
            *a += sign * b;
        }
        for d in 0..2 {
            self.v_sum[d] += sign * other.v_sum[d];
            self.v_sq[d] += sign * other.v_sq[d];
        }
    }
}

/// The sums of a set of frames: the moments `H` from which the Gram matrix is assembled, the
/// vector sums, and the number of frames.
#[derive(Clone, Debug, PartialEq)]
pub struct Sums {
    /// `H[a, b] = Σ cos(a θ_x) cos(b θ_y)` over the points in the box, column-major
    /// `(2 m_x + 1) x (2 m_y + 1)`; with heading harmonics, [`n_slices`] such matrices one after
    /// another, each with its per-point weight ([`Slice`]).
    pub h: Vec<f64>,
    pub vecs: VecSums,
    pub n_frames: usize,
}

impl Sums {
    pub fn zeros(basis: &Basis) -> Self {
        Self {
            h: vec![0.0; moment_len(basis) * n_slices(basis)],
            vecs: VecSums::zeros(basis.len()),
            n_frames: 0,
        }
    }

    /// The sums of the points `xy`, `v` of `n_frames` frames (headings unknown).
    pub fn of_points(basis: &Basis, xy: &[Point], v: &[[f64; 2]], n_frames: usize) -> Self {
        Self::of_inputs(basis, Inputs::positions(xy), v, n_frames)
    }

    /// The sums of the points at `pts` (positions and previous headings), velocities `v`, of
    /// `n_frames` frames.
    pub fn of_inputs(basis: &Basis, pts: Inputs<'_>, v: &[[f64; 2]], n_frames: usize) -> Self {
        let mut s = Self::zeros(basis);
        for (i0, vel) in (0..pts.len()).step_by(BLOCK).zip(v.chunks(BLOCK)) {
            let i1 = i0 + vel.len();
            let h = if pts.h.is_empty() {
                &[][..]
            } else {
                &pts.h[i0..i1]
            };
            s.add_values(
                basis,
                &AxisValues::with_cosines(basis, &pts.xy[i0..i1]),
                h,
                vel,
            );
        }
        s.n_frames = n_frames;
        s
    }

    /// Add the points whose values (with cosines) are `vals`, previous headings `h` (empty:
    /// unknown) and velocities `v`.
    pub fn add_values(&mut self, basis: &Basis, vals: &AxisValues, h: &[f64], v: &[[f64; 2]]) {
        let [mx, my] = basis.counts();
        let n = vals.n;
        debug_assert_eq!(v.len(), n);
        let (hx, hy) = (2 * mx + 1, 2 * my + 1);
        let weights = slice_weights(basis.harmonics(), h, n);
        let mut scaled = Vec::new();
        for (s, slice) in self.h.chunks_exact_mut(hx * hy).enumerate() {
            // Slice 0 weighs every point by 1: the moments of a field over position.
            let cx = match &weights {
                Some(w) if s > 0 => {
                    scaled.clear();
                    let w = &w[s * n..(s + 1) * n];
                    for c in vals.cx.chunks_exact(n) {
                        scaled.extend(c.iter().zip(w).map(|(c, w)| c * w));
                    }
                    &scaled[..]
                }
                _ => &vals.cx[..],
            };
            matmul(
                MatMut::from_column_major_slice_mut(slice, hx, hy),
                Accum::Add,
                col(cx, n, hx).transpose(),
                col(&vals.cy, n, hy),
                1.0,
                Par::Seq,
            );
        }
        let (m, mp) = (basis.len(), mx * my);
        let vs = &mut self.vecs;
        let sx = col(&vals.sx, n, mx);
        // Per heading function `c`, `Σ ψ_c φ` and `Σ ψ_c φ v_d`: the y values weighted per point,
        // over the full position block, of which a heading block keeps its lowest `m'` per axis.
        let mut psi = vec![1.0; n];
        let mut weighted = vec![0.0; n * my];
        let mut block = vec![0.0; mp];
        for c in 0..basis.n_heading() {
            if let Some(w) = &weights {
                heading_weights(basis.harmonics(), c, w, n, &mut psi);
            }
            let (at, [bx, by]) = (basis.block_offset(c), basis.block_counts(c));
            for d in 0..3 {
                // d = 0: Σ ψ_c φ; d = 1, 2: Σ ψ_c φ v_{d−1}.
                for (k, o) in weighted.chunks_mut(n).enumerate() {
                    let sy = &vals.sy[k * n..(k + 1) * n];
                    if d == 0 {
                        for ((o, s), p) in o.iter_mut().zip(sy).zip(&psi) {
                            *o = s * p;
                        }
                    } else {
                        for (((o, s), p), vel) in o.iter_mut().zip(sy).zip(&psi).zip(v) {
                            *o = s * p * vel[d - 1];
                        }
                    }
                }
                let out = match d {
                    0 => &mut vs.phi_sum[at..],
                    d => &mut vs.phi_v[(d - 1) * m + at..],
                };
                if [bx, by] == [mx, my] {
                    matmul(
                        MatMut::from_column_major_slice_mut(&mut out[..mp], mx, my),
                        Accum::Add,
                        sx.transpose(),
                        col(&weighted, n, my),
                        1.0,
                        Par::Seq,
                    );
                } else {
                    matmul(
                        MatMut::from_column_major_slice_mut(&mut block, mx, my),
                        Accum::Replace,
                        sx.transpose(),
                        col(&weighted, n, my),
                        1.0,
                        Par::Seq,
                    );
                    for k in 0..by {
                        for (o, x) in out[k * bx..(k + 1) * bx].iter_mut().zip(&block[k * mx..]) {
                            *o += x;
                        }
                    }
                }
            }
        }
        for vel in v {
            for d in 0..2 {
                vs.v_sum[d] += vel[d];
                vs.v_sq[d] += vel[d] * vel[d];
            }
        }
        vs.n_points += n;
    }

    /// `self += other`.
    pub fn add(&mut self, other: &Self) {
        self.add_scaled(other, 1.0);
        self.vecs.n_points += other.vecs.n_points;
        self.n_frames += other.n_frames;
    }

    /// `self −= other` (`other` a subset of the frames summed here).
    pub fn sub(&mut self, other: &Self) {
        self.add_scaled(other, -1.0);
        self.vecs.n_points -= other.vecs.n_points;
        self.n_frames -= other.n_frames;
    }

    fn add_scaled(&mut self, other: &Self, sign: f64) {
        for (a, b) in self.h.iter_mut().zip(&other.h) {
            *a += sign * b;
        }
        self.vecs.add_scaled(&other.vecs, sign);
    }

    /// The sums under `coarse`, a basis on the same box with at most as many functions per axis
    /// (the lowest frequencies): sub-blocks of the moments and of the vector sums.
    pub fn restrict(&self, full: &Basis, coarse: &Basis) -> Self {
        debug_assert_eq!(full.harmonics(), coarse.harmonics());
        debug_assert!((0..2).all(|d| coarse.heading_counts()[d] <= full.heading_counts()[d]));
        let ([mx, _], [cx, cy]) = (full.counts(), coarse.counts());
        let hx = 2 * mx + 1;
        let mut h = Vec::with_capacity(moment_len(coarse) * n_slices(coarse));
        for slice in self.h.chunks_exact(moment_len(full)) {
            for b in 0..2 * cy + 1 {
                h.extend_from_slice(&slice[b * hx..b * hx + 2 * cx + 1]);
            }
        }
        let m = full.len();
        let pick = |v: &[f64]| -> Vec<f64> { coarse_indices(full, coarse).map(|c| v[c]).collect() };
        Self {
            h,
            vecs: VecSums {
                phi_sum: pick(&self.vecs.phi_sum),
                phi_v: [pick(&self.vecs.phi_v[..m]), pick(&self.vecs.phi_v[m..])].concat(),
                ..self.vecs.clone()
            },
            n_frames: self.n_frames,
        }
    }

    /// `G = Σ φ φᵀ` (M x M, both triangles) from the moments.
    pub fn gram(&self, basis: &Basis) -> Vec<f64> {
        let harmonics = basis.harmonics();
        if harmonics == 0 {
            return position_gram(basis, &self.h);
        }
        // Block (c, c') of heading functions: a combination of the slices' position Grams, over
        // each block's position functions. Slice 0 (every point) enters block (0, 0) only, so it
        // is the only slice needed over all position functions in both directions; the others
        // only where one side is a heading block: all rows, the heading blocks' columns. Blocks
        // (c ≥ 1, 0) are then the transposes of (0, c) (each position Gram is symmetric, bitwise).
        let (mp, mx, m) = (basis.positions_len(), basis.counts()[0], basis.len());
        let [hx, hy] = basis.heading_counts();
        let cols: Vec<usize> = (0..hy)
            .flat_map(|k| (0..hx).map(move |j| j + mx * k))
            .collect();
        let slices: Vec<&[f64]> = self.h.chunks_exact(moment_len(basis)).collect();
        let all: Vec<usize> = (0..mp).collect();
        let grams: Vec<Vec<f64>> = slices
            .iter()
            .enumerate()
            .map(|(s, h)| position_gram_cols(basis, h, if s == 0 { &all } else { &cols }))
            .collect();
        let mut g = vec![0.0; m * m];
        for c2 in 0..basis.n_heading() {
            let ([bx2, by2], at2) = (basis.block_counts(c2), basis.block_offset(c2));
            for c in 0..basis.n_heading() {
                if c2 == 0 && c > 0 {
                    continue;
                }
                let ([bx, by], at) = (basis.block_counts(c), basis.block_offset(c));
                let terms = heading_product(harmonics, c, c2);
                for col in 0..bx2 * by2 {
                    // The column's position in the slices' Grams: its own index in slice 0's
                    // (all columns), its place among the heading columns in the others'.
                    let pcol = if c2 == 0 {
                        col % bx2 + mx * (col / bx2)
                    } else {
                        col
                    };
                    let out = &mut g[(at2 + col) * m + at..][..bx * by];
                    for &(slice, w) in &terms {
                        let src = &grams[slice][pcol * mp..(pcol + 1) * mp];
                        for (k, o) in out.chunks_exact_mut(bx).enumerate() {
                            for (o, x) in o.iter_mut().zip(&src[k * mx..k * mx + bx]) {
                                *o += w * x;
                            }
                        }
                    }
                }
            }
        }
        // Blocks (c ≥ 1, 0): the transposes of blocks (0, c).
        for col in 0..mp {
            for row in mp..m {
                g[col * m + row] = g[row * m + col];
            }
        }
        g
    }
}

/// Entries of one moment slice: `(2 m_x + 1)(2 m_y + 1)`.
fn moment_len(basis: &Basis) -> usize {
    let [mx, my] = basis.counts();
    (2 * mx + 1) * (2 * my + 1)
}

/// Moment slices of a basis: 1 over position; with `J` heading harmonics, `4J + 2` (every point;
/// points with a known heading; `cos m h` and `sin m h` for `m = 1..=2J`).
pub fn n_slices(basis: &Basis) -> usize {
    match basis.harmonics() {
        0 => 1,
        j => 4 * j + 2,
    }
}

/// The slice holding `cos m h` (`m = 0`: the points with a known heading).
fn cos_slice(m: usize) -> usize {
    1 + m
}

/// The slice holding `sin m h`, `m ≥ 1`.
fn sin_slice(harmonics: usize, m: usize) -> usize {
    1 + 2 * harmonics + m
}

/// Each slice's weight of each of `n` points (slice-major), `None` over position: 1; 1 where the
/// heading is known; `cos m h`; `sin m h` (zero where `h` is unknown: empty or `NaN`).
fn slice_weights(harmonics: usize, h: &[f64], n: usize) -> Option<Vec<f64>> {
    if harmonics == 0 {
        return None;
    }
    let mut w = vec![0.0; (4 * harmonics + 2) * n];
    w[..n].fill(1.0);
    for (i, &hi) in h.iter().enumerate() {
        if hi.is_nan() {
            continue;
        }
        w[cos_slice(0) * n + i] = 1.0;
        for m in 1..=2 * harmonics {
            let (sn, cs) = (m as f64 * hi).sin_cos();
            w[cos_slice(m) * n + i] = cs;
            w[sin_slice(harmonics, m) * n + i] = sn;
        }
    }
    Some(w)
}

/// `ψ_c` of each point from its slice weights `w` (`1` for `c = 0`; [`heading::features`] order).
fn heading_weights(harmonics: usize, c: usize, w: &[f64], n: usize, psi: &mut [f64]) {
    let slice = match c {
        0 => 0,
        c if c % 2 == 1 => cos_slice(heading::harmonic_of(c)),
        c => sin_slice(harmonics, heading::harmonic_of(c)),
    };
    psi.copy_from_slice(&w[slice * n..(slice + 1) * n]);
}

/// `ψ_c ψ_c'` as weighted slices: `(slice, weight)` terms (product-to-sum identities; a term of
/// `sin 0 h` vanishes).
fn heading_product(harmonics: usize, c: usize, c2: usize) -> Vec<(usize, f64)> {
    // (is sine, harmonic) of a heading function; the constant is `cos 0h` over every point.
    let kind = |c: usize| (c > 0 && c.is_multiple_of(2), heading::harmonic_of(c));
    match (kind(c), kind(c2)) {
        ((_, 0), (false, 0)) => vec![(0, 1.0)],
        ((false, 0), (sine, j)) | ((sine, j), (false, 0)) => {
            let slice = if sine {
                sin_slice(harmonics, j)
            } else {
                cos_slice(j)
            };
            vec![(slice, 1.0)]
        }
        ((false, j), (false, k)) => vec![(cos_slice(j.abs_diff(k)), 0.5), (cos_slice(j + k), 0.5)],
        ((true, j), (true, k)) => vec![(cos_slice(j.abs_diff(k)), 0.5), (cos_slice(j + k), -0.5)],
        ((false, j), (true, k)) | ((true, k), (false, j)) => {
            // cos jh sin kh = ½ (sin (k + j) h + sin (k − j) h).
            let mut t = vec![(sin_slice(harmonics, j + k), 0.5)];
            if k != j {
                let sign = if k > j { 0.5 } else { -0.5 };
                t.push((sin_slice(harmonics, k.abs_diff(j)), sign));
            }
            t
        }
    }
}

/// The position Gram `Σ φ φᵀ` (`m_x m_y` square) from one moment slice `h`.
fn position_gram(basis: &Basis, h: &[f64]) -> Vec<f64> {
    let all: Vec<usize> = (0..basis.positions_len()).collect();
    position_gram_cols(basis, h, &all)
}

/// The columns `cols` (position indices `j + m_x k`) of the position Gram from one moment slice
/// `h`: `m_x m_y` rows per column, column after column.
fn position_gram_cols(basis: &Basis, h: &[f64], cols: &[usize]) -> Vec<f64> {
    let [mx, my] = basis.counts();
    let [lx, ly] = basis.half_widths();
    let (m, hx) = (mx * my, 2 * mx + 1);
    let scale = 1.0 / (4.0 * lx * ly);
    let h = |a: usize, b: usize| h[a + hx * b];
    let mut g = vec![0.0; m * cols.len()];
    for (col, &p) in g.chunks_exact_mut(m).zip(cols) {
        let (j2, k2) = (p % mx, p / mx);
        for k in 0..my {
            let (em, ep) = (k.abs_diff(k2), k + k2 + 2);
            for j in 0..mx {
                let (dm, dp) = (j.abs_diff(j2), j + j2 + 2);
                col[j + mx * k] = scale * (h(dm, em) - h(dm, ep) - h(dp, em) + h(dp, ep));
            }
        }
    }
    g
}

/// Where each function of `coarse` (a basis on the same box with no more functions per axis, in
/// the position block and in the heading blocks) sits in `full`'s feature order: with heading
/// harmonics (the same in both), each heading block's own.
pub fn coarse_indices<'a>(full: &'a Basis, coarse: &'a Basis) -> impl Iterator<Item = usize> + 'a {
    (0..coarse.n_heading()).flat_map(move |c| {
        let ([fx, _], [cx, cy], at) = (
            full.block_counts(c),
            coarse.block_counts(c),
            full.block_offset(c),
        );
        (0..cy).flat_map(move |k| (0..cx).map(move |j| at + j + fx * k))
    })
}

/// Weights on `coarse`'s functions as weights on `full`'s (zero on the functions it lacks).
pub fn embed(full: &Basis, coarse: &Basis, w: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; full.len()];
    for (c, x) in coarse_indices(full, coarse).zip(w) {
        out[c] = *x;
    }
    out
}

/// One output group's factor: `R = chol(σ_n² I + D G D)` and `z = R⁻¹ D b` (M x outputs).
#[derive(Clone, Debug)]
pub struct Group {
    pub outs: &'static [usize],
    pub signal_var: f64,
    pub noise_var: f64,
    pub chol: Vec<f64>,
    pub z: Vec<f64>,
}

impl Group {
    /// Factor the group of outputs `outs` (signal variance `s2`, noise `noise`) with `d = σ √s`.
    pub fn new(
        outs: &'static [usize],
        (s2, noise): (f64, f64),
        gram: &[f64],
        d: &[f64],
        vecs: &VecSums,
        mean: [f64; 2],
    ) -> Result<Self> {
        let m = d.len();
        let chol = Chol::factor(m, "reduced-rank", Par::Seq, || {
            let mut b = vec![0.0; m * m];
            for j in 0..m {
                for i in 0..m {
                    b[j * m + i] = d[i] * gram[j * m + i] * d[j];
                }
                b[j * m + j] += noise;
            }
            b
        })?;
        let mut g = Self {
            outs,
            signal_var: s2,
            noise_var: noise,
            chol: chol.l,
            z: Vec::new(),
        };
        g.z = g.whiten(d, vecs, mean);
        Ok(g)
    }

    pub fn r(&self, m: usize) -> MatRef<'_, f64> {
        MatRef::from_column_major_slice(&self.chol, m, m)
    }

    pub fn log_det(&self, m: usize) -> f64 {
        2.0 * (0..m).map(|i| self.chol[i * m + i].ln()).sum::<f64>()
    }

    /// `z = R⁻¹ D b` for every output of the group.
    pub fn whiten(&self, d: &[f64], vecs: &VecSums, mean: [f64; 2]) -> Vec<f64> {
        let m = d.len();
        let mut z = Vec::with_capacity(m * self.outs.len());
        for &o in self.outs {
            z.extend(vecs.b(o, mean[o]).iter().zip(d).map(|(b, d)| b * d));
        }
        solve_lower_triangular_in_place(
            self.r(m),
            MatMut::from_column_major_slice_mut(&mut z, m, self.outs.len()),
            Par::Seq,
        );
        z
    }

    /// `D R⁻ᵀ (z + σ_n ε)` per output of the group (M x outputs): the posterior mean weights with
    /// `noise = None`, a draw with standard normals `noise`.
    pub fn weights(&self, d: &[f64], noise: Option<&mut dyn FnMut() -> f64>) -> Vec<f64> {
        let m = d.len();
        let mut a = self.z.clone();
        if let Some(eps) = noise {
            let s = self.noise_var.sqrt();
            for x in a.iter_mut() {
                *x += s * eps();
            }
        }
        solve_upper_triangular_in_place(
            self.r(m).transpose(),
            MatMut::from_column_major_slice_mut(&mut a, m, self.outs.len()),
            Par::Seq,
        );
        for col in a.chunks_mut(m) {
            for (x, d) in col.iter_mut().zip(d) {
                *x *= d;
            }
        }
        a
    }
}

/// `D = σ √s` for a group's signal variance.
pub fn scaled_sqrt_spectrum(sqrt_s: &[f64], signal_var: f64) -> Vec<f64> {
    let s = signal_var.sqrt();
    sqrt_s.iter().map(|x| s * x).collect()
}

/// `log p(D)` under the reduced-rank GP from the factors of every output group.
pub fn log_marginal(groups: &[Group], vecs: &VecSums, mean: [f64; 2], m: usize) -> f64 {
    let n = vecs.n_points as f64;
    let mut total = -n * LN_2PI;
    for g in groups {
        let s2n = g.noise_var;
        let k = g.outs.len() as f64;
        let zz: f64 = g.z.iter().map(|x| x * x).sum();
        let yy: f64 = g.outs.iter().map(|&d| vecs.yy(d, mean[d])).sum();
        let log_det = (n - m as f64) * s2n.ln() + g.log_det(m);
        total -= 0.5 * (yy - zz) / s2n + 0.5 * k * log_det;
    }
    total
}

/// A pattern's sums factored under hyperparameters: its log marginal likelihood and the posterior
/// of its weights.
#[derive(Clone, Debug)]
pub struct Posterior {
    pub params: GpParams,
    groups: Vec<Group>,
    /// `D` of each group, in group order.
    d: Vec<Vec<f64>>,
    pub log_marginal: f64,
}

impl Posterior {
    /// Factor `sums` (whose Gram matrix is `gram`) under `params`: one M x M Cholesky per output
    /// group.
    pub fn new(basis: &Basis, sums: &Sums, gram: &[f64], params: GpParams) -> Result<Self> {
        Self::reusing(basis, sums, gram, params, None)
    }

    /// The same sums under other `params`, keeping the factor of every output group whose
    /// variances are unchanged when the length scales and means are (a noise step changes one
    /// output's noise at a time: the other group's factor is the same numbers).
    pub fn refit(
        &self,
        basis: &Basis,
        sums: &Sums,
        gram: &[f64],
        params: GpParams,
    ) -> Result<Self> {
        let same =
            params.length_scales == self.params.length_scales && params.mean == self.params.mean;
        Self::reusing(basis, sums, gram, params, same.then_some(self))
    }

    fn reusing(
        basis: &Basis,
        sums: &Sums,
        gram: &[f64],
        params: GpParams,
        old: Option<&Self>,
    ) -> Result<Self> {
        let sqrt_s = basis.sqrt_spectral(params.length_scales);
        let mut groups = Vec::new();
        let mut ds = Vec::new();
        for outs in params.groups() {
            let vars = params.group_vars(outs);
            let kept = old.and_then(|o| {
                o.groups
                    .iter()
                    .zip(&o.d)
                    .find(|(g, _)| g.outs == *outs && (g.signal_var, g.noise_var) == vars)
            });
            if let Some((g, d)) = kept {
                groups.push(g.clone());
                ds.push(d.clone());
                continue;
            }
            let d = scaled_sqrt_spectrum(&sqrt_s, vars.0);
            groups.push(Group::new(outs, vars, gram, &d, &sums.vecs, params.mean)?);
            ds.push(d);
        }
        let log_marginal = log_marginal(&groups, &sums.vecs, params.mean, basis.len());
        Ok(Self {
            params,
            groups,
            d: ds,
            log_marginal,
        })
    }

    /// The weights `[a_x, a_y]` (M each, feature order): the posterior mean with `rng = None`, a
    /// posterior draw otherwise.
    pub fn weights(&self, mut rng: Option<&mut dyn rand::Rng>) -> [Vec<f64>; 2] {
        let mut out = [Vec::new(), Vec::new()];
        for (g, d) in self.groups.iter().zip(&self.d) {
            let a = match rng.as_deref_mut() {
                Some(r) => {
                    let mut eps = || -> f64 { StandardNormal.sample(&mut *r) };
                    g.weights(d, Some(&mut eps))
                }
                None => g.weights(d, None),
            };
            let m = d.len();
            for (c, &o) in g.outs.iter().enumerate() {
                out[o] = a[c * m..(c + 1) * m].to_vec();
            }
        }
        out
    }
}

#[cfg(test)]
#[path = "tests/hsgp_sums.rs"]
mod tests;
