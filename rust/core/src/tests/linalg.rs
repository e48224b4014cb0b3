use super::*;

#[test]
fn factor_reconstructs_and_log_det() {
    let a = vec![4.0, 2.0, 2.0, 3.0];
    let c = Chol::factor(2, "test", Par::Seq, || a.clone()).unwrap();
    assert_eq!(c.jitter, 0.0);
    assert!((c.log_det() - (8.0f64).ln()).abs() < 1e-14);
    let mut b = vec![2.0, 1.0];
    c.solve_lower(&mut b, Par::Seq);
    // L = [[2, 0], [1, sqrt 2]]: L^{-1} [2, 1] = [1, 0]
    assert!((b[0] - 1.0).abs() < 1e-15 && b[1].abs() < 1e-15);
}

#[test]
fn singular_matrix_gets_jitter_and_indefinite_fails() {
    let ones = vec![1.0; 9];
    let c = Chol::factor(3, "test", Par::Seq, || ones.clone()).unwrap();
    assert!(c.jitter > 0.0);
    let neg = vec![-1.0, 0.0, 0.0, -1.0];
    let err = Chol::factor(2, "test", Par::Seq, || neg.clone()).unwrap_err();
    assert!(matches!(err, Error::NotPositiveDefinite { n: 2, .. }));
}
