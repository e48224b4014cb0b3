"""The numpy/scipy baseline for benches/gp.rs: the same work on one OpenBLAS thread.

    OPENBLAS_NUM_THREADS=1 python benches/gp_numpy.py

Prints median seconds and GFLOP/s (Cholesky n³/3; log-likelihood n³/3 + 4n²) for kernel
assembly, scipy.linalg.cho_factor, and cho_factor + solve, at n = 100, 1000, 4000.
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.linalg import cho_factor, solve_triangular  # noqa: E402


def median_time(fn, repeat: int) -> float:
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def gram(xy, wx=10.0, wy=40.0, s2=4.0, sn2=1.0):
    dx = xy[:, None, 0] - xy[None, :, 0]
    dy = xy[:, None, 1] - xy[None, :, 1]
    k = s2 * np.exp(-(dx**2) / (2 * wx**2) - dy**2 / (2 * wy**2))
    k[np.diag_indices_from(k)] += sn2
    return k


def lml(xy, v):
    c, _ = cho_factor(gram(xy), lower=True, check_finite=False)
    z = solve_triangular(c, v - np.array([0.0, 30.0]), lower=True, check_finite=False)
    return -0.5 * np.sum(z**2) - 2 * np.sum(np.log(np.diag(c))) - len(xy) * np.log(2 * np.pi)


def main() -> None:
    rng = np.random.default_rng(0)
    print(f"{'n':>5} {'kernel ms':>10} {'Gentry/s':>9} {'chol ms':>9} {'GFLOP/s':>8} {'lml ms':>9} {'GFLOP/s':>8}")
    for n in (100, 1000, 4000):
        xy = np.column_stack([rng.uniform(0, 72, n), rng.uniform(1350, 1550, n)])
        v = np.column_stack([np.sin(xy[:, 1] / 40), 30 + xy[:, 0] / 5])
        rep = 30 if n < 4000 else 7
        tk = median_time(lambda: gram(xy), rep)
        k = gram(xy)
        tc = median_time(lambda: cho_factor(k, lower=True, check_finite=False), rep)
        tl = median_time(lambda: lml(xy, v), rep)
        f_chol, f_lml = n**3 / 3, n**3 / 3 + 4 * n**2
        print(
            f"{n:>5} {tk * 1e3:>10.3f} {n * n / tk / 1e9:>9.3f} {tc * 1e3:>9.3f} {f_chol / tc / 1e9:>8.2f} {tl * 1e3:>9.3f} {f_lml / tl / 1e9:>8.2f}"
        )


if __name__ == "__main__":
    main()
