use super::*;

fn data(n: usize, seed: u64) -> (Vec<Point>, Vec<[f64; 2]>) {
    let mut u = crate::test_util::uniform(seed);
    let xy: Vec<Point> = (0..n).map(|_| [u() * 60.0, u() * 200.0]).collect();
    let v: Vec<[f64; 2]> = xy
        .iter()
        .map(|p| [(p[1] / 30.0).sin() + u(), 30.0 + p[0] / 10.0 + u()])
        .collect();
    (xy, v)
}

fn params(sx: f64, sy: f64) -> GpParams {
    GpParams::new((7.0, 25.0), (sx, sy), (0.8, 0.8), (0.3, 30.0)).unwrap()
}

#[test]
fn predictive_is_the_ratio_of_marginal_likelihoods() {
    let (xy, v) = data(60, 1);
    let unequal_noise = GpParams::new((7.0, 25.0), (2.0, 2.0), (0.8, 0.1), (0.3, 30.0)).unwrap();
    for p in [params(2.0, 2.0), params(1.5, 9.0), unequal_noise] {
        let all = log_marginal_likelihood(&xy, &v, &p, Par::Seq).unwrap();
        let train = log_marginal_likelihood(&xy[..45], &v[..45], &p, Par::Seq).unwrap();
        let pred = log_predictive(&xy[..45], &v[..45], &xy[45..], &v[45..], &p, Par::Seq).unwrap();
        assert!(
            (all - train - pred).abs() < 1e-9 * all.abs(),
            "{all} {train} {pred}"
        );
    }
}

#[test]
fn single_point_marginal_is_a_normal_density() {
    let p = params(1.5, 9.0);
    let got = log_marginal_likelihood(&[[1.0, 2.0]], &[[1.0, 33.0]], &p, Par::Seq).unwrap();
    let norm = |x: f64, m: f64, s2: f64| -0.5 * (LN_2PI + s2.ln() + (x - m) * (x - m) / s2);
    let want = norm(1.0, 0.3, 1.5 + 0.8) + norm(33.0, 30.0, 9.0 + 0.8);
    assert!((got - want).abs() < 1e-12);
}

#[test]
fn posterior_far_from_data_reverts_to_the_prior() {
    let (xy, v) = data(40, 2);
    let p = params(1.5, 9.0);
    let (m, s) = posterior(&xy, &v, &[[1e4, 1e4]], &p, Par::Seq).unwrap();
    assert!((m[0][0] - 0.3).abs() < 1e-12 && (m[0][1] - 30.0).abs() < 1e-12);
    assert!((s[0][0] - 1.5).abs() < 1e-12 && (s[0][1] - 9.0).abs() < 1e-12);
}

#[test]
fn bad_inputs_are_errors_not_panics() {
    let p = params(1.0, 1.0);
    assert!(matches!(
        log_marginal_likelihood(&[], &[], &p, Par::Seq),
        Err(Error::Shape(_))
    ));
    assert!(matches!(
        log_marginal_likelihood(&[[0.0, 0.0]], &[], &p, Par::Seq),
        Err(Error::Shape(_))
    ));
    assert!(matches!(
        log_marginal_likelihood(&[[f64::NAN, 0.0]], &[[0.0, 0.0]], &p, Par::Seq),
        Err(Error::InvalidInput(_))
    ));
    assert!(GpParams::new((1.0, 1.0), (1.0, 0.0), (1.0, 1.0), (0.0, 0.0)).is_err());
    assert!(GpParams::new((1.0, 1.0), (1.0, 1.0), (1.0, -1.0), (0.0, 0.0)).is_err());
}
