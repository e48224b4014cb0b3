"""Benchmark: frame 10 million synthetic track rows with dpgp.make_frames.

    python benches/frame_tracks.py [--rows 10_000_000] [--velocity diff|columns] [--interleaved]

Synthetic vehicles drive curved paths sampled at 10 Hz (100 samples each, random start times
over an hour, a few gaps); the table is ``track, t, x, y`` (plus ``vx, vy`` with
``--velocity columns``), sorted by track as the readers return it (``--interleaved``: sorted by
time instead, which makes make_frames group the rows itself). Frames at dt = 0.5 s, cropped to
an ROI that holds about half of the positions.

Prints the seconds make_frames takes and its peak memory against the table's size, measured two
ways: the process's peak resident memory while framing (Linux VmHWM, reset just before; it
includes the table itself and the interpreter) and the peak of new allocations (tracemalloc, on
a second run).
"""

from __future__ import annotations

import argparse
import gc
import os
import resource
import time
import tracemalloc

import numpy as np
import pandas as pd

import dpgp


def synthetic_tracks(n_rows: int, with_velocity: bool, interleaved: bool, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    per = 100
    n_tracks = n_rows // per
    track = np.repeat(np.arange(n_tracks, dtype=np.int64), per)
    step = np.tile(np.arange(per, dtype=np.float64), n_tracks)
    start = np.round(rng.uniform(0, 3600, n_tracks), 1)
    t = np.repeat(start, per)
    t += step * 0.1
    t += ((track % 50 == 0) & (step >= per // 2)) * 3.0  # every 50th track has a 3 s gap
    # curved paths: constant speed, slowly turning heading
    speed = np.repeat(rng.uniform(5, 30, n_tracks), per)
    heading = np.repeat(rng.uniform(0, 2 * np.pi, n_tracks), per)
    heading += step * np.repeat(rng.normal(0, 0.005, n_tracks), per)
    del step
    x = np.cumsum((speed * np.cos(heading) * 0.1).reshape(n_tracks, per), axis=1).ravel()
    x += np.repeat(rng.uniform(0, 1000, n_tracks), per)
    y = np.cumsum((speed * np.sin(heading) * 0.1).reshape(n_tracks, per), axis=1).ravel()
    y += np.repeat(rng.uniform(0, 1000, n_tracks), per)
    cols = {"track": track, "t": t, "x": x, "y": y}
    if with_velocity:
        cols["vx"] = speed * np.cos(heading)
        cols["vy"] = speed * np.sin(heading)
    del speed, heading
    df = pd.DataFrame(cols, copy=False)
    if interleaved:
        df = df.sort_values("t", kind="stable", ignore_index=True)
    return df


def _reset_peak_rss() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")  # resets VmHWM (peak resident set) on Linux
        return True
    except OSError:
        return False


def _peak_rss_bytes() -> int:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", type=int, default=10_000_000)
    ap.add_argument("--velocity", choices=("diff", "columns"), default="diff")
    ap.add_argument("--interleaved", action="store_true")
    ap.add_argument("--dt", type=float, default=0.5)
    args = ap.parse_args()

    df = synthetic_tracks(args.rows, args.velocity == "columns", args.interleaved)
    gc.collect()
    table = int(df.memory_usage(index=True, deep=True).sum())
    roi = (250.0, 750.0, 0.0, 1000.0)

    exact = _reset_peak_rss()
    t0 = time.perf_counter()
    frames = dpgp.make_frames(df, roi=roi, dt=args.dt, velocity=args.velocity)
    seconds = time.perf_counter() - t0
    rss = _peak_rss_bytes()
    n_frames, n_points = len(frames), frames.n_points
    del frames
    gc.collect()

    tracemalloc.start()
    dpgp.make_frames(df, roi=roi, dt=args.dt, velocity=args.velocity)
    _, traced = tracemalloc.get_traced_memory()
    tracemalloc.stop()

    mb = 1 << 20
    print(
        f"table: {len(df):,} rows x {df.shape[1]} columns = {table / mb:,.0f} MiB"
        f" ({'interleaved by time' if args.interleaved else 'sorted by track'}, velocity={args.velocity})"
    )
    print(f"frames: {n_frames:,} frames, {n_points:,} vehicle observations (dt {args.dt} s)")
    print(f"make_frames: {seconds:.2f} s")
    print(
        f"peak resident memory while framing{'' if exact else ' (whole run: VmHWM reset unavailable)'}: "
        f"{rss / mb:,.0f} MiB = {rss / table:.2f} x the table (includes the table and the interpreter)"
    )
    print(
        f"peak new allocations in make_frames (tracemalloc): {traced / mb:,.0f} MiB = {traced / table:.2f} x the table"
    )
    print(f"cpu count {os.cpu_count()}")


if __name__ == "__main__":
    main()
