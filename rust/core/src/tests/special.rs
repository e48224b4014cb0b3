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

#[test]
fn scaled_bessel_matches_scipy() {
    // scipy.special.ive(j, z) for j = 0, 1, 2, 5.
    let cases: [(f64, [f64; 4]); 7] = [
        (
            0.01,
            [
                0.990_074_585_149_707_4,
                0.004_950_311_047_118_277,
                1.237_572_605_237_790_9e-5,
                2.578_265_518_135_873_7e-14,
            ],
        ),
        (
            0.5,
            [
                0.645_035_270_449_150_1,
                0.156_420_803_184_871_67,
                0.019_352_057_709_663_28,
                4.987_605_521_470_165_5e-6,
            ],
        ),
        (
            1.0,
            [
                0.465_759_607_593_640_4,
                0.207_910_415_349_708_42,
                0.049_938_776_894_223_56,
                9.986_571_411_208_7e-5,
            ],
        ),
        (
            2.0,
            [
                0.308_508_322_553_671,
                0.215_269_289_248_937_65,
                0.093_239_033_304_733_36,
                0.001_329_761_094_188_157_8,
            ],
        ),
        (
            4.0,
            [
                0.207_001_921_223_986_64,
                0.178_750_839_502_435_3,
                0.117_626_501_472_769_03,
                0.009_244_349_173_127_098,
            ],
        ),
        (
            25.0,
            [
                0.080_196_773_547_436_65,
                0.078_576_113_319_292_76,
                0.073_910_684_481_893_3,
                0.048_225_415_779_992_176,
            ],
        ),
        (
            400.0,
            [
                0.019_953_356_281_939_99,
                0.019_928_398_958_903_543,
                0.019_853_714_287_145_47,
                0.019_338_706_488_833_99,
            ],
        ),
    ];
    for (z, want) in cases {
        let got = bessel_ive(5, z);
        for (j, w) in [0, 1, 2, 5].into_iter().zip(want) {
            assert!(
                (got[j] - w).abs() <= 1e-13 * w,
                "z={z} j={j}: {} vs {w}",
                got[j]
            );
        }
        // The Fourier series of exp(z (cos θ − 1)) at θ = 0 sums to one.
        let all = bessel_ive(400, z);
        let sum = all[0] + 2.0 * all[1..].iter().sum::<f64>();
        assert!((sum - 1.0).abs() < 1e-14, "z={z}: {sum}");
    }
    assert_eq!(bessel_ive(3, 0.0), vec![1.0, 0.0, 0.0, 0.0]);
}
