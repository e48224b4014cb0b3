"""Two checks of issue 16 (docs/inference.md):

    python benches/inference_checks.py synthetic   # 4 chains x 30 sweeps on the synthetic intersection, 5 seeds
    python benches/inference_checks.py defaults    # cost of resolving the defaults: 50 US-101 frames x 5 sweeps

``synthetic``: ``datasets.synthetic("intersection", 200, seed=s)`` for s = 0..4; ``fit_chains(n_chains=4,
iterations=30)`` with every default; the point estimate (``Chains.point_estimate()``, VI loss)
against the true labels by adjusted Rand index, per seed.

``defaults``: a default fit (noise sampled, split–merge on) of the first 50 US-101 frames, 5 map
sweeps (the issue's setting), against the same fit with every default resolved beforehand
(noise_var and length_scale_prior given as the values the default fit started from). The cost of
resolving the defaults is the difference of the medians over --repeats runs, as a share of the fit;
the pilots (noise_var="pilot", the earlier default) are timed the same way for comparison.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import dpgp

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ngsim_us101_frames.tsv"


def synthetic(seeds: int) -> None:
    for s in range(seeds):
        frames = dpgp.datasets.synthetic("intersection", 200, seed=s)
        t = time.perf_counter()
        ch = dpgp.fit_chains(frames, n_chains=4, iterations=30, seed=s, progress=False)
        est = ch.point_estimate()
        ari = dpgp.adjusted_rand_index(est.labels, frames.labels)
        k = [int(x) for x in ch.traces["n_patterns"][:, -1]]
        print(json.dumps({"seed": s, "ari": round(float(ari), 4), "K_point": int(len(np.unique(est.labels))), "K_last": k,
                          "seconds": round(time.perf_counter() - t, 1)}), flush=True)  # fmt: skip


def defaults_cost(repeats: int) -> None:
    frames = dpgp.read_frames(DATA)[:50]
    common = dict(iterations=5, assignment="map", seed=1, progress=False)
    rows = {"default": [], "resolved": [], "pilot": [], "pilot_resolved": []}
    for _ in range(repeats):
        t = time.perf_counter()
        m = dpgp.DPGP(**common).fit(frames)
        rows["default"].append(time.perf_counter() - t)
        start = m.defaults_.noise_var  # where the chain started: "auto" resolves to this
        t = time.perf_counter()
        dpgp.DPGP(**common, noise_var=start, length_scale_prior=m.length_scale_prior_).fit(frames)
        rows["resolved"].append(time.perf_counter() - t)
        t = time.perf_counter()
        p = dpgp.DPGP(**common, noise_var="pilot").fit(frames)
        rows["pilot"].append(time.perf_counter() - t)
        t = time.perf_counter()
        dpgp.DPGP(**common, noise_var=p.noise_var_, length_scale_prior=p.length_scale_prior_).fit(frames)
        rows["pilot_resolved"].append(time.perf_counter() - t)
    from dpgp.gp import defaults

    resolve = {}
    for noise in ("auto", "pilot"):
        t = time.perf_counter()
        defaults.resolve(frames, preset=None, assignment="map", noise_var=noise, length_scale_prior="auto",
                         pilot=dpgp.DPGP(**common)._pilot_fit)  # fmt: skip
        resolve[noise] = round(time.perf_counter() - t, 4)
    print(json.dumps({"resolve_seconds": resolve, "noise_step_seconds_per_sweep": round(m.timings_["noise"] / 5, 4),
                      "split_merge_seconds_per_sweep": round(m.timings_["split_merge"] / 5, 4)}), flush=True)  # fmt: skip
    med = {k: float(np.median(v)) for k, v in rows.items()}
    print(json.dumps({
        "median_seconds": {k: round(v, 4) for k, v in med.items()},
        "defaults_share_of_fit": round((med["default"] - med["resolved"]) / med["resolved"], 3),
        "pilots_share_of_fit": round((med["pilot"] - med["pilot_resolved"]) / med["pilot_resolved"], 3),
        "sweep_seconds_default_fit": [round(x, 4) for x in m.history_["seconds"]],
    }), flush=True)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("check", choices=["synthetic", "defaults"])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    synthetic(args.seeds) if args.check == "synthetic" else defaults_cost(args.repeats)


if __name__ == "__main__":
    main()
