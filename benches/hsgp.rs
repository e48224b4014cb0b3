//! Criterion benches of the reduced-rank (HSGP) kernels: a pattern's statistics make every
//! operation cost the same whatever the pattern's size, so each is timed at one size (1,000
//! frames of 15 vehicles) for several basis sizes M.
//!
//! - `hsgp_score/M`: one frame against a pattern (M² l flops per output group);
//! - `hsgp_move/M`: insert then remove a frame (two rank-l updates of each group's factor);
//! - `hsgp_length_scales/M`: one length-scale evaluation (an M x M factorisation per group);
//! - `cheap_score`: the informed proposal's cell score of one frame against one pattern.

use std::hint::black_box;
use std::sync::Arc;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use dpgp_core::gp::GpParams;
use dpgp_core::hsgp::{Basis, HsgpPattern};
use dpgp_core::kernel::{LengthScales, Point};
use dpgp_core::pattern::FrameRef;
use dpgp_core::proposal::{CellGrid, CellStats};

#[path = "common.rs"]
mod common;
use common::Gen;

/// `count` highway-like frames of `l` vehicles on a 72 x 200 ROI.
fn frames(count: usize, l: usize) -> Vec<(Vec<Point>, Vec<[f64; 2]>)> {
    let mut g = Gen(7);
    (0..count)
        .map(|_| {
            let xy: Vec<Point> = (0..l)
                .map(|_| {
                    [
                        6.0 + 12.0 * (g.u() * 6.0).floor() + g.u(),
                        1350.0 + 200.0 * g.u(),
                    ]
                })
                .collect();
            let v = xy
                .iter()
                .map(|p| [0.3 * g.u(), 35.0 + p[0] / 10.0 + g.u()])
                .collect();
            (xy, v)
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let fs = frames(1001, 15);
    let refs: Vec<FrameRef> = fs.iter().map(|(xy, v)| FrameRef::new(xy, v)).collect();
    let members: Vec<(usize, FrameRef)> = (0..1000).map(|i| (i, refs[i])).collect();
    let p = GpParams::new((10.0, 10.0), (1.0, 30.0), (1.0, 1.0), (0.5, 38.0)).unwrap();
    let mut score = c.benchmark_group("hsgp_score");
    let sizes = [(10, 20), (20, 30), (21, 45)];
    let patterns: Vec<HsgpPattern> = sizes
        .iter()
        .map(|&(mx, my)| {
            let b = Basis::new([36.0, 1450.0], [56.0, 120.0], [mx, my]).unwrap();
            HsgpPattern::new(Arc::new(b), p, &members).unwrap()
        })
        .collect();
    for ((mx, my), pat) in sizes.iter().zip(&patterns) {
        score.bench_with_input(BenchmarkId::from_parameter(mx * my), pat, |b, pat| {
            b.iter(|| black_box(pat.score(&refs[1000..]).unwrap()))
        });
    }
    score.finish();
    let mut moves = c.benchmark_group("hsgp_move");
    for ((mx, my), pat) in sizes.iter().zip(&patterns) {
        let mut pat = pat.clone();
        moves.bench_function(BenchmarkId::from_parameter(mx * my), |b| {
            b.iter(|| {
                pat.insert(1000, refs[1000]).unwrap();
                black_box(pat.remove(1000).unwrap())
            })
        });
    }
    moves.finish();
    let mut ls = c.benchmark_group("hsgp_length_scales");
    ls.sample_size(10);
    for ((mx, my), pat) in sizes.iter().zip(&patterns) {
        let q = p.with_length_scales(LengthScales::new(12.0, 9.0).unwrap());
        ls.bench_with_input(BenchmarkId::from_parameter(mx * my), pat, |b, pat| {
            b.iter(|| black_box(pat.with_params(q).unwrap().log_marginal()))
        });
    }
    ls.finish();
    let all: Vec<Point> = fs.iter().flat_map(|f| f.0.iter().copied()).collect();
    let grid = Arc::new(CellGrid::new(&all, [5.0, 5.0]));
    let mut cells = CellStats::new(Arc::clone(&grid));
    for f in &refs[..1000] {
        cells.add(*f, 1.0);
    }
    let idx = grid.cells(refs[1000].xy);
    c.bench_function("cheap_score", |b| {
        b.iter(|| black_box(cells.score(refs[1000], &idx, false, &p)))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
