use super::*;

#[test]
fn alpha_slice_sampler_targets_its_posterior() {
    // p(α | K=136, N=1000) has its mode near α ≈ 42 and most mass in 30–60.
    let (k, n) = (136, 1000);
    let mut x = 311f64.ln();
    let mut fx = Sampler::alpha_log_target(x, k, n);
    let mut draws = Vec::new();
    for sweep in 0..3000 {
        let mut rng = stream(9, sweep, Phase::Alpha, 0);
        (x, fx) = slice_step(x, fx, 1.0, &mut rng, |y| Sampler::alpha_log_target(y, k, n));
        draws.push(x.exp());
    }
    let mean = draws[100..].iter().sum::<f64>() / (draws.len() - 100) as f64;
    assert!(
        (35.0..55.0).contains(&mean),
        "posterior mean of alpha {mean}"
    );
}
