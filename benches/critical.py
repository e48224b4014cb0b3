"""Importance-sampled critical scenarios against crude Monte Carlo (issue 35), on fitted models of
the shared data.

For each data set: ``--crude`` natural scenes of 16 steps (every default of ``sample_scenarios``)
measured once (:func:`dpgp.generate.criticality.criticality`, per scene); events "hardest
deceleration above a threshold" (or ``--measure`` ttc, gap, pet below one) with the thresholds
at the crude run's ``--rates`` quantiles (a rate inside an atom of the measure, such as the scenes
braking at the generator's bound, has no event: the bench says how many scenes sit there);
for each event a tilt learned by :func:`dpgp.generate.critical.learn_tilt` (``--rounds`` of
``--per-round`` scenes) and ``--tilted`` scenes drawn with it. Prints per event: the crude rate
and its 95 % interval, the tilted estimate, its standard error and effective sample size, whether
it lies in the 95 % interval of a crude run just large enough to see the event 300 times (the
first scenes of the crude run; the issue's reference), the z of its difference from the whole crude
run's rate, and the acceleration (:attr:`Estimate.acceleration`): how many crude scenes the tilted
estimate's standard error would take, over the scenes it took (tilted, and tilted plus learning). Then the realism score's kinematic features
(speed, acceleration, turn rate, angular acceleration) of ``--realism`` tilted scenes (the rarest
event's tilt) against as many natural ones, both scored against the recorded test windows.

    python benches/critical.py [--only sumo_junction,us101_linked] [--model NAME=PATH ...]
        [--crude 300000] [--rates 1e-2,3e-3,1e-3] [--tilted 30000] [--per-round 1000] [--rounds 6]
        [--realism 2000] [--cache DIR] [--plots DIR] [--measure deceleration]

``--model NAME=PATH`` uses a saved fit (else: fitted here, 20 sweeps on the training 70 %, kept in
``--cache``). ``--cache DIR`` keeps the crude runs' measures there (by model file, count and the
generator's sources) and the fits. ``--plots DIR``: each set's figure of the measure's natural and tilted distributions.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import sys
import time
from pathlib import Path

import numpy as np

import dpgp
from dpgp.evaluate import split_in_time
from dpgp.evaluate.realism_checks import realism, recorded_windows
from dpgp.generate.critical import learn_tilt
from dpgp.generate.criticality import EVENT_MEASURES, Estimate, Event, criticality, default_size

sys.path.insert(0, str(Path(__file__).resolve().parent))
from realism import datasets  # noqa: E402  (benches/realism.py, this folder)

STEPS = 16
BATCH = 5_000
CRUDE_HITS = 300  # the crude reference sees the event at least this often
KINEMATIC = ("speed", "acceleration", "turn_rate", "angular_acceleration")


def batches(model, n: int, seed: int, size, tilt=None):
    """Per-scene measures and weights of ``n`` scenes, generated and measured ``BATCH`` at a time."""
    per: dict[str, list[np.ndarray]] = {}
    weights: list[np.ndarray] = []
    for b in range(math.ceil(n / BATCH)):
        k = min(BATCH, n - b * BATCH)
        sc = model.sample_scenarios(k, steps=STEPS, seed=seed + b, tilt=tilt)
        for name, v in criticality(sc, size=size).per_scene().items():
            per.setdefault(name, []).append(np.asarray(v, dtype=np.float64))
        weights.append(np.ones(k) if sc.weights is None else sc.weights)
    return {k: np.concatenate(v) for k, v in per.items()}, np.concatenate(weights)


def generator_version() -> str:
    """What the crude run's scenes depend on besides the fit: the generation layer's sources and the
    core library (a cached run of an older generator is not reused)."""
    root = Path(dpgp.__file__).resolve().parent
    h = hashlib.sha1()
    for f in sorted((root / "generate").glob("*.py")) + sorted(root.glob("_core*")):
        h.update(f.read_bytes())
    return h.hexdigest()


def crude_run(model, path: str, n: int, size, cache: Path | None) -> dict[str, np.ndarray]:
    what = f"{Path(path).resolve()}:{Path(path).stat().st_mtime_ns}:{n}:{STEPS}:{generator_version()}"
    key = hashlib.sha1(what.encode()).hexdigest()[:12]
    kept = None if cache is None else cache / f"crude-{key}.npz"
    if kept is not None and kept.exists():
        return dict(np.load(kept))
    per, _ = batches(model, n, 1_000_000, size)
    if kept is not None:
        kept.parent.mkdir(parents=True, exist_ok=True)
        np.savez(kept, **per)
    return per


def load_model(name: str, load, given: dict[str, str], cache: Path | None):
    frames, tracks = load()
    train, test = split_in_time(frames)
    if name in given:
        path = given[name]
    else:
        path = str((cache or Path(".")) / f"{name}-position-20.npz")
        if not Path(path).exists():
            dpgp.DPGP(iterations=20, seed=0, progress=False).fit(train).save(path)
    return dpgp.DPGP.load(path), path, frames, tracks, train, test


def kinematics(model, tilt, tracks, train, test, n: int, size) -> dict[str, tuple[float, float]]:
    """The realism score's kinematic features of ``n`` natural and ``n`` tilted scenes."""
    rec = recorded_windows(tracks, test, STEPS)
    fixed = recorded_windows(tracks, train, STEPS)
    natural = model.sample_scenarios(n, steps=STEPS, seed=77).to_pandas()
    tilted = model.sample_scenarios(n, steps=STEPS, seed=78, tilt=tilt).to_pandas()
    a = realism(natural, rec, train=fixed).scores["generated"]
    b = realism(tilted, rec, train=fixed).scores["generated"]
    return {f: (float(a[f]), float(b[f])) for f in KINEMATIC}


def plot(path: Path, name: str, crude: np.ndarray, tilted: np.ndarray, w: np.ndarray, thresholds) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    bins = np.linspace(0, max(float(np.max(crude)), float(np.max(tilted))), 60)
    ax.hist(crude, bins=bins, density=True, histtype="step", lw=1.5, label="natural (crude Monte Carlo)")
    ax.hist(tilted, bins=bins, density=True, histtype="step", lw=1.5, label="tilted (as drawn)")
    ax.hist(tilted, bins=bins, weights=w, density=True, histtype="step", ls="--", lw=1.5,
            label="tilted, weighted by the likelihood ratio")  # fmt: skip
    for t in thresholds:
        ax.axvline(t, color="grey", lw=0.8, ls=":")
    ax.set_yscale("log")
    ax.set_xlabel("hardest deceleration in the scene (the data's unit / s²)")
    ax.set_ylabel("density")
    ax.set_title(f"{name}: natural and tilted scenes")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.mkdir(parents=True, exist_ok=True)
    fig.savefig(path / f"critical_{name}.png", dpi=90)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", default="sumo_junction,us101_linked")
    ap.add_argument("--model", action="append", default=[], help="NAME=PATH: a saved fit for data set NAME")
    ap.add_argument("--crude", type=int, default=300_000)
    ap.add_argument("--rates", default="1e-2,3e-3,1e-3")
    ap.add_argument("--tilted", type=int, default=30_000)
    ap.add_argument("--per-round", type=int, default=1_000)
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--realism", type=int, default=2_000)
    ap.add_argument("--cache", type=Path)
    ap.add_argument("--plots", type=Path)
    ap.add_argument("--measure", default="deceleration", choices=sorted(EVENT_MEASURES))
    args = ap.parse_args()
    given = dict(m.split("=", 1) for m in args.model)
    sets = datasets()
    for name in args.only.split(","):
        load, unit = sets[name]
        model, path, frames, tracks, train, test = load_model(name, load, given, args.cache)
        size = default_size(frames.summary)
        t0 = time.perf_counter()
        crude = crude_run(model, path, args.crude, size, args.cache)
        n = len(crude[args.measure])
        print(f"\n{name} ({Path(path).name}; unit {unit}): {n} crude scenes in {time.perf_counter() - t0:.0f} s")
        print(f"  {'event':22s} {'crude rate [95 %]':>30s} {'tilted rate ± se':>24s} {'hits':>6s} {'ESS':>7s} "
              f"{'in 300-hit crude CI (n)':>23s} {'z':>6s} {'accel.':>7s} {'w/ learning':>11s}")  # fmt: skip
        last = None
        values = crude[args.measure]
        above = EVENT_MEASURES[args.measure] == ">"
        for rate in (float(r) for r in args.rates.split(",")):
            threshold = float(np.quantile(values, 1 - rate if above else rate))
            # a measure with an atom at its end (the braking bound; touching vehicles' ttc and gap
            # of 0) has no event that rare: say how many scenes sit there instead
            edge = float(values.max() if above else values.min())
            tol = 1e-9 * max(1.0, abs(edge))
            if abs(threshold - edge) <= tol:
                share = float(np.mean(np.abs(values - edge) <= tol))
                print(f"  {args.measure} at rate {rate:g}: none; {share:.4f} of the crude scenes sit at its "
                      f"{'largest' if above else 'least'} value, {edge:.4g}", flush=True)  # fmt: skip
                continue
            event = Event(args.measure, round(threshold, 3))
            hits = event.happened(crude)
            c = Estimate.of(hits)
            # the reference: a crude run just large enough to see the event 300 times
            first = int(np.searchsorted(np.cumsum(hits), CRUDE_HITS)) + 1
            c300 = Estimate.of(hits[:first]) if hits.sum() >= CRUDE_HITS else None
            tilt, levels = learn_tilt(
                model, event, per_round=args.per_round, rounds=args.rounds, steps=STEPS, seed=5, size=size
            )
            learned = args.per_round * len(levels)
            per, w = batches(model, args.tilted, 2_000_000, size, tilt=tilt)
            e = Estimate.of(event.happened(per), w)
            z = (e.rate - c.rate) / math.hypot(e.stderr, c.stderr)
            inside = "n/a" if c300 is None else str(c300.interval[0] <= e.rate <= c300.interval[1])
            print(f"  {str(event):22s} {c.rate:10.3e} [{c.interval[0]:.3e}, {c.interval[1]:.3e}] "
                  f"{e.rate:11.3e} ± {e.stderr:.2e} {e.hits:6d} {e.ess:7.0f} {inside:>5s} ({first:7d}) {z:6.2f} "
                  f"{e.acceleration:7.2f} {e.acceleration * e.n / (e.n + learned):11.2f}", flush=True)  # fmt: skip
            last = (event, tilt, per, w)
            print(f"    levels {np.round(levels, 2).tolist()}, shift {tilt.shift}", flush=True)
        if last is not None and args.realism > 0:
            k = kinematics(model, last[1], tracks, train, test, args.realism, size)
            print(f"  kinematic realism scores, natural -> tilted toward {last[0]} (ratio):")
            for f, (a, b) in k.items():
                print(f"    {f:22s} {a:.4f} -> {b:.4f} ({b / a:.3f})")
        if last is not None and args.plots is not None and above:
            thresholds = [float(np.quantile(values, 1 - float(r))) for r in args.rates.split(",")]
            plot(args.plots, name, values, last[2][args.measure], last[3], thresholds)


if __name__ == "__main__":
    main()
