"""The cost model of ``likelihood="auto"`` (dpgp.engine_cost): calibration and the check that auto
picks the faster engine (issue 16, item 3).

    python benches/engine_cost.py calibrate [--out engine_cost.jsonl] [--engines subcluster]   # time sweeps of each engine
    python benches/engine_cost.py fit engine_cost.jsonl                 # NNLS fit of the coefficients
    python benches/engine_cost.py check [--only NAME,...] [--sweeps 5]  # auto against each engine
    python benches/engine_cost.py probe [--only NAME,...] [--seeds 5]   # auto's accuracy probe by seed

``calibrate`` fits synthetic and real scenes of several sizes with each engine (exact; hsgp on the collapsed
sampler, "hsgp"; hsgp on the sub-cluster sampler, "subcluster"; fixed noise, so
that no pilot runs) and records, per sweep after the first, its seconds and the cost model's
features of the state it started from; ``fit`` fits the coefficients (non-negative least squares
on relative error) and prints them with the median and largest relative error of the
prediction. ``check``: on every shared data set and the synthetic scenes at 200, 1,000 and
10,000 frames, with every default, the median sweep seconds of exact, of hsgp on each sampler and
of auto's pick, auto's predicted seconds, and the held-out log density (last 30% of the frames,
nats per vehicle) of each. Exact is skipped where its predicted sweep exceeds ``--max-exact``
seconds or its memory the budget (then its predicted seconds are shown).
``probe``: per scene (training part) and seed, the engine ``likelihood="auto"`` picks (a fit of
one sweep) and the probe's statistics on that seed's hsgp initialisation: the gap of its largest
pattern alone (the probe before issue 16's seed-stability fix) and the points-weighted gap over
all its patterns (``engine_cost.partition_gap``; auto takes the median over the seeds
``engine_cost.PROBE_SEEDS``), whether or not the cost model lets the probe run.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import dpgp
from dpgp.evaluate import split_in_time
from dpgp.model import engine_cost

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _real(name: str):
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_evaluate", Path(__file__).with_name("evaluate.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod.datasets()[name][0]()[0]


def scenes(names: list[str] | None = None) -> dict:
    """name -> loader of frames: every shared data set, then the synthetic scenes."""
    out = {
        n: (lambda n=n: _real(n))
        for n in ("us101", "peachtree", "eth", "zara01", "sumo_left_turn", "lankershim", "sumo_grid")
    }
    for kind in ("highway", "intersection"):
        for n in (200, 1000, 10000):
            out[f"synthetic_{kind}_{n}"] = lambda kind=kind, n=n: dpgp.datasets.synthetic(kind, n, seed=0)
    return {k: v for k, v in out.items() if names is None or k in names}


def _timed_fit(frames, likelihood: str, sweeps: int, **kw) -> dpgp.DPGP:
    m = dpgp.DPGP(iterations=sweeps, likelihood=likelihood, seed=1, progress=False, store_labels=True, **kw)
    return m.fit(frames)


def calibrate(out: str, engines: list[str]) -> None:
    configs = []
    for kind in ("highway", "intersection"):
        for n in (50, 100, 200, 400):
            configs += [(f"synthetic_{kind}", n, e) for e in ("exact", "hsgp", "subcluster")]
        for n in (1000, 3000, 10000):
            configs += [(f"synthetic_{kind}", n, e) for e in ("hsgp", "subcluster")]
        configs.append((f"synthetic_{kind}", 100_000, "subcluster"))  # where its pass dominates
    for name, n in (("us101", 100), ("us101", 300), ("eth", 300), ("zara01", 400), ("peachtree", 600),
                    ("sumo_left_turn", 100), ("lankershim", 25)):  # fmt: skip
        configs += [(name, n, e) for e in ("exact", "hsgp", "subcluster")]
    with open(out, "a") as fh:
        for name, n, lik in (c for c in configs if c[2] in engines):
            if name.startswith("synthetic_"):
                frames = dpgp.datasets.synthetic(name.split("_", 1)[1], n, seed=0)
                kw = {"noise_var": 0.49}
            else:
                frames = _real(name)[:n]
                kw = {"noise_var": tuple(0.05 * frames.v.var(axis=0))}
            sweeps = 4 if lik == "exact" else 6
            if lik != "exact":  # engine "hsgp" is hsgp on the collapsed sampler, "subcluster" on its own
                kw["sampler"] = "collapsed" if lik == "hsgp" else "subcluster"
            m = _timed_fit(frames, "exact" if lik == "exact" else "hsgp", sweeps, **kw)
            sizes = frames.sizes
            M = None if m.basis_ is None else m.basis_.size
            for t in range(1, sweeps):  # sweep t started from the state after sweep t - 1
                pts = engine_cost.pattern_points(m.label_trace_[t - 1], sizes)
                row = {"scene": name, "frames": n, "engine": lik, "M": M, "sweep": t,
                       "seconds": m.history_["seconds"][t], "pattern_points": pts[pts > 0].tolist(),
                       "frame_sizes": sizes.tolist()}  # fmt: skip
                fh.write(json.dumps(row) + "\n")
            print(
                f"{name} {n} {lik}: M={M} K={m.n_patterns_} median sweep {np.median(m.history_['seconds'][1:]):.4f} s",
                flush=True,
            )


def fit(path: str) -> None:
    from scipy.optimize import least_squares, nnls

    rows = [json.loads(line) for line in open(path)]
    # One point per configuration: the median over its sweeps after the second (the first ones
    # warm caches and threads up), which tames the noise of a shared machine.
    configs: dict = {}
    for x in rows:
        x["features"] = engine_cost.features(x["engine"], x["pattern_points"], x["frame_sizes"], x["M"]).tolist()
        if x["sweep"] >= 2:
            configs.setdefault((x["scene"], x["frames"], x["engine"]), []).append(x)
    for engine in engine_cost.ENGINES:
        r = [{**v[0], "sweep": "median"} for k, v in configs.items() if k[2] == engine]
        X = np.array([np.median([x["features"] for x in v], axis=0) for k, v in configs.items() if k[2] == engine])
        y = np.array([np.median([x["seconds"] for x in v]) for k, v in configs.items() if k[2] == engine])
        scale = X.max(axis=0)
        scale[scale == 0] = 1
        start, _ = nnls(X / scale / y[:, None], np.ones(len(y)))  # relative error, then log error:
        # predictions too low and too high by the same factor weigh the same
        fit = least_squares(lambda c: np.log(X / scale @ c + 1e-12) - np.log(y), start + 1e-6, bounds=(0, np.inf))
        coef = fit.x / scale
        rel = X @ coef / y - 1
        log_err = np.abs(np.log(X @ coef / y))
        print(f"{engine}: coefficients {tuple(float(f'{c:.3g}') for c in coef)}; {len(y)} configurations; "
              f"relative error median {np.median(np.abs(rel)):.2f}, max {np.max(np.abs(rel)):.2f}; "
              f"factor off median {np.exp(np.median(log_err)):.2f}, max {np.exp(np.max(log_err)):.2f}")  # fmt: skip
        for i in np.argsort(-np.abs(rel)):
            print(f"   {r[i]['scene']} {r[i]['frames']}: {y[i]:.4f} s, predicted {X[i] @ coef:.4f} s")


def check(names: list[str] | None, sweeps: int, max_exact: float) -> None:
    import pandas as pd

    rows = []
    for name, load in scenes(names).items():
        frames = load()
        train, test = split_in_time(frames)
        row: dict = {"scene": name, "frames": len(train), "points": train.n_points}
        t = time.perf_counter()
        auto = dpgp.DPGP(iterations=sweeps, seed=0, progress=False).fit(train)
        row["auto_fit_s"] = time.perf_counter() - t
        ch = auto.engine_choice_
        row.update(pick=auto.likelihood_, sizes_from=ch["sizes_from"], M=ch["basis"],
                   pred_exact_s=ch["exact_seconds"], pred_hsgp_s=ch["hsgp_seconds"])  # fmt: skip
        row["auto_sweep_s"] = float(np.median(auto.history_["seconds"]))
        # The other engine with every default too (noise sampled in the chain, as auto's), so that
        # the two sweeps do the same work.
        fixed = {"length_scale_prior": auto.length_scale_prior_}
        picked = "exact" if auto.likelihood_ == "exact" else ("hsgp" if auto.sampler_ == "collapsed" else "subcluster")
        row["pick"] = picked
        for engine in engine_cost.ENGINES:  # hsgp: on the collapsed sampler; subcluster: hsgp on its own
            if engine == picked:
                m = auto
            elif engine == "exact" and (ch["exact_seconds"] > max_exact or not ch["exact_fits"]):
                row["exact_sweep_s"], row["exact_density"] = np.nan, np.nan
                continue
            else:
                kw = {"likelihood": "exact"} if engine == "exact" else {"likelihood": "hsgp", "sampler": "collapsed"}
                if engine == "subcluster":
                    kw["sampler"] = "subcluster"
                m = dpgp.DPGP(iterations=sweeps, seed=0, progress=False, **kw, **fixed).fit(train)
            row[f"{engine}_sweep_s"] = float(np.median(m.history_["seconds"]))
            row[f"{engine}_K"] = m.n_patterns_
            row[f"{engine}_density"] = float(m.evaluate(test).table.loc["dpgp", "log_density"])
        fastest = min(
            engine_cost.ENGINES, key=lambda e: row[f"{e}_sweep_s"] if np.isfinite(row[f"{e}_sweep_s"]) else np.inf
        )
        row["auto_picked_faster"] = picked == fastest or (picked != "exact" and fastest != "exact")
        rows.append(row)
        print(json.dumps(row, default=float), flush=True)
    table = pd.DataFrame(rows).set_index("scene")
    with pd.option_context("display.width", 250, "display.max_columns", 40):
        print(table.to_string(float_format=lambda x: f"{x:.4g}"))


def probe(names: list[str] | None, seeds: int) -> None:
    for name, load in scenes(names).items():
        train, _ = split_in_time(load())
        hsgp = dpgp.DPGP(iterations=1, likelihood="hsgp", seed=0, progress=False).fit(train)
        for seed in range(seeds):
            t = time.perf_counter()
            auto = dpgp.DPGP(iterations=1, seed=seed, progress=False).fit(train)
            auto_s = time.perf_counter() - t
            labels = hsgp._probe_labels(train, seed)
            pts = engine_cost.pattern_points(labels, train.sizes)
            largest = engine_cost.resolution_gap(
                *engine_cost.probe_points(labels, train, int(np.argmax(pts))), hsgp.params_, hsgp.basis_
            )
            weighted = engine_cost.partition_gap(labels, train, hsgp.params_, hsgp.basis_)
            ch = auto.engine_choice_
            row = {"scene": name, "seed": seed, "pick": auto.likelihood_, "sizes_from": ch["sizes_from"],
                   "predicted_exact_over_hsgp": ch["exact_seconds"] / ch["hsgp_seconds"],
                   "auto_gap": ch["resolution_gap"], "largest_pattern_gap": largest, "partition_gap": weighted,
                   "K_init": int((pts > 0).sum()), "auto_fit_s": auto_s}  # fmt: skip
            print(json.dumps(row), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("calibrate")
    c.add_argument("--out", default="engine_cost.jsonl")
    c.add_argument("--engines", nargs="+", default=list(engine_cost.ENGINES), choices=engine_cost.ENGINES)
    f = sub.add_parser("fit")
    f.add_argument("path")
    k = sub.add_parser("check")
    k.add_argument("--only")
    k.add_argument("--sweeps", type=int, default=5)
    k.add_argument("--max-exact", type=float, default=30.0, help="skip exact where its predicted sweep is longer (s)")
    p = sub.add_parser("probe")
    p.add_argument("--only")
    p.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args()
    if args.cmd == "probe":
        probe(args.only.split(",") if args.only else None, args.seeds)
    elif args.cmd == "calibrate":
        calibrate(args.out, args.engines)
    elif args.cmd == "fit":
        fit(args.path)
    else:
        check(args.only.split(",") if args.only else None, args.sweeps, args.max_exact)


if __name__ == "__main__":
    sys.exit(main())
