//! The sums against their definitions: the Gram matrix from the moments against `Σ φ φᵀ` of
//! [`Basis::features`], the vector sums against the features, the axis values by recurrence
//! against direct evaluation; the posterior's mean and covariance against the dense formula.

use super::*;
use crate::test_util::uniform;

fn points(n: usize, seed: u64) -> (Vec<Point>, Vec<[f64; 2]>) {
    let mut u = uniform(seed);
    // Some points outside the box on one axis or both: their features are zero.
    let xy = (0..n)
        .map(|_| [-4.0 + 20.0 * u(), -3.0 + 12.0 * u()])
        .collect();
    let v = (0..n).map(|_| [3.0 * u() - 1.0, u() - 0.5]).collect();
    (xy, v)
}

fn basis() -> Basis {
    Basis::new([6.0, 3.0], [8.0, 5.0], [7, 5]).unwrap()
}

/// The sums of `b` at `pts` against `Σ φ φᵀ`, `Σ φ`, `Σ φ v` of [`Basis::features_of`].
fn assert_sums_are_feature_sums(b: &Basis, pts: Inputs<'_>, v: &[[f64; 2]]) -> Sums {
    let sums = Sums::of_inputs(b, pts, v, 10);
    let m = b.len();
    let phi = b.features_of(pts);
    let mut want = vec![0.0; m * m];
    let (mut ps, mut pv) = (vec![0.0; m], vec![0.0; 2 * m]);
    for (p, col) in phi.chunks(m).enumerate() {
        for c in 0..m {
            ps[c] += col[c];
            for d in 0..2 {
                pv[d * m + c] += v[p][d] * col[c];
            }
            for r in 0..m {
                want[c * m + r] += col[r] * col[c];
            }
        }
    }
    let got = sums.gram(b);
    let scale = want.iter().fold(0.0f64, |a, x| a.max(x.abs()));
    for (g, w) in got.iter().zip(&want) {
        assert!((g - w).abs() <= 1e-11 * scale, "{g} vs {w}");
    }
    for (g, w) in sums
        .vecs
        .phi_sum
        .iter()
        .zip(&ps)
        .chain(sums.vecs.phi_v.iter().zip(&pv))
    {
        assert!((g - w).abs() <= 1e-11 * scale, "{g} vs {w}");
    }
    assert_eq!(sums.vecs.n_points, pts.len());
    assert_eq!(sums.n_frames, 10);
    sums
}

/// Headings for `n` points: every `every`-th unknown (a vehicle's first frame).
fn headings(n: usize, seed: u64, every: usize) -> Vec<f64> {
    let mut u = uniform(seed);
    (0..n)
        .map(|i| {
            let h = 7.0 * u() - 3.5;
            if i % every == 0 { f64::NAN } else { h }
        })
        .collect()
}

#[test]
fn the_gram_matrix_from_moments_is_the_sum_of_feature_outer_products() {
    let b = basis();
    let (xy, v) = points(300, 3);
    let sums = assert_sums_are_feature_sums(&b, Inputs::positions(&xy), &v);
    let vs: f64 = v.iter().map(|r| r[1]).sum();
    assert!((sums.vecs.v_sum[1] - vs).abs() < 1e-12);
}

#[test]
fn sums_add_and_subtract() {
    let b = basis();
    let (xy, v) = points(50, 5);
    let all = Sums::of_points(&b, &xy, &v, 5);
    let mut part = Sums::of_points(&b, &xy[..20], &v[..20], 2);
    part.add(&Sums::of_points(&b, &xy[20..], &v[20..], 3));
    for (a, c) in all.h.iter().zip(&part.h) {
        assert!((a - c).abs() < 1e-10);
    }
    part.sub(&Sums::of_points(&b, &xy[20..], &v[20..], 3));
    assert_eq!(part.n_frames, 2);
    assert_eq!(part.vecs.n_points, 20);
}

#[test]
fn axis_values_by_recurrence_match_the_features() {
    let b = basis();
    let (xy, _) = points(40, 8);
    let vals = AxisValues::new(&b, &xy);
    let phi = b.features(&xy);
    let [mx, my] = b.counts();
    for p in 0..xy.len() {
        for k in 0..my {
            for j in 0..mx {
                let want = phi[p * mx * my + j + mx * k];
                let got = vals.sx[j * vals.n + p] * vals.sy[k * vals.n + p];
                assert!((got - want).abs() < 1e-12, "{got} vs {want}");
            }
        }
    }
}

/// The posterior of the weights by the dense formula: precision `Λ⁻¹ + ΦᵀΦ / σ_n²`, mean
/// `Σ Φᵀ (v − μ) / σ_n²`, with `Λ = σ² diag(s)`.
#[test]
fn the_weight_posterior_matches_the_dense_formula() {
    let b = basis();
    let (xy, v) = points(60, 9);
    let params = GpParams::new((3.0, 2.5), (1.5, 0.7), (0.3, 0.2), (0.4, -0.1)).unwrap();
    let sums = Sums::of_points(&b, &xy, &v, 6);
    let post = Posterior::new(&b, &sums, &sums.gram(&b), params).unwrap();
    let mean = post.weights(None);
    let m = b.len();
    let phi = b.features(&xy);
    let s = b.sqrt_spectral(params.length_scales);
    for d in 0..2 {
        let (s2, n2) = (params.signal_var[d], params.noise_var[d]);
        let mut prec = vec![0.0; m * m];
        let mut rhs = vec![0.0; m];
        for (p, col) in phi.chunks(m).enumerate() {
            for c in 0..m {
                rhs[c] += col[c] * (v[p][d] - params.mean[d]) / n2;
                for r in 0..m {
                    prec[c * m + r] += col[r] * col[c] / n2;
                }
            }
        }
        for j in 0..m {
            prec[j * m + j] += 1.0 / (s2 * s[j] * s[j]);
        }
        // Solve prec · a = rhs by the core's dense Cholesky.
        let chol = crate::linalg::Chol::factor(m, "test", faer::Par::Seq, || prec.clone()).unwrap();
        let mut a = rhs.clone();
        crate::small::solve_lower(&chol.l, m, &mut a);
        let lt = faer::MatRef::from_column_major_slice(&chol.l, m, m);
        faer::linalg::triangular_solve::solve_upper_triangular_in_place(
            lt.transpose(),
            faer::MatMut::from_column_major_slice_mut(&mut a, m, 1),
            faer::Par::Seq,
        );
        for (g, w) in mean[d].iter().zip(&a) {
            assert!(
                (g - w).abs() < 1e-8 * (1.0 + w.abs()),
                "output {d}: {g} vs {w}"
            );
        }
    }
    // Draws: their mean and spread approach the posterior's (the first weight, 4000 draws).
    let mut rng = crate::rng::stream(1, 0, crate::rng::Phase::Predict, 0);
    let draws: Vec<f64> = (0..4000)
        .map(|_| post.weights(Some(&mut rng))[0][0])
        .collect();
    let mu = draws.iter().sum::<f64>() / 4000.0;
    let sd = (draws.iter().map(|x| (x - mu).powi(2)).sum::<f64>() / 4000.0).sqrt();
    assert!((mu - mean[0][0]).abs() < 4.0 * sd / 4000f64.sqrt() + 1e-12);
}

#[test]
fn the_log_marginal_from_sums_is_the_patterns() {
    let b = Arc::new(basis());
    let (xy, v) = points(200, 4);
    let params = GpParams::new((3.0, 2.5), (1.5, 0.7), (0.3, 0.2), (0.4, -0.1)).unwrap();
    let frames: Vec<(usize, crate::frame::FrameRef)> = (0..20)
        .map(|i| {
            (
                i,
                crate::frame::FrameRef {
                    xy: &xy[10 * i..10 * i + 10],
                    v: &v[10 * i..10 * i + 10],
                    h: &[],
                },
            )
        })
        .collect();
    let pattern = crate::hsgp::HsgpPattern::new(Arc::clone(&b), params, &frames).unwrap();
    let sums = Sums::of_points(&b, &xy, &v, 20);
    let post = Posterior::new(&b, &sums, &sums.gram(&b), params).unwrap();
    let want = pattern.log_marginal();
    assert!(
        (post.log_marginal - want).abs() < 1e-8 * want.abs(),
        "{} vs {want}",
        post.log_marginal
    );
}

/// With heading harmonics the Gram matrix is assembled from the heading-weighted moment slices
/// (product-to-sum identities): the same as `Σ φ φᵀ` of the features over position and heading,
/// with points whose heading is unknown observing only the constant heading function, and with
/// more than one block of points.
#[test]
fn the_gram_matrix_over_heading_is_the_sum_of_feature_outer_products() {
    for harmonics in [1, 2, 3] {
        let b = basis().with_harmonics(harmonics).unwrap();
        let (xy, v) = points(600, 11);
        let h = headings(600, 12, 5);
        let pts = Inputs { xy: &xy, h: &h };
        assert_sums_are_feature_sums(&b, pts, &v);
        // Every heading unknown (frames without tracks): the constant block only.
        assert_sums_are_feature_sums(&b, Inputs::positions(&xy[..40]), &v[..40]);
    }
}

/// Restricting sums over heading keeps every heading block's coarse functions.
#[test]
fn restricted_sums_over_heading_are_the_coarse_bases_sums() {
    let b = basis().with_harmonics(2).unwrap();
    let coarse = Basis::new(b.center(), b.half_widths(), [4, 3])
        .unwrap()
        .with_harmonics(2)
        .unwrap();
    assert_restriction_is_the_coarse_sums(&b, &coarse);
}

/// The sums of headed points under `b` restricted to `coarse` against `coarse`'s own sums.
fn assert_restriction_is_the_coarse_sums(b: &Basis, coarse: &Basis) {
    let (xy, v) = points(120, 6);
    let h = headings(120, 7, 4);
    let pts = Inputs { xy: &xy, h: &h };
    let direct = Sums::of_inputs(coarse, pts, &v, 4);
    let restricted = Sums::of_inputs(b, pts, &v, 4).restrict(b, coarse);
    assert_eq!(direct.h.len(), restricted.h.len());
    assert_eq!(direct.vecs.phi_v.len(), restricted.vecs.phi_v.len());
    for (a, c) in direct
        .h
        .iter()
        .zip(&restricted.h)
        .chain(direct.vecs.phi_v.iter().zip(&restricted.vecs.phi_v))
        .chain(direct.vecs.phi_sum.iter().zip(&restricted.vecs.phi_sum))
    {
        assert!((a - c).abs() < 1e-9, "{a} vs {c}");
    }
}

use std::sync::Arc;

/// The sums restricted to a coarser basis on the same box are the coarse basis's own sums, and
/// weights embedded back give the same field.
#[test]
fn restricted_sums_are_the_coarse_bases_sums() {
    let b = basis();
    let coarse = Basis::new(b.center(), b.half_widths(), [4, 3]).unwrap();
    let (xy, v) = points(120, 6);
    let direct = Sums::of_points(&coarse, &xy, &v, 4);
    let restricted = Sums::of_points(&b, &xy, &v, 4).restrict(&b, &coarse);
    for (a, c) in direct
        .h
        .iter()
        .zip(&restricted.h)
        .chain(direct.vecs.phi_v.iter().zip(&restricted.vecs.phi_v))
    {
        assert!((a - c).abs() < 1e-9, "{a} vs {c}");
    }
    assert_eq!(direct.h.len(), restricted.h.len());
    let w: Vec<f64> = (0..coarse.len()).map(|j| 0.1 * j as f64).collect();
    let full = embed(&b, &coarse, &w);
    let (fc, ff) = (coarse.features(&xy[..3]), b.features(&xy[..3]));
    for p in 0..3 {
        let a: f64 = fc[p * coarse.len()..(p + 1) * coarse.len()]
            .iter()
            .zip(&w)
            .map(|(x, y)| x * y)
            .sum();
        let c: f64 = ff[p * b.len()..(p + 1) * b.len()]
            .iter()
            .zip(&full)
            .map(|(x, y)| x * y)
            .sum();
        assert!((a - c).abs() < 1e-12);
    }
}

#[test]
fn sin_cos_on_zero_to_pi_matches_libm() {
    let mut worst: f64 = 0.0;
    for i in 0..=100_000 {
        let th = std::f64::consts::PI * i as f64 / 100_000.0;
        let (s, c) = crate::basis::sin_cos_0_pi(th);
        worst = worst.max((s - th.sin()).abs()).max((c - th.cos()).abs());
    }
    assert!(worst < 1e-15, "{worst}");
}

/// Heading blocks on fewer position functions (the lowest per axis): the Gram matrix and the
/// vector sums are still those of the basis's features, and restricting to a coarser basis keeps
/// each block's own lowest functions.
#[test]
fn sums_over_coarse_heading_blocks_are_feature_sums() {
    for (harmonics, hm) in [(1, [4, 3]), (2, [1, 1]), (3, [7, 2])] {
        let b = basis().with_heading(harmonics, hm).unwrap();
        assert_eq!(b.len(), 35 + 2 * harmonics * hm[0] * hm[1]);
        let (xy, v) = points(600, 21);
        let h = headings(600, 22, 5);
        assert_sums_are_feature_sums(&b, Inputs { xy: &xy, h: &h }, &v);
        assert_sums_are_feature_sums(&b, Inputs::positions(&xy[..40]), &v[..40]);
    }
    let b = basis().with_heading(2, [4, 3]).unwrap();
    let coarse = Basis::new(b.center(), b.half_widths(), [4, 3])
        .unwrap()
        .with_heading(2, [2, 3])
        .unwrap();
    assert_restriction_is_the_coarse_sums(&b, &coarse);
    // Heading counts past the position counts, or zero, are refused.
    assert!(basis().with_heading(1, [8, 1]).is_err());
    assert!(basis().with_heading(1, [0, 2]).is_err());
}
