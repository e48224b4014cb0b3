//! Criterion benches of the sampler's hot paths: scoring a block of frames against a pattern (the
//! append trial, the dominant kernel) and one whole Gibbs sweep.
//!
//! `score/n` reports "elements"/s where an element is one flop of the dense algorithm
//! (per frame and output group: n² l for the triangular solve + n l² for VᵀV), i.e. GFLOP/s,
//! to be read next to the machine's dgemm rate (docs/engine.md, "What bounds the speed").

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use dpgp_core::gibbs::{Assignment, Data, Proposal, Sampler, Settings};
use dpgp_core::gp::GpParams;
use dpgp_core::kernel::Point;
use dpgp_core::pattern::{FrameRef, Pattern};
use dpgp_core::pattern_model::Likelihood;

#[path = "common.rs"]
mod common;
use common::Gen;

/// `count` highway-like frames of `l` vehicles in 4 lanes; odd frames change lanes.
fn frames(count: usize, l: usize, seed: u64) -> Vec<(Vec<Point>, Vec<[f64; 2]>)> {
    let mut g = Gen(seed);
    (0..count)
        .map(|i| {
            let xy: Vec<Point> = (0..l)
                .map(|_| {
                    [
                        6.0 + 12.0 * (g.u() * 4.0).floor() + g.u(),
                        1350.0 + 200.0 * g.u(),
                    ]
                })
                .collect();
            let v = xy
                .iter()
                .map(|p| {
                    [
                        if i % 2 == 1 { 2.0 } else { 0.0 } + 0.3 * g.u(),
                        35.0 + p[0] / 10.0 + g.u(),
                    ]
                })
                .collect();
            (xy, v)
        })
        .collect()
}

fn params() -> GpParams {
    GpParams::new((10.0, 40.0), (1.0, 30.0), (1.0, 1.0), (0.5, 38.0)).unwrap()
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("score");
    let l = 15;
    for n_frames in [10usize, 67, 200] {
        let train = frames(n_frames, l, 1);
        let members: Vec<(usize, FrameRef)> = train
            .iter()
            .enumerate()
            .map(|(i, (xy, v))| (i, FrameRef::new(xy, v)))
            .collect();
        let pattern = Pattern::new(params(), &members).unwrap();
        let test = frames(32, l, 2);
        let refs: Vec<FrameRef> = test.iter().map(|(xy, v)| FrameRef::new(xy, v)).collect();
        let n = pattern.n_points();
        g.throughput(Throughput::Elements(
            (2 * 32 * (n * n * l + n * l * l)) as u64,
        ));
        g.bench_with_input(BenchmarkId::new("n", n), &refs, |b, refs| {
            b.iter(|| black_box(pattern.score(refs).unwrap()))
        });
    }
    g.finish();

    let mut g = c.benchmark_group("sweep");
    g.sample_size(10);
    let all = frames(300, l, 3);
    let (mut xy, mut v, mut offsets) = (Vec::new(), Vec::new(), vec![0]);
    for (fx, fv) in &all {
        xy.extend_from_slice(fx);
        v.extend_from_slice(fv);
        offsets.push(xy.len());
    }
    let data = Data::new(xy, v, offsets).unwrap();
    let settings = Settings {
        assignment: Assignment::Gibbs,
        base: params(),
        fixed_length_scales: false,
        length_scale_prior: (10.0, 1.0),
        heading_prior: None,
        alpha: None,
        new_pattern_samples: 100,
        length_scale_fraction: 1.0,
        pattern_moments: false,
        seed: 0,
        likelihood: Likelihood::Exact,
        proposal: Proposal::Full,
        memory_budget: None,
        split_merge: Default::default(),
        noise_prior: None,
        noise_scope: Default::default(),
        dynamics: None,
        sampler: Default::default(),
    };
    let mut sampler = Sampler::new(data, settings).unwrap();
    sampler.sweep(&|| false).unwrap();
    g.bench_function("synthetic_300_frames", |b| {
        b.iter(|| black_box(sampler.sweep(&|| false).unwrap()))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
