"""Time the exact GP layer's calls as a user makes them (``dpgp.gp`` and the single-GP baseline).

    python benches/gp_layer.py [N] [REPEAT] [CALL]

N training points (default 2000) on a highway-like ROI: ``log_marginal_likelihood``,
``log_predictive`` of 300 test points, ``posterior`` at 5,000 queries, and ``SingleGP``'s scores
of 200 frames of 12 vehicles; each REPEAT times (default 3), or only the calls whose name starts
with CALL. Prints the median seconds per call.
Compare two builds by running it under each (``PYTHONPATH=.../python``) in one session.
"""

from __future__ import annotations

import sys
import time

import numpy as np

import dpgp
from dpgp.evaluate import SingleGP


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 2000
    repeat = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    rng = np.random.default_rng(0)
    m = n + 300 + 200 * 12
    xy = np.column_stack([rng.uniform(0, 72, m), rng.uniform(0, 400, m)])
    v = np.column_stack([np.sin(xy[:, 1] / 40) + rng.normal(0, 0.5, m), 40 + xy[:, 0] / 6 + rng.normal(0, 1, m)])
    p = dpgp.GPParams((10.0, 40.0), (0.5, 4.0), (0.3, 1.0), (0.0, 40.0))
    tr, te, fr = slice(0, n), slice(n, n + 300), slice(n + 300, m)
    q = rng.uniform([0, 0], [72, 400], size=(5000, 2))
    offsets = np.arange(0, 200 * 12 + 1, 12)
    frames = dpgp.Frames(np.arange(200), offsets, xy[fr], v[fr])
    single = SingleGP(p, xy[tr], v[tr])
    calls = {
        "log_marginal_likelihood": lambda: dpgp.gp.log_marginal_likelihood(xy[tr], v[tr], p),
        "log_predictive(300)": lambda: dpgp.gp.log_predictive(xy[tr], v[tr], xy[te], v[te], p),
        "posterior(5000)": lambda: dpgp.gp.posterior(xy[tr], v[tr], q, p),
        "SingleGP.score_frames(200)": lambda: single.score_frames(frames),
    }
    only = sys.argv[3] if len(sys.argv) > 3 else ""
    for name, call in calls.items():
        if not name.startswith(only):
            continue
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            call()
            times.append(time.perf_counter() - t0)
        print(f"{name:28s} n={n:5d}  median {np.median(times):.4f} s")


if __name__ == "__main__":
    main()
