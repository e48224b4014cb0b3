//! The Hilbert-space basis of the reduced-rank GP (Solin & Särkkä 2020; Riutort-Mayol et al. 2023).
//!
//! On a box `[c − L, c + L]` per axis, the Laplacian's Dirichlet eigenfunctions
//! `φ_j(u) = sin(π j (u − c + L) / (2L)) / √L` with `√λ_j = π j / (2L)` give the separable basis
//! `φ_jk(x, y) = φ_j(x) φ_k(y)`, and the squared-exponential kernel becomes
//! `k̃(p, q) = σ² Σ_jk s_jk φ_jk(p) φ_jk(q)` with `s_jk = S_x(√λ_j) S_y(√λ_k)` the kernel's
//! (unit-variance) spectral density. The basis does not depend on the length scales: what a
//! pattern's frames contribute are sums over them (`hsgp_sums`).

use std::f64::consts::PI;

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use crate::error::{Error, Result};
use crate::frame::{Inputs, LengthScales, Point};
use crate::heading;

/// Most basis functions a fit may use (M x M matrices of 8 bytes: 128 MiB each at the cap).
pub const MAX_BASIS: usize = 4096;

/// The basis: a box per axis and the number of eigenfunctions along each; for a field over
/// position and heading, also the harmonics in heading (`heading`), heading-major: block `c = 0`
/// is the position functions (index `j + m_x k`), and each later block is `cos h`, `sin h`, …,
/// `cos Jh`, `sin Jh` times the lowest `m'_x m'_y` position functions (index `j + m'_x k`
/// within its block), the *heading counts* `m'` (`m' = m`: the full tensor product).
///
/// Why fewer position functions with heading: every factorisation of a pattern is `M x M`, so
/// the full product costs `(2J + 1)³` times a position fit's; the part of a field that varies
/// with heading (which lane's direction, which turn) varies over longer distances than the
/// field itself, and `k̃ = q_0² k_m(p, p') + Σ_{j ≥ 1} q_j² cos(j (h − h')) k_m'(p, p')` is a
/// kernel in its own right (a sum of two), with `k_m` the position kernel on `m` functions.
#[derive(Clone, Debug, PartialEq)]
pub struct Basis {
    center: [f64; 2],
    half: [f64; 2],
    m: [usize; 2],
    harmonics: usize,
    /// Position functions per axis of each heading block (`≤ m`).
    heading_m: [usize; 2],
}

impl Basis {
    pub fn new(center: [f64; 2], half: [f64; 2], m: [usize; 2]) -> Result<Self> {
        if !(center.iter().all(|c| c.is_finite()) && half.iter().all(|h| h.is_finite() && *h > 0.0))
        {
            return Err(Error::InvalidInput(format!(
                "the basis box needs a finite centre and positive half-widths, got {center:?}, {half:?}"
            )));
        }
        if m[0] == 0 || m[1] == 0 || m[0].saturating_mul(m[1]) > MAX_BASIS {
            return Err(Error::InvalidInput(format!(
                "n_basis must be two positive counts with a product of at most {MAX_BASIS}, got {m:?}"
            )));
        }
        Ok(Self {
            center,
            half,
            m,
            harmonics: 0,
            heading_m: m,
        })
    }

    /// The same position basis times `2 harmonics + 1` functions of heading (0: position only),
    /// the full tensor product.
    pub fn with_harmonics(self, harmonics: usize) -> Result<Self> {
        let m = self.m;
        self.with_heading(harmonics, m)
    }

    /// The position basis with `harmonics` heading harmonics, each heading block on the lowest
    /// `heading_m` position functions per axis (at least 1, at most the position counts).
    pub fn with_heading(self, harmonics: usize, heading_m: [usize; 2]) -> Result<Self> {
        if !(1..=self.m[0]).contains(&heading_m[0]) || !(1..=self.m[1]).contains(&heading_m[1]) {
            return Err(Error::InvalidInput(format!(
                "heading counts must be 1 to the position counts {:?} per axis, got {heading_m:?}",
                self.m
            )));
        }
        let blocks = (heading_m[0] * heading_m[1]).saturating_mul(2 * harmonics);
        let total = (self.m[0] * self.m[1]).saturating_add(blocks);
        if total > MAX_BASIS {
            return Err(Error::InvalidInput(format!(
                "{} position functions and {blocks} heading functions make {total} basis \
                 functions, more than {MAX_BASIS}: use fewer heading harmonics or a smaller n_basis",
                self.m[0] * self.m[1],
            )));
        }
        Ok(Self {
            harmonics,
            heading_m,
            ..self
        })
    }

    /// Heading harmonics `J` (0: the field does not depend on heading).
    pub fn harmonics(&self) -> usize {
        self.harmonics
    }

    /// Position functions `m_x m_y`.
    pub fn positions_len(&self) -> usize {
        self.m[0] * self.m[1]
    }

    /// Position functions per axis of each heading block (`m'`).
    pub fn heading_counts(&self) -> [usize; 2] {
        self.heading_m
    }

    /// Heading functions `2J + 1` (1 over position).
    pub fn n_heading(&self) -> usize {
        2 * self.harmonics + 1
    }

    /// Position functions per axis of heading block `c` (`m` for the constant, `m'` after).
    pub fn block_counts(&self, c: usize) -> [usize; 2] {
        if c == 0 { self.m } else { self.heading_m }
    }

    /// Where heading block `c` starts in feature order.
    pub fn block_offset(&self, c: usize) -> usize {
        match c {
            0 => 0,
            c => self.positions_len() + (c - 1) * self.heading_m[0] * self.heading_m[1],
        }
    }

    /// Each feature's index in the full tensor product (`c m_x m_y + j + m_x k`), in feature
    /// order: how the features, spectra and fields of a basis with fewer heading functions are
    /// read off the full product's.
    pub fn tensor_indices(&self) -> impl Iterator<Item = usize> + '_ {
        let (mx, mp) = (self.m[0], self.positions_len());
        (0..self.n_heading()).flat_map(move |c| {
            let [bx, by] = self.block_counts(c);
            (0..by).flat_map(move |k| (0..bx).map(move |j| c * mp + j + mx * k))
        })
    }

    /// Feature-order weights `w` as weights on the full tensor product (zero on the functions
    /// this basis lacks): `2J + 1` position blocks of `m_x m_y`.
    pub fn to_tensor(&self, w: &[f64]) -> Vec<f64> {
        debug_assert_eq!(w.len(), self.len());
        let mut out = vec![0.0; self.positions_len() * self.n_heading()];
        for (i, x) in self.tensor_indices().zip(w) {
            out[i] = *x;
        }
        out
    }

    /// Whether the heading blocks hold every position function (the full tensor product).
    pub fn is_tensor(&self) -> bool {
        self.heading_m == self.m
    }

    /// Whether the basis has heading functions and `ls` a finite heading length scale.
    fn headed(&self, ls: LengthScales) -> bool {
        self.harmonics > 0 && heading::is_headed(ls.wh)
    }

    /// The documented sizing rule for training positions `xy`. Per axis, with `S` the data's
    /// half-range, `w_lo` a low and `w_mid` a typical length scale: the box half-width is
    /// `L = max(1.2 S, S + 2 w_mid)` (the boundary distorts `k̃` within about two length scales
    /// of it) and `m = ceil(2 L / w_lo)`, which puts the highest frequency at `π / w_lo`, where
    /// the spectral density has fallen to `e^{−π²/2} ≈ 0.7%` of its peak for `w = w_lo` and to
    /// far less for the typical `w`. `m` given by the caller overrides the count.
    pub fn for_data(
        xy: &[Point],
        w_lo: [f64; 2],
        w_mid: [f64; 2],
        m: Option<[usize; 2]>,
    ) -> Result<Self> {
        if xy.is_empty() {
            return Err(Error::Shape("no positions to size the basis from".into()));
        }
        let mut center = [0.0; 2];
        let mut half = [0.0; 2];
        let mut count = [0; 2];
        for d in 0..2 {
            let lo = xy.iter().map(|p| p[d]).fold(f64::INFINITY, f64::min);
            let hi = xy.iter().map(|p| p[d]).fold(f64::NEG_INFINITY, f64::max);
            if !(w_lo[d] > 0.0 && w_mid[d] > 0.0 && w_lo[d].is_finite() && w_mid[d].is_finite()) {
                return Err(Error::InvalidInput(format!(
                    "length scales for sizing the basis must be positive, got {w_lo:?}, {w_mid:?}"
                )));
            }
            let s = (0.5 * (hi - lo)).max(w_lo[d]);
            center[d] = 0.5 * (lo + hi);
            half[d] = (1.2 * s).max(s + 2.0 * w_mid[d]);
            count[d] = ((2.0 * half[d] / w_lo[d]).ceil() as usize).max(4);
        }
        let count = match m {
            Some(m) => m,
            None => {
                // Past the cap, shrink both counts in proportion.
                let total = count[0] * count[1];
                if total > MAX_BASIS {
                    let f = (MAX_BASIS as f64 / total as f64).sqrt();
                    [0, 1].map(|d| ((count[d] as f64 * f).floor() as usize).max(1))
                } else {
                    count
                }
            }
        };
        Self::new(center, half, count)
    }

    /// [`Basis::for_data`] with the low and typical length scales of the fit: the 5% quantile
    /// and the median of the Gamma(shape, scale) prior, or the fixed length scales.
    pub fn for_prior(
        xy: &[Point],
        prior: (f64, f64),
        fixed: Option<LengthScales>,
        m: Option<[usize; 2]>,
    ) -> Result<Self> {
        let (lo, mid) = match fixed {
            Some(ls) => ([ls.wx, ls.wy], [ls.wx, ls.wy]),
            None => {
                let (a, b) = prior;
                if !(a > 0.0 && b > 0.0 && a.is_finite() && b.is_finite()) {
                    return Err(Error::InvalidInput(format!(
                        "length_scale_prior must be (shape, scale) with both positive, got {prior:?}"
                    )));
                }
                let lo = crate::special::gamma_quantile(0.05, a, b);
                let mid = crate::special::gamma_quantile(0.5, a, b);
                ([lo; 2], [mid; 2])
            }
        };
        Self::for_data(xy, lo, mid, m)
    }

    pub fn len(&self) -> usize {
        self.positions_len() + 2 * self.harmonics * self.heading_m[0] * self.heading_m[1]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn center(&self) -> [f64; 2] {
        self.center
    }

    pub fn half_widths(&self) -> [f64; 2] {
        self.half
    }

    pub fn counts(&self) -> [usize; 2] {
        self.m
    }

    fn sqrt_eig(&self, d: usize, j: usize) -> f64 {
        PI * (j + 1) as f64 / (2.0 * self.half[d])
    }

    /// `φ_j(u)` along axis `d` for every `j`, zero outside the box.
    fn eval_axis(&self, d: usize, u: f64, out: &mut [f64]) {
        let t = u - self.center[d] + self.half[d];
        if !(0.0..=2.0 * self.half[d]).contains(&t) {
            out.fill(0.0);
            return;
        }
        let norm = 1.0 / self.half[d].sqrt();
        let theta = PI * t / (2.0 * self.half[d]);
        for (j, o) in out.iter_mut().enumerate() {
            *o = norm * ((j + 1) as f64 * theta).sin();
        }
    }

    /// Whether `p` lies in the box (where the basis has support).
    pub fn contains(&self, p: Point) -> bool {
        (0..2).all(|d| (p[d] - self.center[d]).abs() <= self.half[d])
    }

    /// `Φᵀ` of the points: column-major `M x n`, one column of basis values per point
    /// (index `j + m_x k` for `φ_j(x) φ_k(y)`; with heading harmonics, that block once per
    /// heading function, the points' headings unknown: see [`Basis::features_of`]).
    pub fn features(&self, xy: &[Point]) -> Vec<f64> {
        self.features_of(Inputs::positions(xy))
    }

    /// `Φᵀ` at positions and previous headings (`ψ_c(h) φ_j(x) φ_k(y)` in feature order).
    pub fn features_of(&self, pts: Inputs<'_>) -> Vec<f64> {
        let (mx, my) = (self.m[0], self.m[1]);
        let mp = mx * my;
        let mm = self.len();
        let [hx, hy] = self.heading_m;
        let mut out = vec![0.0; mm * pts.len()];
        let mut fx = vec![0.0; mx];
        let mut fy = vec![0.0; my];
        let mut psi = vec![0.0; 2 * self.harmonics + 1];
        for (i, (col, p)) in out.chunks_mut(mm).zip(pts.xy).enumerate() {
            self.eval_axis(0, p[0], &mut fx);
            self.eval_axis(1, p[1], &mut fy);
            for (k, &y) in fy.iter().enumerate() {
                for (c, &x) in col[k * mx..(k + 1) * mx].iter_mut().zip(&fx) {
                    *c = x * y;
                }
            }
            if self.harmonics > 0 {
                // Each heading block: ψ_c(h) times the lowest h_x h_y position values.
                heading::features(pts.heading(i), &mut psi);
                let (pos, rest) = col.split_at_mut(mp);
                for (block, &w) in rest.chunks_mut(hx * hy).zip(&psi[1..]) {
                    for (row, src) in block.chunks_mut(hx).zip(pos.chunks(mx)) {
                        for (b, &x) in row.iter_mut().zip(src) {
                            *b = w * x;
                        }
                    }
                }
            }
        }
        out
    }

    /// Per-axis unit spectral densities `S_d(√λ_j)` at length scales `ls`.
    fn axis_spectra(&self, ls: LengthScales) -> [Vec<f64>; 2] {
        let w = [ls.wx, ls.wy];
        [0, 1].map(|d| {
            (0..self.m[d])
                .map(|j| {
                    let o = self.sqrt_eig(d, j);
                    (2.0 * PI).sqrt() * w[d] * (-0.5 * w[d] * w[d] * o * o).exp()
                })
                .collect()
        })
    }

    /// `√s_jk` for every basis function, in feature order (times `√q_c` of the heading function
    /// `c` with heading harmonics: a heading length scale of `∞` leaves only the constant).
    pub fn sqrt_spectral(&self, ls: LengthScales) -> Vec<f64> {
        let [sx, sy] = self.axis_spectra(ls);
        let pos: Vec<f64> = sy
            .iter()
            .flat_map(|&y| sx.iter().map(move |&x| (x * y).sqrt()))
            .collect();
        if self.harmonics == 0 {
            return pos;
        }
        let q = heading::spectrum(ls.wh, self.harmonics);
        let mp = pos.len();
        self.tensor_indices()
            .map(|i| pos[i % mp] * q[heading::harmonic_of(i / mp)].sqrt())
            .collect()
    }

    /// The eigenfunctions along each axis at the points (points x m_d, column-major): what
    /// [`Basis::correlation_between`] needs, independent of the length scales.
    pub fn axis_features(&self, pts: &[Point]) -> AxisFeatures {
        let n = pts.len();
        let f = [0, 1].map(|d| {
            let m = self.m[d];
            let mut f = vec![0.0; n * m];
            let mut col = vec![0.0; m];
            for (i, p) in pts.iter().enumerate() {
                self.eval_axis(d, p[d], &mut col);
                for (j, c) in col.iter().enumerate() {
                    f[j * n + i] = *c;
                }
            }
            f
        });
        AxisFeatures { n, f }
    }

    /// `scale · k̃(a, b) / σ²` of positions, i.e. `scale Σ s φ(a) φ(b)` over the position
    /// functions, column-major `|a| x |b|`. Separable: the product of two one-axis sums,
    /// `|a| |b| (m_x + m_y)` work.
    pub fn correlation_between(
        &self,
        a: &AxisFeatures,
        b: &AxisFeatures,
        ls: LengthScales,
        scale: f64,
    ) -> Vec<f64> {
        self.position_correlation(a, b, ls, scale, self.m)
    }

    /// [`Basis::correlation_between`] over the lowest `counts` functions per axis.
    fn position_correlation(
        &self,
        a: &AxisFeatures,
        b: &AxisFeatures,
        ls: LengthScales,
        scale: f64,
        counts: [usize; 2],
    ) -> Vec<f64> {
        let spectra = self.axis_spectra(ls);
        let mut out = vec![scale; a.n * b.n];
        if out.is_empty() {
            return out;
        }
        let mut k = vec![0.0; a.n * b.n];
        for d in 0..2 {
            let m = counts[d];
            // a's eigenfunctions weighted by the spectrum, times b's (the first m columns).
            let mut fa = a.f[d][..a.n * m].to_vec();
            for (j, s) in spectra[d][..m].iter().enumerate() {
                for x in &mut fa[j * a.n..(j + 1) * a.n] {
                    *x *= s;
                }
            }
            matmul(
                MatMut::from_column_major_slice_mut(&mut k, a.n, b.n),
                Accum::Replace,
                MatRef::from_column_major_slice(&fa, a.n, m),
                MatRef::from_column_major_slice(&b.f[d][..b.n * m], b.n, m).transpose(),
                1.0,
                Par::Seq,
            );
            for (o, x) in out.iter_mut().zip(&k) {
                *o *= x;
            }
        }
        out
    }

    /// `scale · k̃(a, b) / σ²` of two point sets: [`Basis::headed_correlation`] from their
    /// per-axis features.
    pub fn correlation(
        &self,
        a: Inputs<'_>,
        b: Inputs<'_>,
        ls: LengthScales,
        scale: f64,
    ) -> Vec<f64> {
        let fa = self.axis_features(a.xy);
        if std::ptr::eq(a.xy, b.xy) {
            self.headed_correlation(&fa, &fa, a, b, ls, scale)
        } else {
            self.headed_correlation(&fa, &self.axis_features(b.xy), a, b, ls, scale)
        }
    }

    /// `scale · k̃(a, b) / σ²` of the point sets `a`, `b` whose per-axis features are `fa`, `fb`:
    /// the position correlation times the truncated periodic kernel of the headings,
    /// `Σ_{j ≤ J} q_j² cos(j (h_a − h_b))` (`q_0²` where either is unknown), with the terms
    /// `j ≥ 1` on the heading blocks' position functions. The position correlation alone without
    /// heading harmonics or with `w_h = ∞`.
    pub fn headed_correlation(
        &self,
        fa: &AxisFeatures,
        fb: &AxisFeatures,
        a: Inputs<'_>,
        b: Inputs<'_>,
        ls: LengthScales,
        scale: f64,
    ) -> Vec<f64> {
        let mut out = self.correlation_between(fa, fb, ls, scale);
        if !self.headed(ls) || a.is_empty() {
            return out;
        }
        let q = heading::spectrum(ls.wh, self.harmonics);
        // `Σ_{j ≥ from} q_j² cos(j d)` from `cos d` by the Chebyshev recurrence
        // `cos(j d) = 2 cos d cos((j − 1) d) − cos((j − 2) d)`: no trigonometry per pair (it was
        // a fifth of a rollout over heading).
        let cos_sum = |from: usize, c1: f64| -> f64 {
            let (mut prev, mut cur) = (1.0, c1);
            let mut sum = if from == 0 { q[0] } else { 0.0 };
            for w in &q[1..] {
                sum += w * cur;
                (prev, cur) = (cur, 2.0 * c1 * cur - prev);
            }
            sum
        };
        // `cos(h_a − h_b) = cos h_a cos h_b + sin h_a sin h_b`: NaN where either is unknown.
        let unit = |h: f64| [h.cos(), h.sin()];
        let ua: Vec<[f64; 2]> = (0..a.len()).map(|i| unit(a.heading(i))).collect();
        // The full product is separable: one factor per pair of points.
        let coarse = (!self.is_tensor())
            .then(|| self.position_correlation(fa, fb, ls, scale, self.heading_m));
        for (j, col) in out.chunks_mut(a.len()).enumerate() {
            let ub = unit(b.heading(j));
            for (i, c) in col.iter_mut().enumerate() {
                let c1 = ua[i][0] * ub[0] + ua[i][1] * ub[1];
                if c1.is_nan() {
                    *c *= q[0];
                } else if let Some(coarse) = &coarse {
                    *c = q[0] * *c + cos_sum(1, c1) * coarse[j * a.len() + i];
                } else {
                    *c *= cos_sum(0, c1);
                }
            }
        }
        out
    }
}

/// Eigenfunction values of a set of points along each axis.
#[derive(Clone, Debug)]
pub struct AxisFeatures {
    n: usize,
    f: [Vec<f64>; 2],
}

/// The basis's per-axis values at a chunk of points, by the Chebyshev recurrences
/// `sin((j+1)θ) = 2 cos θ sin(jθ) − sin((j−1)θ)` (and the same for `cos`), a few flops per value
/// instead of a transcendental call: what the sub-cluster sampler evaluates for every point of
/// every sweep. Each is column-major `n x m` (a column per basis index, contiguous over the
/// points), so that products with the points as the inner dimension are matrix products.
///
/// - `sx`, `sy`: `φ_j(x) = sin((j+1) θ_x) / √L_x` (and `y`), zero outside the box, so that a
///   point's features are `φ_j(x) φ_k(y)` as [`Basis::features`] gives them (to round-off).
/// - `cx`, `cy` (with [`AxisValues::with_cosines`]): `cos(a θ)` for `a = 0..=2m`, with a point's
///   `cx` row zero unless it lies in the box: the moments from which a Gram matrix is assembled
///   (`hsgp_sums`).
#[derive(Clone, Debug, Default)]
pub struct AxisValues {
    pub n: usize,
    pub sx: Vec<f64>,
    pub sy: Vec<f64>,
    pub cx: Vec<f64>,
    pub cy: Vec<f64>,
}

impl AxisValues {
    /// The sine values of `pts`.
    pub fn new(basis: &Basis, pts: &[Point]) -> Self {
        Self::build(basis, pts, false)
    }

    /// The sine and cosine values of `pts`.
    pub fn with_cosines(basis: &Basis, pts: &[Point]) -> Self {
        Self::build(basis, pts, true)
    }

    fn build(basis: &Basis, pts: &[Point], cosines: bool) -> Self {
        let n = pts.len();
        // Per axis, cos θ and sin θ of each point (both 0 outside the box: the recurrences then
        // give zeros throughout), and whether the point is in the box on both axes.
        let mut cos1 = [vec![0.0; n], vec![0.0; n]];
        let mut sin1 = [vec![0.0; n], vec![0.0; n]];
        let mut inside = vec![1.0; n];
        for (i, p) in pts.iter().enumerate() {
            for d in 0..2 {
                let t = p[d] - basis.center[d] + basis.half[d];
                if (0.0..=2.0 * basis.half[d]).contains(&t) {
                    let (s, c) = sin_cos_0_pi(PI * t / (2.0 * basis.half[d]));
                    cos1[d][i] = c;
                    sin1[d][i] = s;
                } else {
                    inside[i] = 0.0;
                }
            }
        }
        let mut out = Self {
            n,
            sx: sines(&cos1[0], &sin1[0], basis.half[0].sqrt().recip(), basis.m[0]),
            sy: sines(&cos1[1], &sin1[1], basis.half[1].sqrt().recip(), basis.m[1]),
            ..Self::default()
        };
        if cosines {
            // A point outside the box on either axis has no features: zero cosine rows.
            out.cx = cosine_columns(&cos1[0], &inside, 2 * basis.m[0] + 1);
            out.cy = cosine_columns(&cos1[1], &inside, 2 * basis.m[1] + 1);
        }
        out
    }
}

/// `scale · sin((j+1) θ)` for `j < m`, column by column over the points (column-major `n x m`),
/// from `cos θ` and `sin θ` of each point.
fn sines(c1: &[f64], s1: &[f64], scale: f64, m: usize) -> Vec<f64> {
    let n = c1.len();
    let mut out = Vec::with_capacity(n * m);
    let mut prev = vec![0.0; n];
    let mut cur = s1.to_vec();
    for _ in 0..m {
        step(&mut out, &mut prev, &mut cur, c1, scale);
    }
    out
}

/// `mask · cos(a θ)` for `a < m`, column by column over the points, from `cos θ`.
fn cosine_columns(c1: &[f64], mask: &[f64], m: usize) -> Vec<f64> {
    let n = c1.len();
    let mut out = Vec::with_capacity(n * m);
    let mut prev: Vec<f64> = c1.iter().zip(mask).map(|(c, w)| c * w).collect(); // cos(−θ)
    let mut cur = mask.to_vec(); // cos 0
    for _ in 0..m {
        step(&mut out, &mut prev, &mut cur, c1, 1.0);
    }
    out
}

/// One step of the Chebyshev recurrence for every point: append the column `scale · cur` to
/// `out` (no zeroed buffer first), then `(prev, cur) ← (cur, 2 cos θ · cur − prev)`.
fn step(out: &mut Vec<f64>, prev: &mut [f64], cur: &mut [f64], c1: &[f64], scale: f64) {
    let n = cur.len();
    let (prev, c1) = (&mut prev[..n], &c1[..n]);
    out.extend(cur.iter().map(|c| scale * c));
    for i in 0..n {
        let next = 2.0 * c1[i] * cur[i] - prev[i];
        prev[i] = cur[i];
        cur[i] = next;
    }
}

/// `(sin θ, cos θ)` for `θ ∈ [0, π]`, to about one unit in the last place of 1 (absolute): with
/// `ψ = θ − π/2` and `h = ψ / 2 ∈ [−π/4, π/4]`, Taylor series of `sin h` and `cos h` to the
/// 17th and 16th powers (the next terms are below 1e-17 there), then `sin θ = cos ψ = 1 − 2 sin²h`
/// and `cos θ = −sin ψ = −2 sin h cos h`. Branch-free arithmetic where libm's `sin_cos` was a
/// fifth of the assignment pass.
pub fn sin_cos_0_pi(theta: f64) -> (f64, f64) {
    let h = 0.5 * (theta - 0.5 * PI);
    let h2 = h * h;
    // sin h = h (1 − h²/3! + h⁴/5! − …), cos h = 1 − h²/2! + h⁴/4! − … (Horner, from the top)
    let mut s = 1.0 / 355_687_428_096_000.0; // 1/17!
    let mut c = 1.0 / 20_922_789_888_000.0; // 1/16!
    for (sk, ck) in [
        (-1.0 / 1_307_674_368_000.0, -1.0 / 87_178_291_200.0), // 1/15!, 1/14!
        (1.0 / 6_227_020_800.0, 1.0 / 479_001_600.0),          // 1/13!, 1/12!
        (-1.0 / 39_916_800.0, -1.0 / 3_628_800.0),             // 1/11!, 1/10!
        (1.0 / 362_880.0, 1.0 / 40_320.0),                     // 1/9!, 1/8!
        (-1.0 / 5_040.0, -1.0 / 720.0),                        // 1/7!, 1/6!
        (1.0 / 120.0, 1.0 / 24.0),                             // 1/5!, 1/4!
        (-1.0 / 6.0, -1.0 / 2.0),                              // 1/3!, 1/2!
        (1.0, 1.0),
    ] {
        s = s * h2 + sk;
        c = c * h2 + ck;
    }
    let s = s * h;
    (1.0 - 2.0 * s * s, -2.0 * s * c)
}
