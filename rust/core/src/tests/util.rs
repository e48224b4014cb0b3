//! Test data shared by the pattern tests: random frames of 2-7 vehicles on a 30 x 100 area; the
//! total variation between a chain's partition frequencies and the exact posterior.

use std::collections::HashMap;

use crate::kernel::Point;
use crate::pattern::FrameRef;

/// A deterministic stream of uniforms in [0, 1) (a 64-bit LCG's top 53 bits): test data
/// that needs no random-number crate and is the same on every platform.
pub fn uniform(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    }
}

pub fn frames(seed: u64, count: usize) -> Vec<(Vec<Point>, Vec<[f64; 2]>)> {
    let mut u = uniform(seed);
    (0..count)
        .map(|_| {
            let l = 2 + (u() * 6.0) as usize;
            let xy: Vec<Point> = (0..l).map(|_| [u() * 30.0, u() * 100.0]).collect();
            let v = xy
                .iter()
                .map(|p| [(p[1] / 20.0).sin() + u(), 20.0 + p[0] / 5.0 + u()])
                .collect();
            (xy, v)
        })
        .collect()
}

pub fn refs(fs: &[(Vec<Point>, Vec<[f64; 2]>)]) -> Vec<FrameRef<'_>> {
    fs.iter().map(|(xy, v)| FrameRef::new(xy, v)).collect()
}

/// Total variation between partition frequencies and the exact posterior over partitions.
/// Previous headings of every point of `fs`: `NaN` where `(i + k) % nan_every == 0` (point `i`
/// of frame `k`), else `angle(i, k)`.
pub fn headings(
    fs: &[(Vec<Point>, Vec<[f64; 2]>)],
    nan_every: usize,
    angle: impl Fn(usize, usize) -> f64,
) -> Vec<Vec<f64>> {
    (fs.iter().enumerate())
        .map(|(k, f)| {
            (0..f.0.len())
                .map(|i| {
                    if (i + k) % nan_every == 0 {
                        f64::NAN
                    } else {
                        angle(i, k)
                    }
                })
                .collect()
        })
        .collect()
}

/// [`refs`] with the previous headings `hs` (one vector per frame).
pub fn refs_with<'a>(
    fs: &'a [(Vec<Point>, Vec<[f64; 2]>)],
    hs: &'a [Vec<f64>],
) -> Vec<FrameRef<'a>> {
    (fs.iter().zip(hs))
        .map(|(f, h)| FrameRef {
            xy: &f.0,
            v: &f.1,
            h,
        })
        .collect()
}

pub fn tv(freq: &HashMap<Vec<usize>, f64>, exact: &HashMap<Vec<usize>, f64>) -> f64 {
    0.5 * exact
        .iter()
        .map(|(p, e)| (freq.get(p).copied().unwrap_or(0.0) - e).abs())
        .sum::<f64>()
}
