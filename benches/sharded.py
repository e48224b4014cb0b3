"""One chain over frames in shards (issue 33): identity in process and on a Dask cluster, and the
cost of a sweep on a LocalCluster of worker processes.

    python benches/sharded.py write DIR --frames 100000 --shards 4     # synthetic highway, seed 1
    python benches/sharded.py identity DIR [--sweeps 10] [--workers 2]
    python benches/sharded.py cluster DIR [--sweeps 10] [--workers 2]  # JSON: seconds, bytes, memory

``write``: ``dpgp.datasets.synthetic("highway", n, seed=1)`` (in chunks of a million frames with
seeds 1, 2, ... beyond a million, so that the generator's own memory stays small) written as
shards. ``identity``: the same directory fitted with every default (seed 1) in this process and
on ``LocalCluster(n_workers, processes=True)``; whether labels, length scales, noise, α and the
log joint history agree, and each fit's median seconds per sweep. ``cluster``: the cluster fit
alone, in a process of its own so that its peak memory is the leader's: the median and slowest
sweep, the bytes sent to and received from the workers per sweep, the leader's and each worker's
peak resident memory, K, and the ARI against the true labels stored in the shards.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np


def write(directory: str, n: int, shards: int) -> None:
    import dpgp

    t = time.perf_counter()
    if n <= 1_000_000:
        frames = dpgp.datasets.synthetic("highway", n, seed=1)
    else:
        parts = []
        for c, start in enumerate(range(0, n, 1_000_000)):
            f = dpgp.datasets.synthetic("highway", min(1_000_000, n - start), seed=1 + c)
            parts.append((np.repeat(np.arange(len(f)) + start, f.sizes), f.xy, f.v, f.labels))
        frame, xy, v, labels = (np.concatenate(x) for x in zip(*parts))
        del parts
        frames = dpgp.Frames.from_arrays(frame, xy[:, 0], xy[:, 1], v[:, 0], v[:, 1], labels=labels)
        del frame, xy, v, labels
    made = time.perf_counter() - t
    frames.to_parquet(directory, shards=shards, overwrite=True)
    print(json.dumps({"frames": len(frames), "points": int(frames.n_points), "generate_s": made,
                      "write_s": time.perf_counter() - t - made}))  # fmt: skip


def _truth(directory: str) -> np.ndarray:
    """The true labels stored in the shards (the label column alone, one value per frame)."""
    import pyarrow.parquet as pq

    from dpgp.data.shards import read_manifest

    m = read_manifest(directory)
    out = []
    for i in range(m.n_shards):
        t = pq.read_table(m.path(i), columns=["frame_number", "label"])
        number = t.column("frame_number").to_numpy()
        first = np.flatnonzero(np.r_[True, np.diff(number) != 0])
        out.append(t.column("label").take(first).to_numpy())
    return np.concatenate(out)


def _peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def cluster(directory: str, sweeps: int, workers: int) -> dict:
    from distributed import Client, LocalCluster

    import dpgp

    with (
        LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0") as lc,
        Client(lc) as client,
    ):
        import threading

        import psutil

        trace: list[tuple[float, float]] = []
        done = threading.Event()

        def watch() -> None:  # the leader's resident memory over the fit, every half second
            me = psutil.Process()
            while not done.wait(0.5):
                trace.append((time.perf_counter() - t, me.memory_info().rss / 1e9))

        t = time.perf_counter()
        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
        # The start (settings, loads, initialisation) alone, then the sweeps as its continuation:
        # the link's counts over the sweeps alone (the same chain as one fit of `sweeps` sweeps).
        m = dpgp.DPGP(iterations=0, seed=1, progress=False).fit(directory, client=client)
        start_s = time.perf_counter() - t
        link = m._shard_link
        before = (link.bytes_sent, link.bytes_received, link.requests, link.calls, link.seconds)
        t1 = time.perf_counter()
        m.set_params(iterations=sweeps)
        m.fit(directory, client=client, warm_start=True)
        sweeps_wall = time.perf_counter() - t1
        wall = time.perf_counter() - t
        done.set()
        leader_peak = _peak_gb()  # before the true labels are read here
        at, most = max(trace, key=lambda r: r[1]) if trace else (0.0, 0.0)
        worker_peak = client.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6)
        sec = np.asarray(m.history_["seconds"])
        truth = _truth(directory)
        from dpgp.evaluate.metrics import adjusted_rand_index

        return {
            "frames": len(truth), "workers": workers, "sweeps": sweeps, "wall_s": wall, "init_s": m.init_seconds_,
            "median_sweep_s": float(np.median(sec)), "max_sweep_s": float(sec.max()),
            "start_s": start_s, "sweeps_wall_s": sweeps_wall,
            "sent_mb_per_sweep": (link.bytes_sent - before[0]) / 1e6 / sweeps,
            "received_mb_per_sweep": (link.bytes_received - before[1]) / 1e6 / sweeps,
            "requests_per_sweep": (link.requests - before[2]) / sweeps, "calls_per_sweep": (link.calls - before[3]) / sweeps,
            "waiting_per_sweep_s": (link.seconds - before[4]) / sweeps,
            "leader_per_sweep_s": (sweeps_wall - (link.seconds - before[4])) / sweeps, "leader_parts_s": dict(m._sampler.timings()), "leader_peak_gb": leader_peak,
            "leader_rss_peak_at_s": at, "leader_rss_sampled_peak_gb": most,
            "sweep_s": [float(x) for x in sec],
            "worker_peak_gb": sorted(worker_peak.values()), "K": int(m.n_patterns_),
            "ari": float(adjusted_rand_index(truth, m.labels_)), "basis": m.basis_.size,
        }  # fmt: skip


def identity(directory: str, sweeps: int, workers: int) -> dict:
    from distributed import Client, LocalCluster

    import dpgp

    fits = {}
    t = time.perf_counter()
    fits["process"] = dpgp.DPGP(iterations=sweeps, seed=1, progress=False).fit(directory)
    wall = {"process": time.perf_counter() - t}
    with (
        LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0") as lc,
        Client(lc) as client,
    ):
        t = time.perf_counter()
        fits["cluster"] = dpgp.DPGP(iterations=sweeps, seed=1, progress=False).fit(directory, client=client)
        wall["cluster"] = time.perf_counter() - t
    a, b = fits["process"], fits["cluster"]
    return {
        "frames": len(a.labels_), "sweeps": sweeps, "workers": workers,
        "same_labels": bool(np.array_equal(a.labels_, b.labels_)),
        "same_length_scales": bool(np.array_equal(a.length_scales_, b.length_scales_)),
        "same_noise": bool(np.array_equal(a.noise_var_, b.noise_var_)), "same_alpha": a.alpha_ == b.alpha_,
        "same_log_joint": a.history_["log_joint"] == b.history_["log_joint"], "K": int(a.n_patterns_),
        "process_median_sweep_s": float(np.median(a.history_["seconds"])),
        "cluster_median_sweep_s": float(np.median(b.history_["seconds"])), "wall_s": wall,
    }  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    w = sub.add_parser("write")
    w.add_argument("directory")
    w.add_argument("--frames", type=int, default=100_000)
    w.add_argument("--shards", type=int, default=4)
    for name in ("identity", "cluster", "cluster-here"):
        c = sub.add_parser(name)
        c.add_argument("directory")
        c.add_argument("--sweeps", type=int, default=10)
        c.add_argument("--workers", type=int, default=2)
    a = p.parse_args()
    if a.cmd == "write":
        write(a.directory, a.frames, a.shards)
    elif a.cmd == "identity":
        print(json.dumps(identity(a.directory, a.sweeps, a.workers)))
    elif a.cmd == "cluster-here":
        print(json.dumps(cluster(a.directory, a.sweeps, a.workers)))
    else:  # a process of its own: its peak memory is the leader's
        args = [sys.executable, __file__, "cluster-here", a.directory, "--sweeps", str(a.sweeps)]
        out = subprocess.run([*args, "--workers", str(a.workers)], capture_output=True, text=True, check=True)
        print(out.stdout.strip().splitlines()[-1])


if __name__ == "__main__":
    main()
