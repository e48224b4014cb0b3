"""Generation that respects interactions (issue 15): overlaps, rollout FDE and throughput of the
generator, for the paper's pure-field dynamics against the residual and interactive ones.

    python benches/generation.py quality [--only peachtree,eth,zara01,sumo] [--models DIR]
    python benches/generation.py throughput [--dynamics interactive|field] [--models DIR] [--reps 3]

``quality``: each shared data set with tracks is split in time (first 70% of the frames to fit
with every default, the last 30% to test). It prints, per dynamics, the realism score of
:func:`dpgp.realism.model_realism` (ratio, meta-score and every feature's score, collision
rates), the share of object-steps
with another object closer than 2 m (vehicles) or 0.3 m (pedestrians), centre to centre, in as
many generated scenarios of 4 s as there are test frames, against the recorded test frames; and
rollout FDE at 1 and 4 s from every test frame against constant velocity
(:func:`dpgp.evaluate.rollout_errors`).

``throughput``: 1,000 US-101 scenarios of 40 steps (default seed); vehicle-steps per second of
the generation call, the median of ``--reps`` calls. For a before/after ratio, run the two
versions in turn (A B A B ..., same fitted model) as whole processes, e.g. under
``/usr/bin/time -v``, and take the median ratio of the pairs:

    python benches/generation.py throughput --dynamics interactive --models /tmp/g15 --reps 2

``--models DIR`` keeps the fitted models there (fitted once, then loaded; the motion model
stored with them is learned again, so that it is the code's under test).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

import dpgp
from dpgp.data.framing import FT_TO_M
from dpgp.evaluate import rollout_errors, split_in_time
from dpgp.evaluate.realism_checks import FEATURES, model_realism
from dpgp.generate.motion import motion_model

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
DYNAMICS = ("field", "relaxed", "interactive")


def load(name: str):
    """(frames, tracks, metres per data unit, collision threshold in metres)."""
    if name == "peachtree":
        t = dpgp.read_ngsim(DATA / "ngsim_peachtree_raw.csv")
        return dpgp.make_frames(t, roi=(-20, 30, 0, 80), dt=0.5), t, FT_TO_M, 2.0
    if name in ("eth", "zara01"):
        t = dpgp.read_tracks(
            DATA / {"eth": "eth_ucy_biwi_eth.txt", "zara01": "eth_ucy_crowds_zara01.txt"}[name], preset="eth_ucy"
        )
        return dpgp.make_frames(t, dt=0.4), t, 1.0, 0.3
    if name == "sumo":
        t = dpgp.read_tracks(DATA / "sumo_grid_intersection_fcd.xml.gz", preset="sumo")
        return dpgp.make_frames(t), t, 1.0, 2.0
    if name == "us101":
        return dpgp.read_frames(DATA / "ngsim_us101_frames.tsv"), None, FT_TO_M, 2.0
    raise SystemExit(f"unknown data set {name}")


def fitted(name: str, train, models: Path | None, iterations: int | None = None) -> dpgp.DPGP:
    path = None if models is None else models / f"{name}.npz"
    if path is not None and path.exists():
        model = dpgp.DPGP.load(path)
        # the file keeps the fit; what generation learns comes from the code under test
        model.__dict__.get("_cache", {}).pop("motion", None)
        return model
    extra = {} if iterations is None else {"iterations": iterations}
    model = dpgp.DPGP(seed=0, progress=False, **extra).fit(train)
    if path is not None:
        models.mkdir(parents=True, exist_ok=True)
        model.save(path)
    return model


def overlap_share(groups, threshold: float) -> float:
    """Share of object-steps with another object of the same step closer than ``threshold``;
    ``groups``: arrays (l, 2) of the objects present at one step."""
    close = total = 0
    for xy in groups:
        if len(xy) == 0:
            continue
        total += len(xy)
        if len(xy) < 2:
            continue
        d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        close += int((d.min(axis=1) < threshold).sum())
    return close / max(total, 1)


def scenario_steps(scen):
    for sim in scen:
        for t in range(sim.steps + 1):
            yield sim.positions[t][sim.in_roi[t]]


class _Dynamics:
    """The model, its rollouts run with given dynamics (for rollout_errors)."""

    def __init__(self, model, dynamics: str) -> None:
        self._model, self._dynamics = model, dynamics

    def __getattr__(self, name):
        return getattr(self._model, name)

    def simulate(self, *args, **kwargs):
        return self._model.simulate(*args, dynamics=self._dynamics, **kwargs)

    def sample_scenarios(self, *args, **kwargs):
        return self._model.sample_scenarios(*args, dynamics=self._dynamics, **kwargs)


def quality(
    names: list[str], models: Path | None, dynamics: tuple[str, ...] = DYNAMICS, iterations: int | None = None
) -> None:
    rows = []
    for name in names:
        t0 = time.perf_counter()
        frames, tracks, metres, threshold = load(name)
        train, test = split_in_time(frames)
        model = fitted(name, train, models, iterations)
        sweeps = model.history_["seconds"]
        parts = {k: round(v, 1) for k, v in model._sampler.timings().items() if v}
        print(f"{name}: {len(sweeps)} sweeps, median {np.median(sweeps):.2f} s; seconds by part {parts}", flush=True)
        thr = threshold / metres
        steps = int(round(4.0 / model._fitted().dt))
        recorded = overlap_share((f.xy for f in test), thr)
        for dyn in dynamics:
            scen = model.sample_scenarios(len(test), steps=steps, seed=0, dynamics=dyn)
            gen = overlap_share(scenario_steps(scen), thr)
            err = rollout_errors(_Dynamics(model, dyn), test, tracks, (1.0, 4.0)).set_index("horizon")
            real = model_realism(_Dynamics(model, dyn), test, tracks, seed=0)
            scores = real.scores
            rows.append({
                "data": name, "dynamics": dyn, "realism ratio": real.ratio,
                "meta": scores.loc["meta", "generated"], "meta recorded": scores.loc["meta", "recorded"],
                "meta blind": scores.loc["meta", "blind"],
                "collisions": real.collision_rates["generated"], "collisions recorded": real.collision_rates["recorded"],
                **{f: scores.loc[f, "generated"] for f in FEATURES},
                "overlap generated": gen, "overlap recorded": recorded,
                "FDE@1s": err.loc[1.0, "dpgp_fde"], "CV FDE@1s": err.loc[1.0, "constant_velocity_fde"],
                "FDE@4s": err.loc[4.0, "dpgp_fde"], "CV FDE@4s": err.loc[4.0, "constant_velocity_fde"],
                "vehicles/scenario": float(np.mean(scen.counts)), "recorded vehicles/frame": float(np.mean(test.sizes)),
            })  # fmt: skip
        print(f"{name}: {time.perf_counter() - t0:.0f} s ({motion_model(model._fitted())})", flush=True)
        mine = pd.DataFrame([r for r in rows if r["data"] == name]).set_index("dynamics").drop(columns="data")
        print(mine.T.to_string(float_format=lambda x: f"{x:.3g}"), flush=True)
    table = pd.DataFrame(rows).set_index(["data", "dynamics"])
    with pd.option_context("display.width", 250, "display.max_columns", 40):
        print(table.T.to_string(float_format=lambda x: f"{x:.3g}"))


def throughput(dynamics: str, models: Path | None, reps: int) -> None:
    frames, *_ = load("us101")
    model = fitted("us101", frames, models)
    model.sample_scenarios(10, steps=40, seed=1, dynamics=dynamics)  # warm the caches (φ, ψ, motion)
    times, steps = [], 0
    for _ in range(reps):
        t0 = time.perf_counter()
        scen = model.sample_scenarios(1000, steps=40, seed=0, dynamics=dynamics)
        times.append(time.perf_counter() - t0)
        steps = int(scen.counts.sum()) * 40
    med = float(np.median(times))
    print(f"{dynamics}: {steps} vehicle-steps in {med:.3f} s (median of {reps}): {steps / med:,.0f} vehicle-steps/s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("quality", "throughput"))
    ap.add_argument("--only", default="peachtree,eth,zara01,sumo")
    ap.add_argument("--models", type=Path, help="directory to keep fitted models in")
    ap.add_argument("--dynamics", default="interactive", choices=DYNAMICS)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--compare", default=",".join(DYNAMICS), help="quality: the dynamics to compare")
    ap.add_argument("--iterations", type=int, help="sweeps of each fit (default: the estimator's)")
    args = ap.parse_args()
    if args.what == "quality":
        quality(args.only.split(","), args.models, tuple(args.compare.split(",")), args.iterations)
    else:
        throughput(args.dynamics, args.models, args.reps)


if __name__ == "__main__":
    main()
