use super::*;
use crate::test_util::uniform;

/// The kernel against the plain feature vectors (`Basis::features`) times the weights, on points
/// inside and outside the box, for blocks that end part-way, on both inner axes.
#[test]
fn fields_equal_features_times_weights() {
    for (m, n) in [([10, 28], 21), ([7, 3], 8), ([5, 5], 1), ([3, 9], 17)] {
        let basis = Basis::new([2.0, -1.0], [30.0, 12.0], m).unwrap();
        let mut u = uniform(7);
        let xy: Vec<Point> = (0..n)
            .map(|i| {
                let out = if i % 5 == 4 { 2.5 } else { 0.9 }; // every fifth point past the box
                [
                    2.0 + out * 30.0 * (2.0 * u() - 1.0),
                    -1.0 + out * 12.0 * (2.0 * u() - 1.0),
                ]
            })
            .collect();
        let mm = basis.len();
        let weights: Vec<Vec<f64>> = (0..5)
            .map(|_| (0..mm).map(|_| u() - 0.5).collect())
            .collect();
        let blocks = FieldBlocks::new(&basis, weights.iter().map(|w| &w[..]));
        assert_eq!(blocks.len(), 5);
        let phi = basis.features(&xy);
        let mut seen = vec![false; n];
        blocks.for_blocks(&xy, &mut |b0, vals| {
            assert_eq!(b0 % LANES, 0);
            for p in b0..(b0 + LANES).min(n) {
                seen[p] = true;
                for (w, val) in weights.iter().zip(vals) {
                    let want: f64 = phi[p * mm..(p + 1) * mm]
                        .iter()
                        .zip(w)
                        .map(|(a, b)| a * b)
                        .sum();
                    let got = val[p - b0];
                    assert!(
                        (got - want).abs() <= 1e-12 * (1.0 + want.abs()),
                        "{m:?} point {p}: {got} vs {want}"
                    );
                }
            }
        });
        assert!(seen.iter().all(|&s| s));
    }
}

/// The plain path gives the SIMD path's values bit for bit (what makes a fit's result the same on
/// every machine).
#[test]
fn plain_and_simd_paths_agree_bitwise() {
    let basis = Basis::new([0.0, 0.0], [20.0, 50.0], [9, 23]).unwrap();
    let mut u = uniform(3);
    let xy: Vec<Point> = (0..37)
        .map(|_| [40.0 * u() - 20.0, 100.0 * u() - 50.0])
        .collect();
    let weights: Vec<Vec<f64>> = (0..4)
        .map(|_| (0..basis.len()).map(|_| u() - 0.5).collect())
        .collect();
    let blocks = FieldBlocks::new(&basis, weights.iter().map(|w| &w[..]));
    let (mut a, mut b) = (Vec::new(), Vec::new());
    blocks.for_blocks(&xy, &mut |_, vals| {
        a.extend(vals.iter().flatten().map(|v| v.to_bits()))
    });
    blocks.blocks_plain(&xy, &mut |_, vals| {
        b.extend(vals.iter().flatten().map(|v| v.to_bits()))
    });
    assert_eq!(a, b);
}
