use super::*;
use crate::linalg::Chol;
use faer::Par;

#[test]
fn agrees_with_faer() {
    let m = 17;
    let mut a = vec![0.0; m * m];
    for j in 0..m {
        for i in 0..m {
            let d = i as f64 - j as f64;
            a[j * m + i] = (-(d * d) / 8.0).exp() + if i == j { 0.3 } else { 0.0 };
        }
    }
    let reference = Chol::factor(m, "t", Par::Seq, || a.clone()).unwrap();
    let mut l = a.clone();
    cholesky(&mut l, m).unwrap();
    for j in 0..m {
        for i in j..m {
            assert!((l[j * m + i] - reference.l[j * m + i]).abs() < 1e-13);
        }
    }
    let b: Vec<f64> = (0..2 * m).map(|i| (i as f64).sin()).collect();
    let (mut bb, mut rb) = (b.clone(), b.clone());
    solve_lower(&l, m, &mut bb);
    reference.solve_lower(&mut rb, Par::Seq);
    assert!(bb.iter().zip(&rb).all(|(x, y)| (x - y).abs() < 1e-12));
    assert!((log_det(&l, m) - reference.log_det()).abs() < 1e-12);
    assert!(cholesky(&mut [-1.0], 1).is_err());
}
