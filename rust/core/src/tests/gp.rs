use super::*;

#[test]
fn bad_parameters_are_errors_not_panics() {
    assert!(GpParams::new((1.0, 1.0), (1.0, 0.0), (1.0, 1.0), (0.0, 0.0)).is_err());
    assert!(GpParams::new((1.0, 1.0), (1.0, 1.0), (1.0, -1.0), (0.0, 0.0)).is_err());
    assert!(GpParams::new((1.0, 0.0), (1.0, 1.0), (1.0, 1.0), (0.0, 0.0)).is_err());
    assert!(GpParams::new((1.0, 1.0), (1.0, 1.0), (1.0, 1.0), (f64::NAN, 0.0)).is_err());
}

#[test]
fn outputs_share_a_factor_only_when_both_variances_agree() {
    let p = |s: (f64, f64), n: (f64, f64)| GpParams::new((1.0, 1.0), s, n, (0.0, 0.0)).unwrap();
    assert_eq!(p((2.0, 2.0), (0.5, 0.5)).groups().len(), 1);
    assert_eq!(p((2.0, 3.0), (0.5, 0.5)).groups().len(), 2);
    assert_eq!(p((2.0, 2.0), (0.5, 0.4)).groups().len(), 2);
}
