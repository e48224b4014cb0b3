"""Realism of generated scenarios on the shared real data (issue 15): for each data set with
tracks, split in time 70/30, fit with every default (``--iterations`` sweeps), generate as many
4 s scenarios as test frames with ``sample_scenarios`` and score them against the test period's
recorded windows (:mod:`dpgp.realism`), with the training period's own windows ("recorded") and
the position-blind generator ("blind") as references; plus rollout FDE at 1 s and 4 s of
``simulate`` from the recorded test frames against constant velocity (``model.evaluate``).
Prints one table, then the issue's targets met or missed.

    python benches/realism.py [--iterations 20] [--only peachtree,eth,zara01,sumo_junction] [--plots DIR]
                              [--inputs position,position+heading] [--heading-likelihood exact]
                              [--thin N] [--noise-ratio R] [--models DIR] [--harmonics J] [--heading-stride N] [--seed S]

``--inputs``: the fields' inputs to compare, one fit each (issue 34); a fit over heading runs the
sampler of ``--heading-sampler`` (collapsed by default; ``subcluster`` with ``--heading-likelihood
hsgp``) on ``--heading-likelihood`` (it does not choose its engine yet). ``--thin N``:
fit on every N-th training frame (each keeps its own previous step, so the model's step is the
framing's), for fits over heading too slow on every frame; scoring uses every test frame. What
generation learns from consecutive training frames (the residual's and the heading's time
constants) then falls back to its defaults: compare inputs at the same ``N``, not with ``N = 1``.
``--noise-ratio R``: a fixed noise variance of ``R`` times each velocity component's variance in
the training frames, instead of the sampled noise per pattern (issue 34's queue patterns).
``--harmonics J``: at most ``J`` heading harmonics on the reduced-rank engine (the estimator's
cap, ``MAX_HEADING_HARMONICS``, set for this run). ``--heading-stride N``: its heading blocks
on the lowest ``ceil(m / N)`` position functions per axis (``HEADING_BASIS_STRIDE``; 1: all), and
``--heading-min-count N`` at least ``N`` (``HEADING_BASIS_MIN_COUNT``).
``--models DIR`` keeps each fit as a model file there (and loads it when present), so that a
change to generation alone is compared before and after on the same fits.

Scores are WOSAC-style likelihoods (higher is better); collision rates are shares of object
steps; FDE in the data's length units (Peachtree: feet; the others: metres).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import pandas as pd

import dpgp
from dpgp.evaluate import split_in_time
from dpgp.evaluate.realism_checks import FEATURES

sys.path.insert(0, str(Path(__file__).resolve().parent))
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
COLLISION_FLOOR = 0.005  # the floor for "at most twice the recorded collision rate"


def datasets() -> dict:
    """name -> (loader returning (frames, tracks), length unit): the data sets with tracks of
    benches/evaluate.py, framed as there, and the SUMO junction."""
    from evaluate import datasets as evaluate_datasets  # benches/evaluate.py, this folder

    def sumo():
        tracks = dpgp.read_tracks(DATA / "sumo_grid_intersection_fcd.xml.gz", preset="sumo")
        return dpgp.make_frames(tracks, dt=0.5), tracks

    def linked(name, unit):
        # frame files without vehicle ids, linked frame to frame (dpgp.link_tracks); their own
        # rows, frame ids being times, are the track table realism and rollouts are scored on
        def load():
            frames = dpgp.link_tracks(dpgp.read_frames(DATA / name), length_unit=unit)
            return frames, frames.to_pandas().rename(columns={"frame": "t"})

        return load, unit

    theirs = evaluate_datasets()
    return {
        **{k: theirs[k] for k in ("peachtree", "eth", "zara01")},
        "sumo_junction": (sumo, "m"),
        # not in the default run (--only): linked frames are scored since link_tracks times them
        "us101_linked": linked("ngsim_us101_frames.tsv", "ft"),
        "lankershim_linked": linked("ngsim_lankershim_frames.csv", "ft"),
        "left_turn_linked": linked("sumo_left_turn_frames.csv", "m"),
    }


def measure(
    name: str,
    load,
    unit: str,
    iterations: int,
    plots: Path | None,
    inputs: str = "position",
    likelihood: str = "exact",
    thin: int = 1,
    noise_ratio: float | None = None,
    models: Path | None = None,
    sampler: str = "collapsed",
    seed: int = 0,
) -> dict:
    t0 = time.perf_counter()
    frames, tracks = load()
    train, test = split_in_time(frames)
    train = train[::thin]
    options: dict = {} if inputs == "position" else {"inputs": inputs, "likelihood": likelihood, "sampler": sampler}
    if noise_ratio is not None:
        sv = train.v.var(axis=0)
        options["noise_var"] = (noise_ratio * float(sv[0]), noise_ratio * float(sv[1]))
    tag = (
        f"{name}-{inputs}-{likelihood}-{iterations}-thin{thin}"
        + ("" if noise_ratio is None else f"-noise{noise_ratio:g}")
        + ("" if sampler == "collapsed" or inputs == "position" else f"-{sampler}")
        + ("" if seed == 0 else f"-seed{seed}")
    )
    kept = None if models is None else models / f"{tag}.npz"
    if kept is not None and kept.exists():
        model = dpgp.DPGP.load(kept)
    else:
        model = dpgp.DPGP(iterations=iterations, seed=seed, progress=False, **options).fit(train)
        if kept is not None:
            kept.parent.mkdir(parents=True, exist_ok=True)
            model.save(kept)
    fit_s = time.perf_counter() - t0
    ev = model.evaluate(test, tracks=tracks, horizons=(1, 4))
    r, t = ev.realism, ev.table
    row: dict = {"data": f"{name} [{inputs}]", "train/test frames": f"{len(train)}/{len(test)}", "K": model.n_patterns_}
    for f in (*FEATURES, "meta"):
        for src in ("generated", "recorded", "blind"):
            row[f"{f} [{'dpgp' if src == 'generated' else src}]"] = r.scores.loc[f, src]
    row["realism ratio"] = r.ratio
    rates = r.collision_rates
    row["collision rate dpgp"] = rates["generated"]
    row["collision rate recorded (test)"] = rates["test"]
    row["collision rate blind"] = rates["blind"]
    row["length unit"] = unit
    for h in ("1", "4"):
        row[f"FDE@{h}s dpgp"] = t.loc["dpgp", f"fde_{h}s"]
        row[f"FDE@{h}s const. velocity"] = t.loc["constant_velocity", f"fde_{h}s"]
    row["fit s"] = fit_s
    row["evaluate s"] = time.perf_counter() - t0 - fit_s
    row["seconds"] = time.perf_counter() - t0
    if plots is not None:
        plots.mkdir(parents=True, exist_ok=True)
        r.plot().savefig(plots / f"realism_{name}_{inputs.replace('+', '_')}.png", dpi=80)
    return row


def targets(row: dict, unit: str) -> list[str]:
    """The issue's 'Must show' targets, each 'met' or 'MISSED' with the figures."""
    out = []
    ratio = row["realism ratio"]
    out.append(f"realism ratio >= 0.8: {'met' if ratio >= 0.8 else 'MISSED'} ({ratio:.2f})")
    gen, rec = row["collision rate dpgp"], row["collision rate recorded (test)"]
    bound = max(2 * rec, COLLISION_FLOOR)
    out.append(
        f"collision rate <= max(2 x recorded, 0.5%): {'met' if gen <= bound else 'MISSED'} ({gen:.2%} vs bound {bound:.2%})"
    )
    f4, c4 = row["FDE@4s dpgp"], row["FDE@4s const. velocity"]
    out.append(f"FDE@4s <= constant velocity: {'met' if f4 <= c4 else 'MISSED'} ({f4:.2f} vs {c4:.2f} {unit})")
    f1, c1 = row["FDE@1s dpgp"], row["FDE@1s const. velocity"]
    out.append(
        f"FDE@1s within 10% of constant velocity: {'met' if f1 <= 1.1 * c1 else 'MISSED'} ({f1:.2f} vs {c1:.2f} {unit})"
    )
    # issue 34's targets (fields over heading)
    for f in ("turn_rate", "angular_acceleration"):
        gen, rec = row[f"{f} [dpgp]"], row[f"{f} [recorded]"]
        out.append(
            f"issue 34: {f} >= 90% of recorded: {'met' if gen >= 0.9 * rec else 'MISSED'} ({gen:.3f} vs {rec:.3f})"
        )
    out.append(f"issue 34: realism ratio >= 0.9: {'met' if ratio >= 0.9 else 'MISSED'} ({ratio:.2f})")
    out.append(
        f"issue 34: FDE@4s <= 0.8 x constant velocity: {'met' if f4 <= 0.8 * c4 else 'MISSED'} ({f4 / c4:.2f} x)"
    )
    out.append(
        f"issue 34: FDE@1s within 5% of constant velocity: {'met' if f1 <= 1.05 * c1 else 'MISSED'} ({f1 / c1:.2f} x)"
    )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=20, help="Gibbs sweeps per fit")
    ap.add_argument("--only", help="comma-separated subset of the data sets")
    ap.add_argument("--plots", type=Path, help="write each data set's realism figure (PNG) into this folder")
    ap.add_argument(
        "--inputs", default="position", help="comma-separated inputs to compare (position, position+heading)"
    )
    ap.add_argument("--heading-likelihood", default="exact", choices=("exact", "hsgp"))
    ap.add_argument(
        "--heading-sampler", default="collapsed", choices=("collapsed", "subcluster"),
        help="the sampler of fits over heading (subcluster: with --heading-likelihood hsgp)",
    )  # fmt: skip
    ap.add_argument("--thin", type=int, default=1, help="fit on every N-th training frame")
    ap.add_argument("--models", type=Path, help="folder to keep the fits in (loaded from there when present)")
    ap.add_argument("--noise-ratio", type=float, help="fixed noise variance, as a share of the velocity variance")
    ap.add_argument("--harmonics", type=int, help="cap on the heading harmonics of the reduced-rank engine")
    ap.add_argument("--seed", type=int, default=0, help="the fits' seed")
    ap.add_argument("--heading-min-count", type=int, help="... but at least N per axis (HEADING_BASIS_MIN_COUNT)")
    ap.add_argument("--heading-stride", type=int, help="the reduced-rank engine's heading blocks keep m / N functions")
    args = ap.parse_args()
    import dpgp.model.estimator as estimator

    if args.harmonics is not None:
        estimator.MAX_HEADING_HARMONICS = args.harmonics
    if args.heading_stride is not None:
        estimator.HEADING_BASIS_STRIDE = args.heading_stride
    if args.heading_min_count is not None:
        estimator.HEADING_BASIS_MIN_COUNT = args.heading_min_count
    rows, checks = [], {}
    sets = datasets()
    # the linked sets run only when named
    wanted = args.only.split(",") if args.only else [n for n in sets if not n.endswith("_linked")]
    for name, (load, unit) in sets.items():
        if name not in wanted:
            continue
        for inputs in args.inputs.split(","):
            row = measure(
                name, load, unit, args.iterations, args.plots, inputs, args.heading_likelihood,
                thin=args.thin, noise_ratio=args.noise_ratio, models=args.models, sampler=args.heading_sampler,
                seed=args.seed,
            )  # fmt: skip
            rows.append(row)
            checks[row["data"]] = targets(row, unit)
            print(f"{row['data']}: done in {row['seconds']:.0f} s", flush=True)
    table = pd.DataFrame(rows).set_index("data")
    with pd.option_context("display.width", 250, "display.max_columns", 40, "display.max_rows", 100):
        print(table.T.to_string(float_format=lambda x: f"{x:.3g}"))
    for name, lines in checks.items():
        print(f"{name}:")
        for line in lines:
            print(f"  {line}")


if __name__ == "__main__":
    main()
