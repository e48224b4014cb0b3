"""Held-out pattern dynamics (issue 20, docs/dynamics.md): label-sequence log-likelihood and
per-vehicle density of frame t given the frames before it, under the transitions learned by a fit
(HMM forward pass) against the independent DP. First 70% of frames to fit (defaults, 20 sweeps;
``--dynamics sticky`` for the sticky prior), the rest held out in time order.

    PYTHONPATH=$PWD/python nice python benches/dynamics_heldout.py [--only sumo,us101,eth,zara01] [--dynamics sticky]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import dpgp
from dpgp.evaluate import split_in_time
from dpgp.evaluate.sequence import sequence_scores

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def set_rho_prior(spec: str | None) -> None:
    """Experiment (issue 20): ``"a,b"`` replaces the sticky prior's Beta(1, 1) on ρ; one number
    fixes ρ (a point-mass prior). Changes the estimator module's prior for this process only."""
    if spec is None:
        return
    from dpgp.model import estimator

    parts = [float(x) for x in spec.split(",")]
    if len(parts) == 2:
        estimator.STICKINESS_PRIOR = (parts[0], parts[1])
        return
    orig = estimator._sticky_prior
    estimator._sticky_prior = lambda frames: (*orig(frames)[:2], parts[0])


def load(name: str, sumo_dt: float = 0.5) -> dpgp.Frames:
    if name == "us101":
        return dpgp.read_frames(DATA / "ngsim_us101_frames.tsv")  # frame numbers as times (dt 1 frame)
    if name in ("eth", "zara01"):
        file = {"eth": "eth_ucy_biwi_eth.txt", "zara01": "eth_ucy_crowds_zara01.txt"}[name]
        return dpgp.make_frames(dpgp.read_tracks(DATA / file, preset="eth_ucy"), dt=0.4)
    return dpgp.make_frames(dpgp.read_tracks(DATA / "sumo_grid_intersection_fcd.xml.gz", preset="sumo"), dt=sumo_dt)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", default="sumo,us101,eth,zara01")
    ap.add_argument("--iterations", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--dynamics", default=None, choices=[None, "sticky"])
    ap.add_argument("--rho", default=None, help="sticky only: 'a,b' Beta prior of ρ, or a fixed ρ")
    ap.add_argument("--frames", type=int, default=None, help="the first N frames only")
    ap.add_argument("--sumo-dt", type=float, default=0.5, help="SUMO junction's frame grid step, s")
    ap.add_argument("--phases", type=int, default=None, help="also the label sequence under this many phases")
    ap.add_argument("--models", type=Path, default=None, help="keep the fits here (<data>.npz; loaded if present)")
    a = ap.parse_args()
    set_rho_prior(a.rho)
    for name in a.only.split(","):
        frames = load(name, a.sumo_dt)
        train, test = split_in_time(frames if a.frames is None else frames[: a.frames])
        t = time.perf_counter()
        path = None if a.models is None else a.models / f"{name}.npz"
        if path is not None and path.exists():
            model = dpgp.DPGP.load(path)
            print(f"loaded {path} ({len(model.history_['log_joint'])} sweeps)", flush=True)
        else:
            model = dpgp.DPGP(iterations=a.iterations, seed=a.seed, progress=False, dynamics=a.dynamics).fit(train)
            if path is not None:
                model.save(path)
        ph = None if a.phases is None else model.phases(a.phases)
        s = sequence_scores(model, test, phases=ph)
        row = {"data": name, "dynamics": a.dynamics, "train": len(train), "iterations": a.iterations, "K": model.n_patterns_,
               "stickiness": model.stickiness_,
               "train_share_same": round(model.transitions_.share_same, 4), **s.to_dict(),
               "seconds": round(time.perf_counter() - t, 1)}  # fmt: skip
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
