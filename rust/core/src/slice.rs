//! Univariate slice sampling with stepping out and shrinkage (Neal 2003).

use rand::RngExt;

/// One slice-sampling update of `x0` under the log density `f`, whose value at `x0` is `f0`.
/// Returns the new point and its log density. `f` may return `-inf` outside the support.
pub fn slice_step(
    x0: f64,
    f0: f64,
    width: f64,
    rng: &mut impl rand::Rng,
    mut f: impl FnMut(f64) -> f64,
) -> (f64, f64) {
    const MAX_STEPS_OUT: usize = 8;
    const MAX_SHRINKS: usize = 60;
    let level = f0 + rng.random::<f64>().ln();
    let mut lo = x0 - width * rng.random::<f64>();
    let mut hi = lo + width;
    for _ in 0..MAX_STEPS_OUT {
        if f(lo) <= level {
            break;
        }
        lo -= width;
    }
    for _ in 0..MAX_STEPS_OUT {
        if f(hi) <= level {
            break;
        }
        hi += width;
    }
    for _ in 0..MAX_SHRINKS {
        let x = lo + (hi - lo) * rng.random::<f64>();
        let fx = f(x);
        if fx > level {
            return (x, fx);
        }
        if x < x0 { lo = x } else { hi = x }
    }
    (x0, f0)
}

#[cfg(test)]
#[path = "tests/slice.rs"]
mod tests;
