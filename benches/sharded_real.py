"""Real data over shards: the shared US-101 frames and the SUMO grid junction (framed at 1 s),
written as 4 shards and fitted (every default, seed 1, 10 sweeps) in this process and on a
LocalCluster of 2 worker processes; whether the chains are the same, and each fit's seconds."""

import json
import time
from pathlib import Path

import numpy as np

import dpgp

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def main():
    sets = {
        "us101": lambda: dpgp.read_frames(DATA / "ngsim_us101_frames.tsv"),
        "sumo_grid": lambda: dpgp.make_frames(
            dpgp.read_tracks(DATA / "sumo_grid_intersection_fcd.xml.gz", preset="sumo"), dt=1.0
        ),
    }
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as lc, Client(lc) as c:
        for name, make in sets.items():
            fr = make()
            d = f"/work/shards/{name}"
            fr.to_parquet(d, shards=4, overwrite=True)
            t = time.perf_counter()
            a = dpgp.DPGP(iterations=10, seed=1, progress=False).fit(d)
            ta = time.perf_counter() - t
            t = time.perf_counter()
            b = dpgp.DPGP(iterations=10, seed=1, progress=False).fit(d, client=c)
            tb = time.perf_counter() - t
            print(
                json.dumps(
                    {
                        "data": name,
                        "frames": len(fr),
                        "shards": 4,
                        "K": int(a.n_patterns_),
                        "same_labels": bool(np.array_equal(a.labels_, b.labels_)),
                        "same_length_scales": bool(np.array_equal(a.length_scales_, b.length_scales_)),
                        "same_alpha": a.alpha_ == b.alpha_,
                        "same_log_joint": a.history_["log_joint"] == b.history_["log_joint"],
                        "process_s": round(ta, 1),
                        "cluster_s": round(tb, 1),
                    }
                ),
                flush=True,
            )


if __name__ == "__main__":
    main()
