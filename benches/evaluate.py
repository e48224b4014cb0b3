"""Held-out evaluation of dpgp on the shared real data (issue 9): for each data set, fit on the
first 70% of the frames (a split in time) with the default settings and score the last 30%
against a single GP and a position-blind Gaussian; where raw tracks exist, rollout ADE/FDE at
1, 2 and 4 s against constant velocity. Prints one table.

    python benches/evaluate.py [--iterations 20] [--only us101,peachtree,...]

Log densities are nats per test vehicle (higher is better); ADE/FDE are in the data's length
units (NGSIM: feet; ETH/UCY: metres).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import pandas as pd

import dpgp
from dpgp.evaluate import split_in_time

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def datasets() -> dict:
    """name -> (loader returning (frames, tracks or None), length unit)."""

    def frames_file(name):
        return lambda: (dpgp.read_frames(DATA / name), None)

    def peachtree():
        tracks = dpgp.read_ngsim(DATA / "ngsim_peachtree_raw.csv")
        return dpgp.make_frames(tracks, roi=(-20, 30, 0, 80), dt=0.5), tracks

    def eth_ucy(name):
        def load():
            tracks = dpgp.read_tracks(DATA / name, preset="eth_ucy")
            return dpgp.make_frames(tracks, dt=0.4), tracks

        return load

    def sumo_grid():
        tracks = dpgp.read_tracks(DATA / "sumo_grid_intersection_fcd.xml.gz", preset="sumo")
        return dpgp.make_frames(tracks, dt=1.0), tracks

    return {
        "us101": (frames_file("ngsim_us101_frames.tsv"), "ft"),
        "peachtree": (peachtree, "ft"),
        "eth": (eth_ucy("eth_ucy_biwi_eth.txt"), "m"),
        "zara01": (eth_ucy("eth_ucy_crowds_zara01.txt"), "m"),
        "sumo_left_turn": (frames_file("sumo_left_turn_frames.csv"), "m"),
        "lankershim": (frames_file("ngsim_lankershim_frames.csv"), "ft"),
        "sumo_grid": (sumo_grid, "m"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=20, help="Gibbs sweeps per fit")
    ap.add_argument("--only", help="comma-separated subset of the data sets")
    ap.add_argument("--preset", choices=("paper",), help="fit with the paper's settings instead of the defaults")
    args = ap.parse_args()
    rows = []
    for name, (load, unit) in datasets().items():
        if args.only and name not in args.only.split(","):
            continue
        t0 = time.perf_counter()
        frames, tracks = load()
        train, test = split_in_time(frames)
        model = dpgp.DPGP(iterations=args.iterations, seed=0, progress=False, preset=args.preset).fit(train)
        ev = model.evaluate(test, tracks=tracks)
        t = ev.table
        row = {
            "data": name,
            "train/test frames": f"{len(train)}/{len(test)}",
            "K": model.n_patterns_,
            "noise_var_": model.noise_var_,
            "prior mean w": model.length_scale_prior_[0] * model.length_scale_prior_[1],
            "dpgp": t.loc["dpgp", "log_density"],
            "single_gp": t.loc["single_gp", "log_density"],
            "position_blind": t.loc["position_blind", "log_density"],
        }
        row["dpgp - blind"] = row["dpgp"] - row["position_blind"]
        row["dpgp - single"] = row["dpgp"] - row["single_gp"]
        for h in ("1", "2", "4"):
            for m, short in (("dpgp", "dpgp"), ("constant_velocity", "cv")):
                for e in ("ade", "fde"):
                    col = f"{e}_{h}s"
                    row[f"{short} {e.upper()}@{h}s ({unit})"] = t.loc[m, col] if col in t.columns else float("nan")
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
        print(f"{name}: done in {row['seconds']:.0f} s", flush=True)
    table = pd.DataFrame(rows).set_index("data")
    with pd.option_context("display.width", 250, "display.max_columns", 40):
        print(table.T.to_string(float_format=lambda x: f"{x:.3g}"))


if __name__ == "__main__":
    main()
