"""What a SUMO junction fit's patterns are within one signal phase (issue 20, docs/dynamics.md).

The recording carries no signal state, so the phase of each frame is read from the vehicles: the
fixed-time program (90 s cycle, 45 s per direction with amber), its offset fitted to the flow
axis (cos 2θ) of the vehicles moving through the junction's centre. For a fit saved by
benches/dynamics.py this prints the offset and how many frames' own flow agrees with it, then for each dominant pattern (>= 5% of frames): its
share of frames in each phase, where in the phase its frames fall (seconds since the phase
started: median, and the share in the first 15 s — queue discharge — against the rest), and the
frames' mean speed and share of stopped vehicles; and how many distinct patterns (and patterns
with >= 10% of the phase) one phase holds. Finally the dwell of the *phase-level* sequence: each
pattern mapped to the phase it mostly falls in.

    PYTHONPATH=$PWD/python python benches/dynamics_phases.py --model sumo_sticky_dt1.npz
"""

from __future__ import annotations

import argparse
import json

import numpy as np

import dpgp
from dpgp.data.timeorder import time_order

CENTRE = (240.0, 240.0)  # m: the central junction of the 3 x 3 grid (crop [180, 300]^2)
RADIUS = 25.0
CYCLE = 90.0  # s: the signal program (README of the shared data: 42 s green each way)
DISCHARGE = 15.0  # s after a phase starts


def frame_phase(frames: dpgp.Frames, dt: float) -> tuple[np.ndarray, np.ndarray, dict]:
    """Per frame: seconds since its phase started, and the phase (+1 east–west green, −1
    north–south). SUMO's program is fixed-time (90 s: 42 s green + 3 s amber each way), so the
    phase is the 45 s half-cycle; its offset is the one whose square wave best matches the flow
    axis (Σ cos 2θ) of the vehicles moving faster than 2 m/s within 25 m of the centre."""
    v, xy, f = frames.v, frames.xy, frames.frame_of_row
    n = len(frames.ids)
    near = np.hypot(xy[:, 0] - CENTRE[0], xy[:, 1] - CENTRE[1]) < RADIUS
    moving = near & (np.hypot(v[:, 0], v[:, 1]) > 2.0)
    c = np.cos(2 * np.arctan2(v[:, 1], v[:, 0]))
    s = np.bincount(f[moving], weights=c[moving], minlength=n)
    k = np.bincount(f[moving], minlength=n)
    t = time_order(frames).time
    best = (-np.inf, 0.0, 1)
    for t0 in np.arange(0.0, CYCLE, dt / 2):
        sq = np.where(((t - t0) % CYCLE) < CYCLE / 2, 1, -1)
        for sign in (1, -1):
            score = float(np.dot(s, sign * sq))
            if score > best[0]:
                best = (score, t0, sign)
    _, t0, sign = best
    phase = sign * np.where(((t - t0) % CYCLE) < CYCLE / 2, 1, -1)
    since = (t - t0) % (CYCLE / 2)
    agree = float((np.sign(s[k > 0]) == phase[k > 0]).mean())
    return since, phase, {"offset_s": float(t0), "frames_whose_flow_agrees": round(agree, 3)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--model", required=True)
    ap.add_argument("--min-share", type=float, default=0.05)
    a = ap.parse_args()
    model = dpgp.DPGP.load(a.model)
    frames, labels = model.frames_, model.labels_
    dt = model.transitions_.dt
    order = time_order(frames)
    idx = np.argsort(order.time)  # one scene: time order
    since_all, ph, fit = frame_phase(frames, dt)
    t = order.time[idx]
    p = ph[idx]
    z = labels[idx]
    since = since_all[idx]
    # a phase: frames of one half-cycle (a new phase where the phase flips or a gap longer than it)
    start = np.r_[True, (np.diff(p) != 0) | (np.diff(t) > CYCLE / 2)]
    phase_id = np.cumsum(start) - 1
    n_phase = int(phase_id[-1]) + 1
    print(json.dumps({"what": "phases", "n": n_phase, **fit, "share_ew": round(float((p > 0).mean()), 3)}))
    sizes = np.bincount(z, minlength=model.n_patterns_)
    share = sizes / len(z)
    speed = np.hypot(frames.v[:, 0], frames.v[:, 1])
    f_speed = np.bincount(frames.frame_of_row, weights=speed, minlength=len(labels)) / np.maximum(frames.sizes, 1)
    f_stop = np.bincount(frames.frame_of_row, weights=speed < 0.5, minlength=len(labels)) / np.maximum(frames.sizes, 1)
    f_speed, f_stop, n_veh = f_speed[idx], f_stop[idx], frames.sizes[idx]
    for k in np.argsort(-sizes):
        if share[k] < a.min_share:
            break
        m = z == k
        ew = float((p[m] > 0).mean())
        print(json.dumps({"pattern": int(k), "share": round(float(share[k]), 3), "in_ew_phase": round(ew, 3),
                          "since_phase_start_median_s": round(float(np.median(since[m])), 1),
                          "in_first_15s": round(float((since[m] < DISCHARGE).mean()), 3),
                          "mean_speed": round(float(f_speed[m].mean()), 2),
                          "stopped_share": round(float(f_stop[m].mean()), 3),
                          "vehicles": round(float(n_veh[m].mean()), 1)}))  # fmt: skip
    inner_ids = range(1, n_phase - 1)  # the first and last phases are cut by the recording
    distinct = [len(np.unique(z[phase_id == i])) for i in inner_ids]
    big = [int((np.bincount(z[phase_id == i]) >= 0.1 * (phase_id == i).sum()).sum()) for i in inner_ids]
    # every frame's pattern mapped to the phase its pattern mostly falls in (all patterns)
    maj = np.zeros(model.n_patterns_, dtype=int)
    for k in range(model.n_patterns_):
        m = z == k
        maj[k] = 0 if not m.any() else (1 if (p[m] > 0).mean() >= 0.5 else -1)
    mapped = maj[z]
    agree = float((mapped == p).mean())
    r = np.diff(np.flatnonzero(np.r_[True, np.diff(mapped) != 0, True])) * dt
    print(json.dumps({"what": "per phase", "distinct_patterns_median": float(np.median(distinct)),
                      "patterns_ge10pct_median": float(np.median(big)),
                      "phase_of_pattern_agrees_with_frame_phase": round(agree, 3),
                      "mapped_runs": len(r), "mapped_mean_run_s": round(float(r.mean()), 1),
                      "mapped_median_run_s": round(float(np.median(r)), 1)}))  # fmt: skip


if __name__ == "__main__":
    main()
