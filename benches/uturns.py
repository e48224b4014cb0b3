"""U-turns of the pure field (issue 34, "No U-turns"): on the shared track sets, split in time
70/30, fit with fields over position and over position + heading, and roll every vehicle of up to
``--frames`` recorded test frames through its frame's field alone (``dynamics="field"``) for
``--seconds``. A vehicle *reverses* when the heading of one of its velocities at least 0.5 m/s
(the frames' heading speed) fast lies more than 150° from the heading it started with (its first
such velocity), while it is inside the ROI. The recordings' share is the same rule over the same
vehicles' own tracks for the same span. Prints one table: shares, vehicles, seconds.

    python benches/uturns.py [--only peachtree,sumo_junction] [--seconds 20] [--frames 150] [--models DIR]
        [--max-curvature recorded]

``--models DIR`` keeps the fits as model files there (and loads them when present), so that a
change to generation alone is compared before and after on the same fits. ``--max-curvature``
adds a row for the fields over heading rolled out under that turning limit (``"recorded"`` or a
number per unit length: :meth:`dpgp.DPGP.simulate`).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

import dpgp
from dpgp.data._previous import in_frame_units
from dpgp.evaluate import split_in_time
from realism import datasets as realism_datasets  # benches/realism.py, this folder

REVERSAL = np.deg2rad(150.0)


def reversed_share(headings: list[np.ndarray]) -> tuple[float, int]:
    """Share of vehicles (each a sequence of headings, NaN where slower than the heading speed)
    whose heading moves more than 150° from its first, and how many vehicles had two or more."""
    n = rev = 0
    for h in headings:
        h = h[~np.isnan(h)]
        if len(h) < 2:
            continue
        n += 1
        rev += bool(np.any(np.abs(np.angle(np.exp(1j * (h - h[0])))) > REVERSAL))
    return (rev / n if n else float("nan")), n


def own_headings(v: np.ndarray, speed: float) -> np.ndarray:
    return np.where(np.hypot(v[:, 0], v[:, 1]) >= speed, np.arctan2(v[:, 1], v[:, 0]), np.nan)


def recorded(test: dpgp.Frames, starts: np.ndarray, steps: int, speed: float) -> list[np.ndarray]:
    """Each start frame's vehicles' headings along their own tracks for ``steps`` grid steps."""
    out = []
    dt = test.summary.dt
    for i in starts:
        t0 = test.ids[i]
        last = np.searchsorted(test.ids, t0 + steps * dt + 1e-9)
        rows = np.arange(test.offsets[i], test.offsets[last])
        for tr in test.tracks[test.offsets[i] : test.offsets[i + 1]]:
            mine = rows[test.tracks[rows] == tr]
            out.append(own_headings(test.v[mine], speed))
    return out


def simulated(
    model: dpgp.DPGP, test: dpgp.Frames, starts: np.ndarray, steps: int, speed: float, limit: float | str | None = None
) -> list[np.ndarray]:
    out = []
    for i in starts:
        sim = model.simulate(test[int(i)], steps=steps, dynamics="field", max_curvature=limit)
        for j in range(sim.positions.shape[1]):
            inside = sim.in_roi[:, j]
            out.append(own_headings(sim.velocities[inside, j], speed))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="comma-separated subset of the data sets")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--frames", type=int, default=150, help="recorded test frames to start from")
    ap.add_argument("--iterations", type=int, default=20)
    ap.add_argument("--likelihood", default="exact", choices=("exact", "hsgp"))
    ap.add_argument("--models", type=Path, help="folder to keep the fits in (loaded from there when present)")
    ap.add_argument("--max-curvature", help="also roll the fields over heading out under this turning limit")
    args = ap.parse_args()
    sets = realism_datasets()
    rows = []
    for name, (load, _unit) in sets.items():
        if args.only and name not in args.only.split(","):
            continue
        frames, _tracks = load()
        train, test = split_in_time(frames)
        dt = test.summary.dt
        steps = int(round(args.seconds / dt))
        mps = test.heading_min_speed if test.heading_min_speed is not None else 0.5
        speed = in_frame_units(mps, test.summary.length_unit)
        starts = np.unique(np.linspace(0, len(test) - 1, min(args.frames, len(test))).round().astype(np.int64))
        share, n = reversed_share(recorded(test, starts, steps, speed))
        rows.append({"data": name, "source": "recorded", "reversed": share, "vehicles": n, "seconds": 0.0})
        for inputs in ("position", "position+heading"):
            t0 = time.perf_counter()
            kept = None if args.models is None else args.models / f"{name}-{inputs}-{args.iterations}.npz"
            if kept is not None and kept.exists():
                model = dpgp.DPGP.load(kept)
            else:
                model = dpgp.DPGP(
                    iterations=args.iterations, seed=0, progress=False, likelihood=args.likelihood,
                    sampler="collapsed", inputs=inputs,
                ).fit(train)  # fmt: skip
                if kept is not None:
                    kept.parent.mkdir(parents=True, exist_ok=True)
                    model.save(kept)
            limits: list[float | str | None] = [None]
            if args.max_curvature is not None and inputs == "position+heading":
                limits.append(args.max_curvature if args.max_curvature == "recorded" else float(args.max_curvature))
            for limit in limits:
                share, n = reversed_share(simulated(model, test, starts, steps, speed, limit))
                source = inputs if limit is None else f"{inputs}, turning limit {limit}"
                rows.append(
                    {
                        "data": name,
                        "source": source,
                        "reversed": share,
                        "vehicles": n,
                        "seconds": time.perf_counter() - t0,
                    }
                )
                print(rows[-1], flush=True)
    print(pd.DataFrame(rows).to_string(index=False, float_format=lambda x: f"{x:.3g}"))


if __name__ == "__main__":
    main()
