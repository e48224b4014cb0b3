"""Convergence of fit_chains on NGSIM US-101 (1000 frames, every default), by sampler and start,
with and without split–merge moves, and with preset="paper" (docs/inference.md):

    python benches/convergence.py                       # dispersed starts, sub-cluster then collapsed, 600 s each
    python benches/convergence.py --runs split-merge no-split-merge
    python benches/convergence.py --runs paper          # preset="paper"
    python benches/convergence.py --seconds 120 --frames 300

Each run: ``fit_chains(frames, n_chains=4, until="converged", max_seconds=S)``. Prints, per run,
the sweeps per chain, wall seconds, split-R̂ and bulk ESS of the log joint and K (second half
of each chain, as the stopping rule), ESS per second of wall time, K and the noise pair, and
the split–merge proposals and acceptances, and the pairwise adjusted Rand index of the chains'
summary partitions (``Chains.agreement``). One JSON line per run goes to --out.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import dpgp

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ngsim_us101_frames.tsv"
RUNS = {
    "defaults": {},
    "dispersed": {"init": "dispersed"},
    "collapsed": {"sampler": "collapsed"},
    "collapsed-dispersed": {"sampler": "collapsed", "init": "dispersed"},
    "split-merge": {},
    "no-split-merge": {"split_merge": 0},
    "paper": {"preset": "paper"},
    "paper-no-split-merge": {"preset": "paper", "split_merge": 0},
    "per-pattern-noise": {"noise_var": "per_pattern"},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--seconds", type=float, default=600)
    ap.add_argument("--runs", nargs="+", default=["dispersed", "collapsed-dispersed"], choices=sorted(RUNS))
    ap.add_argument("--block", type=int, default=10)
    ap.add_argument("--out", default="convergence.jsonl")
    ap.add_argument("--traces", default=None, help="save each run's (chains, sweeps) traces to PREFIX_RUN.npz")
    args = ap.parse_args()
    frames = dpgp.read_frames(DATA)[: args.frames]
    for name in args.runs:
        t = time.perf_counter()
        ch = dpgp.fit_chains(frames, n_chains=4, until="converged", max_seconds=args.seconds, block=args.block,
                             seed=1, progress=False, **RUNS[name])  # fmt: skip
        wall = time.perf_counter() - t
        rhat, ess = ch.rhat(), ch.ess("bulk")
        agreement = ch.agreement()[np.triu_indices(ch.n_chains, 1)]
        models = ch.models
        hist = [m.history_ for m in models if hasattr(m, "history_")]
        row = {
            "run": name, "frames": len(frames), "sweeps_per_chain": int(ch.n_sweeps), "wall_seconds": round(wall, 1),
            "converged": bool(ch.converged_), "stop_reason": str(ch.stop_reason_),
            "rhat": {q: round(float(v), 3) for q, v in rhat.items()},
            "bulk_ess": {q: round(float(v), 1) for q, v in ess.items()},
            "ess_per_second": {q: round(float(ess[q]) / wall, 3) for q in ("log_joint", "n_patterns")},
            "K_last": [int(k) for k in ch.traces["n_patterns"][:, -1]],
            "median_sweep_seconds": round(float(np.median(ch.traces["seconds"])), 2),
            "sampler": [getattr(m, "sampler_", "collapsed") for m in models][0],
            "partition_ari": {"min": round(float(agreement.min()), 3), "mean": round(float(agreement.mean()), 3)},
            "noise_var": [list(map(float, m.noise_var_)) for m in models],
        }  # fmt: skip
        print(json.dumps(row), flush=True)
        if args.traces:
            np.savez(f"{args.traces}_{name}.npz", **{q: np.asarray(v) for q, v in ch.traces.items()})
        with open(args.out, "a") as f:
            f.write(json.dumps(row) + "\n")
        del hist


if __name__ == "__main__":
    main()
