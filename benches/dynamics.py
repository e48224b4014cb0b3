"""Pattern dynamics on the shared SUMO junction (issue 20, docs/dynamics.md).

Fits DPGP with every default and 20 sweeps on all frames of
``../shared/data/sumo_grid_intersection_fcd.xml.gz`` (or loads the fit saved by an earlier run),
then prints the transition figures: K, K with >= 1% of frames, the share of consecutive frames
that share a pattern, and the runs (mean, median, longest) in seconds.

    PYTHONPATH=$PWD/python nice python benches/dynamics.py [--out /tmp/sumo_none.npz]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import dpgp

DATA = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "sumo_grid_intersection_fcd.xml.gz")


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--data", default=DATA)
    p.add_argument("--out", default="sumo_none.npz", help="model file written by the fit (reused if present)")
    p.add_argument("--iterations", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args()
    if os.path.exists(a.out):
        model = dpgp.DPGP.load(a.out)
        print(f"loaded {a.out}")
    else:
        frames = dpgp.make_frames(dpgp.read_tracks(a.data, preset="sumo"))
        t = time.perf_counter()
        model = dpgp.DPGP(iterations=a.iterations, seed=a.seed, progress=False).fit(frames)
        seconds = time.perf_counter() - t
        sweeps = model.history_.get("seconds") if isinstance(model.history_, dict) else None
        print(f"fit: {len(frames)} frames, {seconds:.1f} s total")
        if sweeps is not None and len(sweeps):
            print(f"sweep time median {np.median(sweeps):.3f} s")
        model.save(a.out)
    tr = model.transitions_
    w = np.bincount(model.labels_, minlength=model.n_patterns_) / len(model.labels_)
    print(f"K = {model.n_patterns_}, K with >= 1% of frames = {int((w >= 0.01).sum())}")
    print(tr.summary())


if __name__ == "__main__":
    main()
