"""Long scenarios that switch pattern (issue 20, docs/dynamics.md): 10-minute scenarios generated
from the SUMO junction fit of benches/dynamics.py; the autocorrelation of the scene's flow axis
(does the junction's 90 s signal cycle show?), on the generated scenarios and, as the reference,
on the recording; throughput; the realism score against the recording.

    PYTHONPATH=$PWD/python nice python benches/dynamics_long.py --model sumo_none.npz [--n 3] [--phases 2]

Each scenario's health against the recording: vehicles per step (all, and in the last minute:
does the scene fill up?), the share of vehicle-steps standing (< 0.5 m/s), the median time a
vehicle stays, and the share of steps whose velocity turns by more than 90° (reversals).

The flow axis of a step is the mean of cos 2θ over the moving vehicles (θ their heading): +1 when
all move east–west, −1 when all move north–south, whichever way along the axis.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import pandas as pd

import dpgp
from dpgp.evaluate.realism_checks import realism

DATA = "../shared/data/sumo_grid_intersection_fcd.xml.gz"


def flow_axis(table: pd.DataFrame, dt: float, t_end: float) -> np.ndarray:
    """Mean cos 2θ of the vehicles moving faster than 1 m/s at each step (0 where none)."""
    moving = table[np.hypot(table.vx, table.vy) > 1.0]
    c = np.cos(2 * np.arctan2(moving.vy, moving.vx))
    step = np.rint(moving.t.to_numpy() / dt).astype(int)
    n = int(round(t_end / dt)) + 1
    s = np.bincount(step, weights=c, minlength=n)[:n]
    k = np.bincount(step, minlength=n)[:n]
    return np.where(k > 0, s / np.maximum(k, 1), 0.0)


def acf_peak(signal: np.ndarray, dt: float, lo: float = 20.0, hi: float = 240.0) -> tuple[float, float]:
    """Lag (s) and height of the autocorrelation's highest peak between ``lo`` and ``hi`` seconds."""
    x = signal - signal.mean()
    r = np.correlate(x, x, "full")[len(x) - 1 :] / (x @ x)
    lags = np.arange(len(r)) * dt
    ok = np.flatnonzero((lags >= lo) & (lags <= hi))
    peaks = [i for i in ok if r[i] >= r[i - 1] and r[i] >= r[min(i + 1, len(r) - 1)]]
    best = max(peaks, key=lambda i: r[i]) if peaks else ok[np.argmax(r[ok])]
    return float(lags[best]), float(r[best])


def health(table: pd.DataFrame, duration: float) -> dict:
    """Vehicles per step (all, last minute), standing share, median stay (s), reversal share."""
    per_step = table.groupby("t").size()
    v = table.sort_values(["vehicle", "t"])
    same = (v.vehicle == v.vehicle.shift()).to_numpy()
    dot = (v.vx * v.vx.shift() + v.vy * v.vy.shift()).to_numpy()[same]
    stay = table.groupby("vehicle").t.agg(lambda t: t.max() - t.min())
    return {
        "vehicles_per_step": round(float(per_step.mean()), 1),
        "vehicles_last_minute": round(float(per_step[per_step.index > duration - 60].mean()), 1),
        "standing": round(float((np.hypot(table.vx, table.vy) < 0.5).mean()), 3),
        "median_stay_s": round(float(stay.median()), 1),
        "reversals": round(float((dot < 0).mean()), 4),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--model", default="sumo_none.npz")
    ap.add_argument("--n", type=int, default=3)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--phases", default=None, help="switch pattern by phase: a number of phases, or 'auto'")
    ap.add_argument("--durations", action="store_true", help="phases by the semi-Markov model")
    ap.add_argument(
        "--evidence",
        default="labels",
        choices=["labels", "likelihood"],
        help="phases fitted to labels or to the frames' likelihoods",
    )
    ap.add_argument("--cycle", action="store_true", help="phases in a fixed cycle (a fixed-time signal's stages)")
    a = ap.parse_args()
    phases = None if a.phases is None else (a.phases if a.phases == "auto" else int(a.phases))
    model = dpgp.DPGP.load(a.model)
    dt = model.transitions_.dt
    tracks = dpgp.read_tracks(DATA, preset="sumo")
    frames = dpgp.make_frames(tracks, dt=dt)
    rec = pd.DataFrame({"t": frames.ids[frames.frame_of_row], "vx": frames.v[:, 0], "vy": frames.v[:, 1]})
    rec_axis = flow_axis(rec.assign(t=rec.t - rec.t.min()), dt, float(rec.t.max() - rec.t.min()))
    lag, height = acf_peak(rec_axis, dt)
    life = tracks.groupby("track").t.agg(lambda t: t.max() - t.min())
    print(json.dumps({"what": "recording", "acf_peak_s": lag, "acf_peak": round(height, 3),
                      "vehicles_per_step": round(float(np.mean(frames.sizes)), 1),
                      "standing": round(float((np.hypot(*frames.v.T) < 0.5).mean()), 3),
                      "median_stay_s": round(float(life.median()), 1)}))  # fmt: skip
    if phases is not None:
        t = time.perf_counter()
        phases = model.phases(phases, durations=a.durations, evidence=a.evidence, cycle=a.cycle)
        print(phases.summary(), f"\n(phases fitted in {time.perf_counter() - t:.1f} s)")
    t = time.perf_counter()
    by_phase = {} if phases is None else {"phases": phases}  # (runs on versions without phases too)
    scen = model.sample_scenarios(a.n, duration=a.duration, seed=a.seed, dynamics=True, **by_phase)
    seconds = time.perf_counter() - t
    rows = sum(len(s.table) for s in scen)
    print(json.dumps({"what": "throughput", "scenarios": a.n, "duration_s": a.duration, "wall_s": round(seconds, 2),
                      "simulated_s_per_wall_s": round(a.n * a.duration / seconds, 1),
                      "vehicle_steps_per_wall_s": round(rows / seconds)}))  # fmt: skip
    for i, s in enumerate(scen):
        lag, height = acf_peak(flow_axis(s.table, dt, a.duration), dt)
        runs = np.diff(np.flatnonzero(np.r_[True, np.diff(s.patterns) != 0, True])) * dt
        print(json.dumps({"what": f"generated {i}", "acf_peak_s": lag, "acf_peak": round(height, 3),
                          "switches": s.switches(), "mean_run_s": round(float(runs.mean()), 2),
                          **health(s.table, a.duration)}))  # fmt: skip
    gen = pd.concat([s.table.assign(scenario=i) for i, s in enumerate(scen)])
    recorded = tracks.rename(columns={"track": "vehicle"}).assign(scenario=0)[["scenario", "vehicle", "t", "x", "y"]]
    try:
        r = realism(gen[["scenario", "vehicle", "t", "x", "y"]], recorded, units="m", dt=dt)
        print(json.dumps({"what": "realism", "meta": float(r.scores.loc["meta", "generated"])}))
    except Exception as e:  # reported, not hidden
        print(json.dumps({"what": "realism", "error": f"{type(e).__name__}: {e}"}))


if __name__ == "__main__":
    main()
