//! Special functions the sampler needs that `std` does not offer on stable Rust.

/// `ln Γ(x)` for `x > 0` (Lanczos, g = 7, 9 terms; relative error ~1e-15).
pub fn ln_gamma(x: f64) -> f64 {
    const G: f64 = 7.0;
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection: Γ(x) Γ(1-x) = π / sin(πx)
        return (std::f64::consts::PI / (std::f64::consts::PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + G + 0.5;
    for (i, &c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Log density of Gamma(shape `a`, scale `b`) at `x > 0`.
pub fn ln_gamma_pdf(x: f64, a: f64, b: f64) -> f64 {
    (a - 1.0) * x.ln() - x / b - ln_gamma(a) - a * b.ln()
}

/// `log Σ exp(v)`, stable; `-inf` for an empty or all `-inf` input.
pub fn log_sum_exp(v: &[f64]) -> f64 {
    let m = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        return m;
    }
    m + v.iter().map(|x| (x - m).exp()).sum::<f64>().ln()
}

/// The regularised lower incomplete gamma function `P(a, x)`, `a > 0`: its series below
/// `x = a + 1`, one minus the continued fraction of `Q(a, x)` (modified Lentz) above.
pub fn gamma_p(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    let log_front = a * x.ln() - x - ln_gamma(a);
    if x < a + 1.0 {
        let (mut term, mut sum, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if term.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        (sum.ln() + log_front).exp().min(1.0)
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let delta = d * c;
            h *= delta;
            if (delta - 1.0).abs() < 1e-16 {
                break;
            }
        }
        (1.0 - (log_front.exp() * h)).max(0.0)
    }
}

/// The `p`-quantile of Gamma(shape `a`, scale `b`), by bisection on `P(a, x / b)`.
pub fn gamma_quantile(p: f64, a: f64, b: f64) -> f64 {
    let (mut lo, mut hi) = (0.0, a.max(1.0));
    while gamma_p(a, hi) < p {
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if gamma_p(a, mid) < p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi) * b
}

/// `I_j(z) e^{−z}` for `j = 0..=j_max`: the exponentially scaled modified Bessel functions of the
/// first kind at `z ≥ 0` (the Fourier coefficients of `exp(z (cos θ − 1))`). Miller's backward
/// recurrence `I_{j−1} = (2j / z) I_j + I_{j+1}` from an order far past where the terms vanish,
/// normalised by `I_0 + 2 Σ I_j = e^z`, so the result needs no `I_0` and cannot overflow.
pub fn bessel_ive(j_max: usize, z: f64) -> Vec<f64> {
    let mut out = vec![0.0; j_max + 1];
    if z == 0.0 {
        out[0] = 1.0;
        return out;
    }
    // I_n / I_0 ≈ exp(−n² / (2z)) for large z and (z/2)^n / n! for small: both are below 1e-20
    // past this order.
    let start = j_max + (80.0 * z).sqrt().ceil() as usize + 40;
    let (mut above, mut here) = (0.0f64, 1e-280f64);
    let mut total = 0.0f64;
    for j in (1..=start).rev() {
        if j <= j_max {
            out[j] = here;
        }
        total += 2.0 * here;
        let below = (2.0 * j as f64 / z) * here + above;
        above = here;
        here = below;
        if here > 1e250 {
            // Rescale everything kept so far; the ratios are what matters.
            let s = 1e-250;
            above *= s;
            here *= s;
            total *= s;
            out.iter_mut().for_each(|o| *o *= s);
        }
    }
    out[0] = here;
    total += here;
    out.iter_mut().for_each(|o| *o /= total);
    out
}

#[cfg(test)]
#[path = "tests/special.rs"]
mod tests;
