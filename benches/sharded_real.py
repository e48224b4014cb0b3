"""Real data over shards: the shared US-101 frames and the SUMO grid junction (framed at 1 s),
written as 4 shards and fitted (every default, seed 1, 10 sweeps) in this process and on a
LocalCluster of 2 worker processes; whether the chains are the same, and each fit's seconds.

    python benches/sharded_real.py [OUT_DIR]      # shards written under OUT_DIR (a temporary one)
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import dpgp

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _timed_fit(directory: str, client: object = None) -> tuple[dpgp.DPGP, float]:
    t = time.perf_counter()
    model = dpgp.DPGP(iterations=10, seed=1, progress=False).fit(directory, client=client)
    return model, time.perf_counter() - t


def main() -> None:
    from distributed import Client, LocalCluster

    out = Path(sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp())
    sets = {
        "us101": lambda: dpgp.read_frames(DATA / "ngsim_us101_frames.tsv"),
        "sumo_grid": lambda: dpgp.make_frames(
            dpgp.read_tracks(DATA / "sumo_grid_intersection_fcd.xml.gz", preset="sumo"), dt=1.0
        ),
    }
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as lc,
        Client(lc) as client,
    ):
        for name, make in sets.items():
            frames = make()
            directory = str(out / name)
            frames.to_parquet(directory, shards=4, overwrite=True)
            a, ta = _timed_fit(directory)
            b, tb = _timed_fit(directory, client)
            row = {
                "data": name, "frames": len(frames), "shards": 4, "K": int(a.n_patterns_),
                "same_labels": bool(np.array_equal(a.labels_, b.labels_)),
                "same_length_scales": bool(np.array_equal(a.length_scales_, b.length_scales_)),
                "same_alpha": a.alpha_ == b.alpha_, "same_log_joint": a.history_["log_joint"] == b.history_["log_joint"],
                "process_s": round(ta, 1), "cluster_s": round(tb, 1),
            }  # fmt: skip
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
