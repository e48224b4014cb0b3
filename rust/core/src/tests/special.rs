use super::*;

#[test]
fn ln_gamma_known_values() {
    // ln Γ(n) = ln (n-1)!, ln Γ(1/2) = ln √π, and a value from tables.
    let mut fact = 1.0f64;
    for n in 1..30 {
        assert!(
            (ln_gamma(n as f64) - fact.ln()).abs() < 1e-12 * fact.ln().abs().max(1.0),
            "n={n}"
        );
        fact *= n as f64;
    }
    assert!((ln_gamma(0.5) - std::f64::consts::PI.sqrt().ln()).abs() < 1e-14);
    assert!((ln_gamma(0.1) - 2.252_712_651_734_206).abs() < 1e-13);
    // Reference values from scipy.special.gammaln.
    assert!((ln_gamma(1000.5) - 5_908.674_175_848_678).abs() < 1e-12 * 5_908.7);
}

#[test]
fn log_sum_exp_is_stable() {
    assert!((log_sum_exp(&[1000.0, 1000.0]) - (1000.0 + 2f64.ln())).abs() < 1e-12);
    assert_eq!(log_sum_exp(&[f64::NEG_INFINITY]), f64::NEG_INFINITY);
}

#[test]
fn gamma_quantiles_match_known_values() {
    // scipy.stats.gamma(a, scale=b).ppf(p)
    for (p, a, b, want) in [
        (0.05, 10.0, 1.0, 5.425_405_697_091_295),
        (0.5, 10.0, 1.0, 9.668_714_614_714_128),
        (0.95, 2.0, 3.0, 14.231_593_555_171_731),
        (0.01, 0.5, 2.0, 0.000_157_087_857_909_701_84),
    ] {
        let got = gamma_quantile(p, a, b);
        assert!(
            (got - want).abs() < 1e-9 * want,
            "{p} {a} {b}: {got} vs {want}"
        );
    }
}
