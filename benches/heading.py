"""Fields over position against fields over position and previous heading (issue 34), held out.

    python benches/heading.py [--only peachtree,sumo_grid,us101,lankershim,left_turn,eth,zara01] [--seeds 1] [--first-seed 0] [--iterations 20] [--average] [--thin N]

Each data set with tracks is framed by ``make_frames`` (which gives every vehicle's previous
heading; the three frame files without vehicle ids are linked by ``dpgp.link_tracks``), split in time (``dpgp.evaluate.split_in_time``), and fitted twice with the same engine,
sampler and seed, ``inputs="position"`` and ``inputs="position+heading"``. Printed per fit: the
held-out log density of the velocities given the positions per vehicle (the last state's:
``score_samples(test, positions=False)``; with ``--average`` the posterior predictive, averaged
over the kept draws after burn-in), K, the median sweep and the fit's seconds; then the
heading fit's gain per vehicle. Both fits run the collapsed sampler (the only sampler fields over
heading have so far). ``--thin N`` fits on every N-th training frame (each keeps its own previous
step) and scores every test frame: for sets whose exact fits over heading are too slow whole.

Two chains differ in their partition and noise as well as in the input, so ``--same-partition``
also scores the position fit's own state (partition, length scales, each pattern's noise, α)
with the heading input added at fixed ``w_h`` values: the input's effect alone (``w_h = 1e6``
gives the position fit's score back exactly).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import dpgp
from dpgp.evaluate import split_in_time

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def datasets(sumo_dt: float) -> dict:
    def eth_ucy(name):
        return lambda: dpgp.make_frames(dpgp.read_tracks(DATA / name, preset="eth_ucy"), dt=0.4)

    return {
        "peachtree": lambda: dpgp.make_frames(
            dpgp.read_ngsim(DATA / "ngsim_peachtree_raw.csv"), roi=(-20, 30, 0, 80), dt=0.5
        ),
        "sumo_grid": lambda: dpgp.make_frames(
            dpgp.read_tracks(DATA / "sumo_grid_intersection_fcd.xml.gz", preset="sumo"), dt=sumo_dt
        ),
        # frames without vehicle ids, linked frame to frame by their velocities (dpgp.link_tracks)
        "us101": lambda: dpgp.link_tracks(dpgp.read_frames(DATA / "ngsim_us101_frames.tsv"), length_unit="ft"),
        "lankershim": lambda: dpgp.link_tracks(
            dpgp.read_frames(DATA / "ngsim_lankershim_frames.csv"), length_unit="ft"
        ),
        "left_turn": lambda: dpgp.link_tracks(dpgp.read_frames(DATA / "sumo_left_turn_frames.csv"), length_unit="m"),
        "eth": eth_ucy("eth_ucy_biwi_eth.txt"),
        "zara01": eth_ucy("eth_ucy_crowds_zara01.txt"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="comma-separated subset of the data sets")
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--first-seed", type=int, default=0, help="seeds first-seed, first-seed + 1, ...")
    ap.add_argument("--iterations", type=int, default=20)
    ap.add_argument("--likelihood", default="exact", choices=("exact", "hsgp"))
    ap.add_argument("--sampler", default="collapsed", choices=("collapsed", "subcluster"))
    ap.add_argument(
        "--harmonics", type=int, default=None, help="heading harmonics J of hsgp's basis (default: the estimator's)"
    )
    ap.add_argument("--sumo-dt", type=float, default=2.0, help="frame step of the SUMO junction (s)")
    ap.add_argument("--thin", type=int, default=1, help="fit on every N-th training frame")
    ap.add_argument("--average", action="store_true", help="score the posterior predictive (kept draws)")
    ap.add_argument("--same-partition", action="store_true", help="also score the position fit's state over heading")
    ap.add_argument(
        "--sweep-cost", type=int, default=0, metavar="S",
        help="also time S sweeps of each input from the position fit's state (the same patterns)",
    )  # fmt: skip
    args = ap.parse_args()
    if args.harmonics is not None:
        import dpgp.model.estimator as estimator

        estimator.MAX_HEADING_HARMONICS = args.harmonics  # the cap of the estimator's rule, for this run
    for name, load in datasets(args.sumo_dt).items():
        if args.only and name not in args.only.split(","):
            continue
        train, test = split_in_time(load())
        train = train[:: args.thin]
        known = float(np.mean(~np.isnan(train.prev_heading)))
        print(f"{name}: {len(train)}/{len(test)} frames, {train.sizes.sum()}/{test.sizes.sum()} vehicles, "
              f"{known:.0%} of training vehicles with a previous heading", flush=True)  # fmt: skip
        gains: list[float] = []
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            scores = {}
            for inputs in ("position", "position+heading"):
                t0 = time.perf_counter()
                model = dpgp.DPGP(
                    iterations=args.iterations, seed=seed, progress=False, likelihood=args.likelihood,
                    sampler=args.sampler, inputs=inputs,
                ).fit(train)  # fmt: skip
                seconds = time.perf_counter() - t0
                held = model.score_samples(test, positions=False, average=args.average)
                scores[inputs] = float(held.sum() / test.sizes.sum())
                wh = getattr(model, "heading_scales_", None)
                extra = "" if wh is None else f", median w_h {np.median(wh):.2f} rad"
                print(f"  seed {seed} {inputs:17s} held-out {scores[inputs]:+.3f} nats/vehicle, K {model.n_patterns_}, "
                      f"median sweep {np.median(model.history_['seconds']):.2f} s, fit {seconds:.0f} s{extra}", flush=True)  # fmt: skip
            gains.append(scores["position+heading"] - scores["position"])
            print(f"  seed {seed} gain {gains[-1]:+.3f} nats/vehicle", flush=True)
            if args.same_partition:
                same_partition(train, test, seed, args)
            if args.sweep_cost:
                sweep_cost(train, seed, args)
        if len(gains) > 1:
            se = np.std(gains, ddof=1) / np.sqrt(len(gains))
            print(
                f"{name}: mean gain {np.mean(gains):+.3f} ± {se:.3f} (s.e.) nats/vehicle over {len(gains)} seeds",
                flush=True,
            )


def same_partition(train, test, seed: int, args) -> None:
    """The position fit's final state scored with the heading input at fixed w_h."""
    kw = dict(seed=seed, progress=False, likelihood=args.likelihood, sampler="collapsed")
    pos = dpgp.DPGP(iterations=args.iterations, **kw).fit(train)
    base = float(pos.score_samples(test, positions=False).sum() / test.sizes.sum())
    headed = dpgp.DPGP(iterations=0, inputs="position+heading", **kw).fit(train)
    noise = np.ascontiguousarray(pos.pattern_noise_var_)
    for wh in (0.3, 0.6, 1.0, 2.0, 5.0, 1e6):  # 1e6: the position field to round-off
        scales = [wh] * pos.n_patterns_
        headed._sampler.set_state(
            pos.labels_.astype(np.int64), pos.length_scales_, pos.alpha_, noise, heading_scales=scales
        )
        headed._sync()
        s = float(headed.score_samples(test, positions=False).sum() / test.sizes.sum())
        print(f"  seed {seed} position fit's state, w_h {wh}: {s:+.3f} (gain {s - base:+.3f})", flush=True)


def sweep_cost(train, seed: int, args) -> None:
    """Median seconds of a sweep (``--sampler``) with each input, both chains started from the position
    fit's final state (its partition, length scales, noise and α; ``w_h`` 1 rad): the cost of the
    input at the same number of patterns (issue 34: at most 1.5x)."""
    kw = dict(seed=seed, progress=False, likelihood=args.likelihood, sampler=args.sampler)
    pos = dpgp.DPGP(iterations=args.iterations, **kw).fit(train)
    noise = np.ascontiguousarray(pos.pattern_noise_var_)
    out = {}
    for inputs in ("position", "position+heading"):
        model = dpgp.DPGP(iterations=0, inputs=inputs, **kw).fit(train)
        wh = [1.0] * pos.n_patterns_ if inputs != "position" else None
        model._sampler.set_state(pos.labels_.astype(np.int64), pos.length_scales_, pos.alpha_, noise, heading_scales=wh)
        times = []
        for _ in range(args.sweep_cost):
            t0 = time.perf_counter()
            model._sampler.sweep()
            times.append(time.perf_counter() - t0)
        out[inputs] = float(np.median(times))
        k = len(model._sampler.patterns())
        print(
            f"  seed {seed} {inputs}: median sweep {out[inputs]:.3f} s from K {pos.n_patterns_} (K {k} after)",
            flush=True,
        )
    print(
        f"  seed {seed} sweep cost ratio heading/position: {out['position+heading'] / out['position']:.2f}", flush=True
    )


if __name__ == "__main__":
    main()
