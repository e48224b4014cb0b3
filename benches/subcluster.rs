//! Criterion benches of the sub-cluster sampler on 10,000 highway-like frames of 12 vehicles in
//! three patterns (three speed profiles across the road), basis 10 x 28 (M = 280, the default's
//! size on `dpgp.datasets.synthetic("highway")`):
//!
//! - `subcluster/pass`: one sweep with the hyperparameters fixed and no split–merge moves: the
//!   weights' draws, every frame's label in parallel, the moved frames' sums;
//! - `subcluster/sweep`: one sweep with every step (length scales, per-pattern noise, α, one
//!   split–merge move);
//! - `subcluster/sums`: the sums of every frame (what a state set from labels costs);
//! - `subcluster/fields`: ten fields at 12,000 points on one thread (the pass's kernel: 67 Mflop).

use std::hint::black_box;
use std::sync::Arc;

use criterion::{Criterion, criterion_group, criterion_main};
use dpgp_core::field_blocks::FieldBlocks;
use dpgp_core::gibbs::{Data, NoisePrior, NoiseScope, SamplerKind, Settings, SplitMerge};
use dpgp_core::gp::GpParams;
use dpgp_core::hsgp::Basis;
use dpgp_core::hsgp_sums::Sums;
use dpgp_core::kernel::LengthScales;
use dpgp_core::pattern_model::Likelihood;
use dpgp_core::subcluster::SubclusterSampler;

#[path = "common.rs"]
mod common;
use common::Gen;

const FRAMES: usize = 10_000;

/// Frames of three patterns (labels `i % 3`): speeds across the road that differ by pattern.
fn data() -> (Data, Vec<usize>) {
    let mut g = Gen(11);
    let (mut xy, mut v, mut offsets) = (Vec::new(), Vec::new(), vec![0]);
    for i in 0..FRAMES {
        let k = (i % 3) as f64;
        for _ in 0..12 {
            let x = 72.0 * g.u();
            xy.push([x, 1350.0 + 200.0 * g.u()]);
            v.push([0.3 * g.u(), 30.0 + (1.0 + k) * x / 10.0 + g.u()]);
        }
        offsets.push(xy.len());
    }
    (
        Data::new(xy, v, offsets).unwrap(),
        (0..FRAMES).map(|i| i % 3).collect(),
    )
}

fn settings(full: bool) -> Settings {
    let basis = Basis::new([36.0, 1450.0], [56.0, 120.0], [10, 28]).unwrap();
    Settings {
        base: GpParams::new((8.0, 8.0), (1.0, 60.0), (0.1, 2.0), (0.15, 38.0)).unwrap(),
        fixed_length_scales: !full,
        alpha: if full { None } else { Some(1.0) },
        likelihood: Likelihood::Hsgp(Arc::new(basis)),
        split_merge: SplitMerge {
            moves_per_sweep: usize::from(full),
            ..SplitMerge::default()
        },
        noise_prior: full.then_some(NoisePrior {
            log_mean: -3.0,
            sd: 2.0,
        }),
        noise_scope: if full {
            NoiseScope::PerPattern
        } else {
            NoiseScope::Global
        },
        sampler: SamplerKind::Subcluster,
        ..Settings::default()
    }
}

fn bench(c: &mut Criterion) {
    let (data, labels) = data();
    let data = Arc::new(data);
    let mut g = c.benchmark_group("subcluster");
    g.sample_size(10);
    for (name, full) in [("pass", false), ("sweep", true)] {
        let mut s = SubclusterSampler::new(Arc::clone(&data), settings(full)).unwrap();
        let ls = [LengthScales::new(8.0, 8.0).unwrap(); 3];
        s.set_state(&labels, &ls, None, 1.0).unwrap();
        s.sweep(&|| false).unwrap();
        g.bench_function(name, |b| b.iter(|| black_box(s.sweep(&|| false).unwrap())));
    }
    let basis = Basis::new([36.0, 1450.0], [56.0, 120.0], [10, 28]).unwrap();
    let (xy, v) = data.points();
    g.bench_function("sums", |b| {
        b.iter(|| black_box(Sums::of_points(&basis, xy, v, FRAMES)))
    });
    // Ten fields (five patterns' two outputs) at 12,000 points on one thread: the pass's kernel.
    let weights: Vec<Vec<f64>> = (0..10)
        .map(|f| {
            (0..basis.len())
                .map(|i| ((i * 7 + f) % 13) as f64 - 6.0)
                .collect()
        })
        .collect();
    let fields = FieldBlocks::new(&basis, weights.iter().map(|w| &w[..]));
    let pts = &xy[..12_000];
    g.bench_function("fields", |b| {
        b.iter(|| {
            let mut total = 0.0;
            fields.for_blocks(pts, &mut |_, vals| total += vals[9][0]);
            black_box(total)
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
