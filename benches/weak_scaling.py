"""Weak scaling of one chain over shards (issue 33): the time of a sweep as workers and frames grow
together, measured on a ``LocalCluster`` of 1, 2, 4 worker processes, and a model of it for many
workers fitted to those runs.

    python benches/weak_scaling.py ROOT [--per-worker 1000000] [--workers 1,2,4] [--sweeps 5]
                                        [--shards-per-worker 2] [--model 8,16,32,64] [--cores N]

For each worker count ``W``: ``W x per-worker`` synthetic highway frames written as ``W x
shards-per-worker`` shards under ``ROOT`` (kept, reused when present), then ``benches/sharded.py
cluster`` in a process of its own (every default, seed 1): the median sweep, the time the leader
waited for its shards, the leader's own part and its split by step, the round trips and the bytes
per sweep. One JSON line per run, then the model.

**The model.** A sweep is the leader's own work, its round trips to the shards, and the shards'
compute. With one core per worker, a worker's compute a sweep is constant under weak scaling;
this machine has ``--cores`` cores (default: the machine's count), so with more workers than cores
each does its part ``W / cores`` times slower. Fitted to the runs, by non-negative least squares:

- the leader's own seconds ``leader = a + b x N`` (``N`` frames; what it computes between waiting
  for its shards);
- the rest of the median sweep, ``sweep - leader(N) = calls x latency + compute x max(1, W /
  cores)``: ``latency`` (a round trip's seconds beyond the compute) and ``compute`` (a worker's
  seconds of work a sweep); the runs past the core count tell the two apart;
- the received bytes ``bytes = c x shards``: each shard answers with its own sums;

and predicted at ``W`` workers (``N = W x per-worker``, one core each, the runs' median round
trips a sweep): ``sweep = leader(N) + calls x latency + compute``, with the bytes received and
their seconds at 1 Gbit/s beside it. The step that stops scaling first is the term that grows with
``W`` and first reaches the constant compute; the model says when the leader's own work does.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import nnls

HERE = Path(__file__).resolve().parent


def run(root: Path, workers: int, per_worker: int, shards_per_worker: int, sweeps: int) -> dict:
    directory = root / f"w{workers}_n{per_worker}_s{shards_per_worker}"
    if not (directory / "manifest.json").exists():
        root.mkdir(parents=True, exist_ok=True)
        subprocess.run(
            [sys.executable, str(HERE / "sharded.py"), "write", str(directory),
             "--frames", str(workers * per_worker), "--shards", str(workers * shards_per_worker)],
            check=True, capture_output=True, text=True,
        )  # fmt: skip
    out = subprocess.run(
        [sys.executable, str(HERE / "sharded.py"), "cluster", str(directory),
         "--sweeps", str(sweeps), "--workers", str(workers)],
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    row = json.loads(out.stdout.strip().splitlines()[-1])
    row["shards"] = workers * shards_per_worker
    return row


def model(rows: list[dict], cores: int, targets: list[int], per_worker: int) -> list[str]:
    """The fitted model (module docstring) and its predictions, as printable lines."""
    w = np.array([r["workers"] for r in rows], dtype=float)
    n = np.array([r["frames"] for r in rows], dtype=float)
    calls = np.array([r["calls_per_sweep"] for r in rows], dtype=float)
    sweep = np.array([r["median_sweep_s"] for r in rows], dtype=float)
    leader = np.array([r["leader_per_sweep_s"] for r in rows], dtype=float)
    shards = np.array([r["shards"] for r in rows], dtype=float)
    received = np.array([r["received_mb_per_sweep"] for r in rows], dtype=float)
    (a, b), _ = nnls(np.c_[np.ones_like(n), n], leader)
    rest = np.maximum(sweep - (a + b * n), 0.0)
    (latency, compute), _ = nnls(np.c_[calls, np.maximum(1.0, w / cores)], rest)
    c = float(np.sum(received * shards) / np.sum(shards * shards))
    rounds = float(np.median(calls))
    spw = float(np.median(shards / w))
    lines = [
        f"fitted: a worker's compute {compute:.2f} s a sweep; {latency * 1e3:.0f} ms a round trip "
        f"({rounds:.0f} a sweep); the leader's own work {a:.2f} s + {b * 1e6:.3f} s per million frames; "
        f"{c:.1f} MB received per shard a sweep",
        "workers  frames      sweep_s  leader_s  rounds_s  compute_s  received_MB  at_1Gbps_s",
    ]
    for t in targets:
        nn = t * per_worker
        lead, rt, mb = a + b * nn, rounds * latency, c * spw * t
        lines.append(
            f"{t:7d}  {nn:10.3g}  {lead + rt + compute:7.2f}  {lead:8.2f}  {rt:8.2f}  {compute:9.2f}  "
            f"{mb:11.0f}  {mb * 8e-3:10.2f}"
        )
    if b > 0:
        lines.append(
            f"the leader's own work reaches a worker's compute at {max(0.0, (compute - a) / b) / per_worker:.0f} "
            f"workers ({per_worker:g} frames each)"
        )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("root", type=Path)
    ap.add_argument("--per-worker", type=int, default=1_000_000)
    ap.add_argument("--workers", default="1,2,4")
    ap.add_argument("--sweeps", type=int, default=5)
    ap.add_argument("--shards-per-worker", type=int, default=2)
    ap.add_argument("--model", default="8,16,32,64", help="worker counts to predict")
    ap.add_argument("--cores", type=int, default=os.cpu_count() or 1, help="cores of this machine")
    ap.add_argument("--rows", type=Path, help="refit the model to the JSON lines of an earlier run's output")
    args = ap.parse_args()
    rows = []
    if args.rows is not None:
        rows = [json.loads(x) for x in args.rows.read_text().splitlines() if x.startswith("{")]
    else:
        for workers in (int(x) for x in args.workers.split(",")):
            rows.append(run(args.root, workers, args.per_worker, args.shards_per_worker, args.sweeps))
            print(json.dumps(rows[-1]), flush=True)
    targets = sorted({int(r["workers"]) for r in rows} | {int(x) for x in args.model.split(",")})
    for line in model(rows, args.cores, targets, args.per_worker):
        print(line)


if __name__ == "__main__":
    main()
