"""Pattern dynamics on the shared SUMO junction (issue 20, docs/dynamics.md).

Fits DPGP (every default but ``dynamics``; 20 sweeps) on the frames of
``../shared/data/sumo_grid_intersection_fcd.xml.gz`` (all 3,150, or the first ``--frames``), or
loads the fit saved by an earlier run, then prints the transition figures: K, K with >= 1% of
frames, the share of consecutive frames that share a pattern, the runs (mean, median, longest),
the mean dwell of the dominant patterns (>= 10% of frames) against the 42 s green, the cycle of
the dominant sequence against the 90 s signal cycle, the sweep time and the ESS per second of the
log joint and of K (second half of the sweeps).

    PYTHONPATH=$PWD/python nice python benches/dynamics.py [--dynamics sticky] [--out sumo_sticky.npz]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

import dpgp
from dpgp.chains.diagnostics import ess_bulk
from dpgp.data.timeorder import time_order

DATA = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "sumo_grid_intersection_fcd.xml.gz")
DOMINANT = 0.10  # share of frames that makes a pattern dominant
MIN_RUN = 5.0  # s: shorter runs are flicker, not a phase, when timing the cycle


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


def cycle_figures(model: dpgp.DPGP, phases: object = None) -> dict:
    """Dominant patterns' mean dwell, and the cycle: the median time between the starts of
    successive runs (>= MIN_RUN) of one dominant pattern, and the lag (20-240 s) of the highest
    autocorrelation of the dominant patterns' indicators on the time grid. With ``phases``
    (:class:`dpgp.evaluate.phases.Phases`), the same of the phases instead of the patterns."""
    tr = model.transitions_ if phases is None else phases.transitions  # type: ignore[attr-defined]
    labels = model.labels_ if phases is None else phases.labels  # type: ignore[attr-defined]
    share = np.bincount(labels, minlength=tr.n_patterns) / len(labels)
    dominant = [int(k) for k in np.flatnonzero(share >= DOMINANT)]
    dwell = {k: float(tr.dwell(k).mean()) for k in dominant}
    order = time_order(model.frames_)
    gaps = []
    for k in dominant:
        runs = tr.runs[(tr.runs[:, 0] == k) & (tr.runs[:, 2] * tr.dt >= MIN_RUN)]
        starts = np.sort(order.time[runs[:, 1]]) if len(runs) else np.array([])
        gaps += list(np.diff(starts))
    t = order.time - order.time.min()
    grid = np.round(t / tr.dt).astype(int)
    best = (float("nan"), -np.inf)
    lags = np.arange(int(20 / tr.dt), int(240 / tr.dt) + 1)
    ac = np.zeros(len(lags))
    for k in dominant:
        x = np.zeros(grid.max() + 1)
        x[grid[labels == k]] = 1.0
        x -= x.mean()
        denom = float(np.dot(x, x)) or 1.0
        ac += np.array([np.dot(x[:-lag], x[lag:]) / denom for lag in lags])
    if len(dominant):
        j = int(np.argmax(ac))
        best = (float(lags[j] * tr.dt), float(ac[j] / len(dominant)))
    return {
        "dominant": {k: round(float(share[k]), 3) for k in dominant},
        "dominant_mean_dwell_s": {k: round(v, 2) for k, v in dwell.items()},
        "cycle_median_recurrence_s": round(float(np.median(gaps)), 2) if gaps else None,
        "cycle_recurrences": len(gaps),
        "cycle_autocorr_peak_s": best[0],
        "cycle_autocorr_height": round(best[1], 3),
    }


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--data", default=DATA)
    p.add_argument("--out", default="sumo_none.npz", help="model file written by the fit (reused if present)")
    p.add_argument("--iterations", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--frames", type=int, default=None, help="fit the first N frames only")
    p.add_argument("--dt", type=float, default=0.5, help="frame grid step, s (make_frames' default 0.5)")
    p.add_argument("--dynamics", default=None, choices=[None, "sticky"])
    p.add_argument("--rho", default=None, help="sticky only: 'a,b' Beta prior of ρ, or a fixed ρ")
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--likelihood", default="auto", help="the fit's likelihood ('auto', 'exact', 'hsgp')")
    p.add_argument("--phases", default=None, help="also the figures of the phases: a number, or 'auto'")
    p.add_argument("--durations", action="store_true", help="phases by the semi-Markov model (log-normal durations)")
    p.add_argument(
        "--evidence",
        default="labels",
        choices=["labels", "likelihood"],
        help="phases fitted to labels or to the frames' likelihoods",
    )
    p.add_argument("--cycle", action="store_true", help="phases in a fixed cycle (a fixed-time signal's stages)")
    a = p.parse_args()
    set_rho_prior(a.rho)
    if os.path.exists(a.out):
        model = dpgp.DPGP.load(a.out)
        print(f"loaded {a.out}")
    else:
        frames = dpgp.make_frames(dpgp.read_tracks(a.data, preset="sumo"), dt=a.dt)
        if a.frames is not None:
            frames = frames[: a.frames]
        t = time.perf_counter()
        model = dpgp.DPGP(
            iterations=a.iterations,
            seed=a.seed,
            progress=False,
            dynamics=a.dynamics,
            n_threads=a.threads,
            likelihood=a.likelihood,
        ).fit(frames)
        print(f"fit: {len(frames)} frames (dt {a.dt} s), dynamics={a.dynamics}, {time.perf_counter() - t:.1f} s total")
        model.save(a.out)
    h = model.history_
    sweeps = np.asarray(h["seconds"])
    half = len(sweeps) // 2
    secs = float(sweeps[half:].sum())
    tr = model.transitions_
    w = np.bincount(model.labels_, minlength=model.n_patterns_) / len(model.labels_)
    row = {
        "frames": len(model.frames_), "dynamics": model.dynamics, "K": model.n_patterns_,
        "K_1pct": int((w >= 0.01).sum()), "share_same": round(tr.share_same, 4),
        "stickiness": model.stickiness_, "sweep_median_s": round(float(np.median(sweeps)), 3),
        "ess_per_s_log_joint": round(ess_bulk(h["log_joint"][half:]) / secs, 4),
        "ess_per_s_K": round(ess_bulk(h["n_patterns"][half:]) / secs, 4),
        **cycle_figures(model),
    }  # fmt: skip
    print(json.dumps(row))
    print(tr.summary())
    if a.phases is not None:
        t = time.perf_counter()
        ph = model.phases(
            a.phases if a.phases == "auto" else int(a.phases), durations=a.durations, evidence=a.evidence, cycle=a.cycle
        )
        seconds = time.perf_counter() - t
        print(ph.summary())
        print(json.dumps({"phases": ph.n_phases, "durations": a.durations, "evidence": a.evidence, "cycle": a.cycle, "fit_s": round(seconds, 2),
                          "share_same": round(ph.transitions.share_same, 4), "log_likelihood": round(ph.log_likelihood, 1),
                          **cycle_figures(model, ph)}))  # fmt: skip


if __name__ == "__main__":
    main()
