"""Checkpoint and resume (issue 11): kill -9 at random points, resume from every checkpoint, and
what a checkpoint costs.

    nice python benches/kill_resume.py            # 20 fits, each SIGKILLed at a random point and
                                                  # resumed, against uninterrupted twins with and
                                                  # without checkpoints (issue 17)
    nice python benches/kill_resume.py --matrix   # resume from every checkpoint of short fits over
                                                  # likelihood x proposal x assignment x seed x threads
    nice python benches/kill_resume.py --cost     # checkpoint cost on NGSIM US-101, 1000 frames,
                                                  # default settings, checkpoint_every=10: the
                                                  # rebuild's and the write's share of the fit

A resumed fit must equal its twin bitwise in labels, length scales, alpha, history (but seconds),
label trace, sweeps and convergence. Every fit runs in a child process (``--child``), so a kill
is a real SIGKILL: no cleanup runs, a checkpoint write may be cut short.
"""

from __future__ import annotations

import argparse
import itertools
import json
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import dpgp
import dpgp.io

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ngsim_us101_frames.tsv"


# --- comparing two fits ---------------------------------------------------------------------------
def differences(a: dpgp.DPGP, b: dpgp.DPGP) -> list[str]:
    """What differs between two fitted models, bit for bit (wall-clock seconds aside)."""
    out = []
    for name in ("labels_", "length_scales_", "label_trace_"):
        x, y = getattr(a, name, None), getattr(b, name, None)
        if (x is None) != (y is None) or (x is not None and not np.array_equal(x, y)):
            out.append(name)
    for name in ("alpha_", "n_iter_", "converged_", "log_joint_"):
        if getattr(a, name) != getattr(b, name):
            out.append(name)
    ha = {k: v for k, v in a.history_.items() if k != "seconds"}
    hb = {k: v for k, v in b.history_.items() if k != "seconds"}
    if ha != hb:
        out.append("history_")
    return out


# --- the child: one fit or one resume, saved as a model file ----------------------------------------
def child(spec: dict) -> None:
    if spec["mode"] == "resume":
        model = dpgp.DPGP.resume(spec["checkpoint"])
    else:
        frames = load_frames(spec["data"], spec["n_frames"], spec.get("data_seed", 0))
        model = dpgp.DPGP(**spec["settings"], checkpoint=spec["checkpoint"], progress=False).fit(frames)
    model.save(spec["out"])


def load_frames(data: str, n_frames: int, seed: int) -> dpgp.Frames:
    if data == "us101":
        return dpgp.read_frames(DATA)[:n_frames]
    return dpgp.datasets.synthetic(data, n_frames, seed=seed)


def run_child(spec: dict, kill_after: float | None = None) -> tuple[str, float]:
    """Run a child; with ``kill_after``, SIGKILL it then. Returns (how it ended, seconds)."""
    t = time.perf_counter()
    proc = subprocess.Popen([sys.executable, __file__, "--child", json.dumps(spec)], stderr=subprocess.PIPE, text=True)
    try:
        proc.wait(timeout=kill_after)
        status = "finished" if proc.returncode == 0 else f"failed: {proc.stderr.read()[-400:]}"
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        status = "killed"
    finally:
        proc.stderr.close()
    return status, time.perf_counter() - t


# --- 20 kills ---------------------------------------------------------------------------------------
CONFIGS = [
    dict(likelihood=lik, proposal=prop, assignment=asg)
    for lik, prop, asg in itertools.product(["exact", "hsgp"], ["informed", "full"], ["gibbs", "map"])
]


def kill_table(n_fits: int, data: str, n_frames: int, iterations: int, every: int, seed: int) -> bool:
    rng = random.Random(seed)
    root = Path(tempfile.mkdtemp(prefix="dpgp-kill-"))
    rows, ok = [], True
    print(f"{n_fits} fits of {data} ({n_frames} frames), {iterations} sweeps, checkpoint every {every}; "
          "each killed by SIGKILL at a random point, then resumed; against the same fit with and without checkpoints")  # fmt: skip
    header = f"{'fit':>3}  {'likelihood':<6} {'proposal':<8} {'assign':<6} {'seed':>4}  {'twin s':>6}  {'kill at s':>9}  {'ckpt sweep':>10}  {'temp':>4}  {'identical':<9}"
    print(header)
    try:
        for i in range(n_fits):
            settings = {**CONFIGS[i % len(CONFIGS)], "iterations": iterations, "checkpoint_every": every,
                        "seed": rng.randrange(1000), "noise_var": 0.2, "n_threads": 1 + i % 2, "store_labels": True}  # fmt: skip
            d = root / f"fit{i}"
            d.mkdir()
            base = {"mode": "fit", "data": data, "n_frames": n_frames, "data_seed": i, "settings": settings}
            status, twin_seconds = run_child({**base, "checkpoint": str(d / "twin.ckpt"), "out": str(d / "twin.npz")})
            if status != "finished":
                raise RuntimeError(f"fit {i}: the twin {status}")
            # The same fit without checkpoints: checkpointing must not change the result (issue 17).
            status, _ = run_child({**base, "checkpoint": None, "out": str(d / "plain.npz")})
            if status != "finished":
                raise RuntimeError(f"fit {i}: the fit without checkpoints {status}")
            # Anywhere from the interpreter's start to the end of the last sweep; a child that
            # finished first (the machine was less busy than for its twin) is run again, its
            # checkpoint removed, and killed earlier.
            ckpt = d / "killed.ckpt"
            for attempt in range(5):
                ckpt.unlink(missing_ok=True)
                kill_at = rng.uniform(0.05, 0.95 - 0.2 * attempt) * twin_seconds
                status, _ = run_child(
                    {**base, "checkpoint": str(ckpt), "out": str(d / "killed.npz")}, kill_after=kill_at
                )
                if status != "finished":
                    break
            temps = len(list(d.glob(".dpgp-*.tmp")))
            if status == "killed" and ckpt.exists():
                sweep = str(dpgp.io.read_metadata(ckpt)["resume"]["sweeps_done"])
                status, _ = run_child({"mode": "resume", "checkpoint": str(ckpt), "out": str(d / "resumed.npz")})
            elif status == "killed":  # before the first checkpoint (still initialising): start again
                sweep = "none"
                status, _ = run_child({**base, "checkpoint": str(ckpt), "out": str(d / "resumed.npz")})
            else:
                sweep = "(missed)"
                shutil.copy(d / "killed.npz", d / "resumed.npz")
            if status != "finished":
                raise RuntimeError(f"fit {i}: the resumed fit {status}")
            twin = dpgp.DPGP.load(d / "twin.npz")
            diff = differences(twin, dpgp.DPGP.load(d / "resumed.npz"))
            diff += [f"plain:{x}" for x in differences(twin, dpgp.DPGP.load(d / "plain.npz"))]
            left = len(list(d.glob(".dpgp-*.tmp")))
            ok &= not diff and not left
            verdict = "yes" if not diff else "NO: " + ",".join(diff)
            temp_note = f"{temps}>{left}" if temps else "0"
            row = (f"{i:>3}  {settings['likelihood']:<6} {settings['proposal']:<8} {settings['assignment']:<6} "
                   f"{settings['seed']:>4}  {twin_seconds:>6.1f}  {kill_at:>9.2f}  {sweep:>10}  {temp_note:>4}  {verdict:<9}")  # fmt: skip
            rows.append(row)
            print(row, flush=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    n_same = sum(r.rstrip().endswith("yes") for r in rows)
    print(f"identical: with checkpoints = without = killed and resumed: {n_same}/{n_fits}")
    print("(temp: checkpoint temporary files left by the kill > left after resuming)")
    return ok


# --- resume from every checkpoint -------------------------------------------------------------------
class _Recording(dpgp.DPGP):
    """A fit that keeps a copy of every checkpoint it writes."""

    copies: list[Path]

    def _write_checkpoint(self, traces):  # noqa: ANN001
        super()._write_checkpoint(traces)
        copy = Path(f"{self.checkpoint}.{len(self.copies)}")
        shutil.copy(self.checkpoint, copy)
        self.copies.append(copy)


def resume_every_checkpoint(frames: dpgp.Frames, settings: dict, directory: Path) -> tuple[dpgp.DPGP, list[str]]:
    """Fit with checkpoints, then resume from each one: (the fit, differences found)."""
    model = _Recording(**settings, checkpoint=str(directory / "fit.ckpt"), progress=False)
    model.copies = []
    model.fit(frames)
    found = []
    for copy in model.copies:
        resumed = dpgp.DPGP.resume(copy)
        found += [f"{copy.name}: {d}" for d in differences(model, resumed)]
    return model, found


# Settings beyond the grid, on exact/informed/gibbs.
EXTRAS = [
    dict(pattern_moments=True),
    dict(length_scale_fraction=0.5),
    dict(alpha=2.0),
    dict(length_scales=(3.0, 30.0)),
    dict(n_iter_no_change=2, ari_tol=0.9),
    dict(store_labels=False),
]


def matrix(n_frames: int) -> bool:
    frames = (
        dpgp.read_frames(DATA)[:n_frames] if DATA.exists() else dpgp.datasets.synthetic("highway", n_frames, seed=1)
    )
    print(f"resume from every checkpoint: {frames!r}, 9 sweeps, checkpoint every 2 (noise_var 1.0)")
    ok = True
    grid = [dict(likelihood=lik, proposal=prop, assignment=asg, seed=seed)
            for lik, prop, asg, seed in itertools.product(["exact", "hsgp"], ["full", "informed"], ["gibbs", "map"], [0, 1])]  # fmt: skip
    grid += [dict(likelihood="exact", proposal="informed", assignment="gibbs", seed=0, **e) for e in EXTRAS]
    with tempfile.TemporaryDirectory() as tmp:
        for i, variant in enumerate(grid):
            fits = []
            for threads in (1, 2):
                d = Path(tmp) / f"{i}-{threads}"
                d.mkdir()
                settings = {"iterations": 9, "checkpoint_every": 2, "noise_var": 1.0, "store_labels": True, **variant}
                t = time.perf_counter()
                model, found = resume_every_checkpoint(frames, {**settings, "n_threads": threads}, d)
                fits.append(model)
                ok &= not found
                name = " ".join(f"{k}={v}" for k, v in variant.items())
                print(f"  {name} threads {threads}: {len(model.copies)} checkpoints, "
                      f"{'all identical' if not found else found} ({time.perf_counter() - t:.1f} s)", flush=True)  # fmt: skip
            across = differences(*fits)
            ok &= not across
            print(f"    1 thread vs 2: {'identical' if not across else across}")
    return ok


# --- cost -------------------------------------------------------------------------------------------
def cost(n_frames: int, iterations: int, every: int) -> None:
    """What a checkpoint costs on a default fit: the canonical rebuild every fit does at the
    cadence (with or without a file) and the file write, each as a share of the fit."""
    frames = dpgp.read_frames(DATA)[:n_frames]
    print(f"US-101 {frames!r}, default settings, {iterations} sweeps, checkpoint_every={every}")
    with tempfile.TemporaryDirectory() as tmp:
        for label, path in (("without a file", None), ("with a file", str(Path(tmp) / "us101.ckpt"))):
            t = time.perf_counter()
            model = dpgp.DPGP(iterations=iterations, checkpoint=path, checkpoint_every=every, progress=False).fit(
                frames
            )
            total = time.perf_counter() - t
            reset, write = (float(np.sum(model.checkpoint_seconds_[k])) for k in ("reset", "write"))
            sweep = float(np.median(model.history_["seconds"]))
            n = len(model.checkpoint_seconds_["reset"])
            print(f"  {label:<15} ({model.likelihood_}, {model.proposal}, {model.n_patterns_} patterns): fit {total:.1f} s, "
                  f"median sweep {sweep:.3f} s; {n} rebuilds {reset:.2f} s = {reset / total:.1%} of the fit"
                  + (f"; writes {write:.2f} s = {write / total:.1%} (file {Path(path).stat().st_size / 1e6:.2f} MB)" if path else ""),
                  flush=True)  # fmt: skip


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--child", help=argparse.SUPPRESS)
    p.add_argument("--matrix", action="store_true", help="resume from every checkpoint over the settings' variants")
    p.add_argument("--cost", action="store_true", help="checkpoint cost on US-101")
    p.add_argument("--fits", type=int, default=20, help="kill/resume fits")
    p.add_argument("--data", default="us101", help="'us101' (the first --frames frames) or a synthetic kind")
    p.add_argument(
        "--frames", type=int, default=None, help="frames (default: 200 for kills and the matrix, 1000 for the cost)"
    )
    p.add_argument("--iterations", type=int, default=None, help="sweeps (default: 30 for kills, 40 for the cost)")
    p.add_argument(
        "--every", type=int, default=None, help="checkpoint_every (default: 3 for the kill fits, 10 for the cost)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the kill times and the fits' seeds")
    args = p.parse_args()
    args.every_set = args.every is not None
    args.every = args.every if args.every_set else 3
    if args.child:
        child(json.loads(args.child))
        return 0
    if args.cost:
        cost(args.frames or 1000, args.iterations or 40, args.every if args.every_set else 10)
        return 0
    if args.matrix:
        return 0 if matrix(args.frames or 200) else 1
    return (
        0 if kill_table(args.fits, args.data, args.frames or 200, args.iterations or 30, args.every, args.seed) else 1
    )


if __name__ == "__main__":
    sys.exit(main())
