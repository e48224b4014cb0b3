use super::*;

fn naive(p: Point, q: Point, ls: LengthScales) -> f64 {
    (-(p[0] - q[0]).powi(2) / (2.0 * ls.wx * ls.wx) - (p[1] - q[1]).powi(2) / (2.0 * ls.wy * ls.wy))
        .exp()
}

#[test]
fn cross_matches_the_formula_serial_and_parallel() {
    let a: Vec<Point> = (0..700)
        .map(|i| [(i as f64 * 0.37).sin() * 30.0, i as f64 * 0.9])
        .collect();
    let b: Vec<Point> = (0..300)
        .map(|i| [(i as f64 * 0.11).cos() * 20.0, i as f64 * 1.7])
        .collect();
    let ls = LengthScales::new(4.0, 11.0).unwrap();
    let s = cross(&a, &b, ls, 2.5, false);
    let p = cross(&a, &b, ls, 2.5, true);
    assert_eq!(s, p, "parallel assembly must be bitwise identical");
    for j in 0..b.len() {
        for i in 0..a.len() {
            let want = 2.5 * naive(a[i], b[j], ls);
            assert!((s[j * a.len() + i] - want).abs() <= 1e-15 * 2.5 + 1e-300);
        }
    }
}

#[test]
fn gram_adds_noise_on_the_diagonal() {
    let a: Vec<Point> = vec![[0.0, 0.0], [1.0, 2.0], [3.0, -1.0]];
    let ls = LengthScales::new(1.5, 2.0).unwrap();
    let k = gram(&a, ls, 3.0, 0.5, false);
    assert!((k[0] - 3.5).abs() < 1e-15);
    assert!((k[1] - 3.0 * naive(a[1], a[0], ls)).abs() < 1e-15);
    assert_eq!(k[1], k[3]);
}

#[test]
fn rejects_bad_length_scales() {
    assert!(LengthScales::new(0.0, 1.0).is_err());
    assert!(LengthScales::new(1.0, -2.0).is_err());
    assert!(LengthScales::new(f64::NAN, 1.0).is_err());
}

#[test]
fn headed_cross_is_the_product_kernel_and_blind_without_a_heading_scale() {
    let a: Vec<Point> = (0..40).map(|i| [i as f64 * 0.7, (i % 5) as f64]).collect();
    let b: Vec<Point> = (0..30)
        .map(|i| [i as f64 * 0.9 - 3.0, (i % 3) as f64])
        .collect();
    let ha: Vec<f64> = (0..40)
        .map(|i| {
            if i % 7 == 0 {
                f64::NAN
            } else {
                i as f64 * 0.37
            }
        })
        .collect();
    let hb: Vec<f64> = (0..30)
        .map(|i| {
            if i % 11 == 3 {
                f64::NAN
            } else {
                -(i as f64) * 0.21
            }
        })
        .collect();
    let blind = LengthScales::new(2.0, 1.5).unwrap();
    let plain = cross(&a, &b, blind, 1.3, false);
    let (ia, ib) = (Inputs { xy: &a, h: &ha }, Inputs { xy: &b, h: &hb });
    assert_eq!(cross_headed(ia, ib, blind, 1.3, false), plain);
    let ls = blind.with_heading(0.8).unwrap();
    let q0 = crate::heading::spectrum(0.8, 0)[0];
    for parallel in [false, true] {
        let k = cross_headed(ia, ib, ls, 1.3, parallel);
        for j in 0..b.len() {
            for i in 0..a.len() {
                let d = ha[i] - hb[j];
                let per = if d.is_nan() {
                    q0
                } else {
                    (-2.0 * (d / 2.0).sin().powi(2) / 0.64).exp()
                };
                let want = plain[j * a.len() + i] * per;
                assert!((k[j * a.len() + i] - want).abs() < 1e-14, "{i} {j}");
            }
        }
    }
    // No headings at all: every one unknown.
    let none = cross_headed(Inputs::positions(&a), Inputs::positions(&b), ls, 1.3, false);
    for (x, y) in none.iter().zip(&plain) {
        assert!((x - y * q0).abs() < 1e-15);
    }
}
