use super::*;

#[test]
fn matches_libm_to_a_few_ulp() {
    let mut xs: Vec<f64> = (0..200_001)
        .map(|i| -(i as f64) * 708.0 / 200_000.0)
        .collect();
    xs.extend([0.0, -1e-300, -1e-12, -0.5, -0.34657359, -700.5]);
    let ys: Vec<f64> = xs.iter().map(|&x| exp_nonpos(x)).collect();
    for (&x, &y) in xs.iter().zip(&ys) {
        let e = x.exp();
        assert!(((y - e) / e).abs() < 4e-16, "exp({x}) = {y}, libm {e}");
    }
}

#[test]
fn underflow_is_zero() {
    let v: Vec<f64> = [-709.0, -1e6, f64::MIN]
        .iter()
        .map(|&x| exp_nonpos(x))
        .collect();
    assert_eq!(v, vec![0.0, 0.0, 0.0]);
}
