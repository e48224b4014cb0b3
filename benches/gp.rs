//! Criterion benches of the exact GP layer: kernel assembly and the Cholesky log-likelihood at
//! n = 100, 1000, 4000, single-threaded (faer `Par::Seq`), so that they compare with
//! `benches/gp_numpy.py` (numpy/scipy with OpenBLAS on one thread).
//!
//! Throughput is reported as "elements"/s where one element is one floating-point operation of
//! the dense algorithm (Cholesky n³/3, two triangular solves 2n²), i.e. Gelem/s = GFLOP/s; for the
//! kernel benches an element is one kernel entry.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use dpgp_core::gp::GpParams;
use dpgp_core::kernel::{self, LengthScales, Point};
use dpgp_core::linalg;
use dpgp_core::pattern::Pattern;
use faer::Par;

fn points(n: usize) -> (Vec<Point>, Vec<[f64; 2]>) {
    let mut s = 0x9E3779B97F4A7C15u64;
    let mut u = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let xy: Vec<Point> = (0..n).map(|_| [u() * 72.0, 1350.0 + u() * 200.0]).collect();
    let v = xy
        .iter()
        .map(|p| [(p[1] / 40.0).sin(), 30.0 + p[0] / 5.0])
        .collect();
    (xy, v)
}

fn bench(c: &mut Criterion) {
    let ls = LengthScales::new(10.0, 40.0).unwrap();
    let mut g = c.benchmark_group("kernel_assembly");
    for n in [100usize, 1000, 4000] {
        let (xy, _) = points(n);
        g.throughput(Throughput::Elements((n * n) as u64));
        g.sample_size(if n >= 4000 { 10 } else { 30 });
        g.bench_with_input(BenchmarkId::new("gram", n), &xy, |b, xy| {
            b.iter(|| black_box(kernel::gram(xy, ls, 4.0, 1.0, false)))
        });
    }
    g.finish();

    let mut g = c.benchmark_group("cholesky");
    for n in [100usize, 1000, 4000] {
        let (xy, _) = points(n);
        let k = kernel::gram(&xy, ls, 4.0, 1.0, false);
        g.throughput(Throughput::Elements((n * n * n / 3) as u64));
        g.sample_size(10);
        g.bench_with_input(BenchmarkId::new("potrf", n), &k, |b, k| {
            b.iter_batched_ref(
                || k.clone(),
                |a| linalg::cholesky(a, n, Par::Seq),
                criterion::BatchSize::LargeInput,
            )
        });
    }
    g.finish();

    // Kernel + factor + 2 solves: one matrix shared by both outputs (equal signal variances).
    let mut g = c.benchmark_group("log_marginal_likelihood");
    let p = GpParams::new((10.0, 40.0), (4.0, 4.0), (1.0, 1.0), (0.0, 30.0)).unwrap();
    for n in [100usize, 1000, 4000] {
        let (xy, v) = points(n);
        g.throughput(Throughput::Elements((n * n * n / 3 + 4 * n * n) as u64));
        g.sample_size(10);
        g.bench_with_input(BenchmarkId::new("exact", n), &(xy, v), |b, (xy, v)| {
            b.iter(|| black_box(Pattern::single(p, xy, v, Par::Seq).unwrap().log_marginal()))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
