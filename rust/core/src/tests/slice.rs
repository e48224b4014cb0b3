use super::*;
use crate::rng::{Phase, stream};

#[test]
fn samples_a_standard_normal() {
    let mut rng = stream(1, 0, Phase::Alpha, 0);
    let f = |x: f64| -0.5 * x * x;
    let (mut x, mut fx) = (3.0, f(3.0));
    let mut xs = Vec::new();
    for _ in 0..40_000 {
        (x, fx) = slice_step(x, fx, 1.0, &mut rng, f);
        xs.push(x);
    }
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let var = xs.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    assert!(mean.abs() < 0.05, "mean {mean}");
    assert!((var - 1.0).abs() < 0.05, "var {var}");
}
