use super::*;

#[test]
fn fourier_series_rebuilds_the_periodic_kernel() {
    for wh in [0.3, 0.7, 1.0, 2.5] {
        let k = HeadingKernel::new(wh);
        let q = spectrum(wh, 200);
        for d in [0.0, 0.4, 1.0, 2.0, 3.1, -2.2] {
            let series: f64 = q
                .iter()
                .enumerate()
                .map(|(j, x)| x * (j as f64 * d).cos())
                .sum();
            let direct = (-2.0 * (d / 2.0f64).sin().powi(2) / (wh * wh)).exp();
            assert!(
                (k.eval(0.3, 0.3 - d) - direct).abs() < 1e-14,
                "wh={wh} d={d}"
            );
            assert!(
                (series - direct).abs() < 1e-13,
                "wh={wh} d={d}: {series} vs {direct}"
            );
        }
    }
}

#[test]
fn basis_functions_weighted_by_the_spectrum_give_the_truncated_kernel() {
    let (wh, harmonics) = (0.9, 3);
    let q = spectrum(wh, harmonics);
    let (mut fa, mut fb) = (vec![0.0; 7], vec![0.0; 7]);
    for (a, b) in [(0.1, 2.0), (-1.0, 1.5), (3.0, -3.0)] {
        features(a, &mut fa);
        features(b, &mut fb);
        let via_basis: f64 = (0..7).map(|c| q[harmonic_of(c)] * fa[c] * fb[c]).sum();
        let truncated: f64 = (0..=harmonics)
            .map(|j| q[j] * (j as f64 * (a - b)).cos())
            .sum();
        assert!((via_basis - truncated).abs() < 1e-14);
    }
}

#[test]
fn an_unknown_heading_sees_the_field_averaged_over_heading() {
    // (2π)⁻¹ ∫ k_h(h, b) dh = q_0² for every b: the covariance of the averaged field.
    let wh = 0.8;
    let k = HeadingKernel::new(wh);
    let n = 20_000;
    for b in [0.0, 1.3, -2.9] {
        let mean: f64 = (0..n)
            .map(|i| k.eval(2.0 * std::f64::consts::PI * i as f64 / n as f64, b))
            .sum::<f64>()
            / n as f64;
        assert!((mean - k.eval(f64::NAN, b)).abs() < 1e-12, "{mean}");
        assert_eq!(k.eval(b, f64::NAN), spectrum(wh, 0)[0]);
    }
    let mut f = vec![9.0; 5];
    features(f64::NAN, &mut f);
    assert_eq!(f, vec![1.0, 0.0, 0.0, 0.0, 0.0]);
}

#[test]
fn the_position_only_field_is_the_limit_of_infinite_heading_length_scale() {
    let k = HeadingKernel::new(f64::INFINITY);
    assert_eq!(k.eval(0.0, 3.0), 1.0);
    assert_eq!(k.eval(f64::NAN, 3.0), 1.0);
    assert_eq!(spectrum(f64::INFINITY, 2), vec![1.0, 0.0, 0.0]);
    assert_eq!(harmonics_for(f64::INFINITY), 0);
}

#[test]
fn harmonics_keep_ninety_nine_percent_of_the_variance() {
    for wh in [0.4, 0.7, 1.0, 2.0] {
        let j = harmonics_for(wh);
        let q = spectrum(wh, 200);
        let kept: f64 = q[..=j].iter().sum();
        let one_fewer: f64 = q[..j].iter().sum();
        assert!(kept >= 0.99 && one_fewer < 0.99, "wh={wh} j={j}");
    }
    // Shorter heading length scales need more harmonics.
    assert!(harmonics_for(0.4) > harmonics_for(1.0));
}
