use super::*;
use crate::linalg::Chol;

fn spd(n: usize) -> Vec<f64> {
    let mut a = vec![0.0; n * n];
    for j in 0..n {
        for i in 0..n {
            let d = i as f64 - j as f64;
            a[j * n + i] = 2.0 * (-(d * d) / 18.0).exp() + if i == j { 0.5 } else { 0.0 };
        }
    }
    a
}

fn dense_l(f: &GrowFactor) -> Vec<f64> {
    let n = f.n();
    let mut out = vec![0.0; n * n];
    for j in 0..n {
        for i in j..n {
            out[j * n + i] = f.mat()[(i, j)];
        }
    }
    out
}

fn sub(a: &[f64], n: usize, keep: &[usize]) -> Vec<f64> {
    let k = keep.len();
    let mut s = vec![0.0; k * k];
    for (jj, &j) in keep.iter().enumerate() {
        for (ii, &i) in keep.iter().enumerate() {
            s[jj * k + ii] = a[j * n + i];
        }
    }
    s
}

#[test]
fn delete_matches_a_fresh_factor() {
    let n = 40;
    let a = spd(n);
    let c = Chol::factor(n, "t", Par::Seq, || a.clone()).unwrap();
    for (p, l) in [(0, 5), (10, 7), (33, 7), (20, 1)] {
        let mut f = GrowFactor::from_dense(&c.l, n);
        assert!(f.delete(p, l));
        let keep: Vec<usize> = (0..n).filter(|i| *i < p || *i >= p + l).collect();
        let s = sub(&a, n, &keep);
        let fresh = Chol::factor(keep.len(), "t", Par::Seq, || s.clone()).unwrap();
        let got = dense_l(&f);
        for j in 0..keep.len() {
            for i in j..keep.len() {
                let (g, e) = (got[j * keep.len() + i], fresh.l[j * keep.len() + i]);
                assert!((g - e).abs() < 1e-12, "p={p} l={l} ({i},{j}): {g} vs {e}");
            }
        }
    }
}

#[test]
fn append_grows_past_capacity() {
    let n = 30;
    let a = spd(n);
    let head = sub(&a, n, &(0..10).collect::<Vec<_>>());
    let c = Chol::factor(10, "t", Par::Seq, || head.clone()).unwrap();
    let mut f = GrowFactor::from_dense(&c.l, 10);
    // Append rows 10..30 in blocks of 5 via the Schur complement, then compare.
    for start in (10..30).step_by(5) {
        let k = f.n();
        let mut v = vec![0.0; k * 5];
        for c in 0..5 {
            for i in 0..k {
                v[c * k + i] = a[(start + c) * n + i];
            }
        }
        f.solve_lower(&mut v, Par::Seq);
        let mut s = sub(&a, n, &(start..start + 5).collect::<Vec<_>>());
        for c in 0..5 {
            for r in 0..5 {
                s[c * 5 + r] -= (0..k).map(|i| v[r * k + i] * v[c * k + i]).sum::<f64>();
            }
        }
        let r = Chol::factor(5, "t", Par::Seq, || s.clone()).unwrap();
        f.append(&v, &r.l, 5);
    }
    let full = Chol::factor(n, "t", Par::Seq, || a.clone()).unwrap();
    let got = dense_l(&f);
    for j in 0..n {
        for i in j..n {
            assert!((got[j * n + i] - full.l[j * n + i]).abs() < 1e-12);
        }
    }
    assert!((f.log_det() - full.log_det()).abs() < 1e-10);
}

#[test]
fn capacity_spares_a_quarter_in_multiples_of_sixteen() {
    assert_eq!(capacity(0), 16);
    assert_eq!(capacity(16), 32);
    assert_eq!(capacity(1000), 1264);
    assert_eq!(capacity(1024), 1280);
    assert_eq!(capacity(1025), 1296);
    for n in 1..3000 {
        let c = capacity(n);
        assert!(
            c >= n && c.is_multiple_of(16) && c <= n + n / 4 + 16,
            "{n}: {c}"
        );
    }
}
