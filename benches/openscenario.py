"""OpenSCENARIO export at scale (issue 18): 1,000 scenarios of 40 steps from a US-101 model (NGSIM,
feet) and from an ETH pedestrian model (BIWI ETH, metres), each written as OpenSCENARIO 1.2
files; every file validated against scenariogeneration's OpenSCENARIO_1_2.xsd, every file read
back with scenariogeneration's reader and compared with the generated table (t, x, y within
1e-6 s and m; which vehicles are deleted, and when); and the export time per scenario as a ratio
to the generation time.

    python benches/openscenario.py                       # fits both models (a few minutes), then the rest
    python benches/openscenario.py --n 200 --only us101
    python benches/openscenario.py --us101-model us101.npz --eth-model eth.npz --json results.json

Models: US-101, the paper's 1000 frames (``read_frames``; that file records no unit, so the export
is told ``units="ft"``); ETH, ``read_tracks(preset="eth_ucy")`` framed at 0.4 s (its model
records metres and pedestrians). Both are fitted with every default and ``--iterations`` sweeps
unless a model file is given. Generation is ``model.sample_scenarios(n, steps, seed)``; export is
``Scenarios.to_openscenario(dir, model, ...)`` with scenariogeneration already imported (its
import, about 3 s once per process, is reported apart). Times are wall-clock medians over
``--repeats`` runs.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

import dpgp
from dpgp.generate import openscenario as osc

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
TOL = 1e-6


def fit_model(which: str, iterations: int, seed: int) -> dpgp.DPGP:
    if which == "us101":
        frames = dpgp.read_frames(DATA / "ngsim_us101_frames.tsv")
    else:
        frames = dpgp.make_frames(dpgp.read_tracks(DATA / "eth_ucy_biwi_eth.txt", preset="eth_ucy"), dt=0.4)
    t0 = time.perf_counter()
    model = dpgp.DPGP(iterations=iterations, seed=seed, progress=False).fit(frames)
    print(f"  fitted {which}: {len(frames)} frames, {model.n_patterns_} patterns, {time.perf_counter() - t0:.0f} s")
    return model


def check(paths: list[Path], table, scale: float, kind: str) -> dict:
    """Validate every file and compare its trajectories with the table."""
    invalid = []
    worst = {"t": 0.0, "x": 0.0, "y": 0.0}
    rows = objects = deleted = 0
    wrong_deletions = wrong_kind = 0
    end = float(table["t"].max())
    table = table.sort_values(["scenario", "vehicle", "t"], kind="stable")
    by_scenario = dict(iter(table.groupby("scenario")))
    for s, p in enumerate(paths):
        errors = osc.validate(p)
        if errors:
            invalid.append((p.name, errors[:2]))
        back = osc.read_openscenario(p)
        want = by_scenario.get(s)
        n_want = 0 if want is None else len(want)
        if len(back) != n_want:
            worst = {k: float("inf") for k in worst}
            continue
        if n_want:
            assert back["vehicle"].tolist() == want["vehicle"].tolist()
            worst["t"] = max(worst["t"], float(np.abs(back["t"].to_numpy() - want["t"].to_numpy()).max()))
            worst["x"] = max(worst["x"], float(np.abs(back["x"].to_numpy() - want["x"].to_numpy() * scale).max()))
            worst["y"] = max(worst["y"], float(np.abs(back["y"].to_numpy() - want["y"].to_numpy() * scale).max()))
            last = want.groupby("vehicle")["t"].max()
            expect = {f"{kind}{v}": float(t) for v, t in last.items() if t < end}
            wrong_deletions += back.attrs["deleted"] != expect
        wrong_kind += any(k != kind for k in back.attrs["kinds"].values())
        rows += len(back)
        objects += len(back.attrs["kinds"])
        deleted += len(back.attrs["deleted"])
    return {
        "files": len(paths), "invalid": len(invalid), "invalid_examples": invalid[:3], "max_error": worst,
        "within_tolerance": all(v <= TOL for v in worst.values()) and not wrong_deletions,
        "wrong_deletions": wrong_deletions, "wrong_object_type": wrong_kind, "vertices": rows, "objects": objects,
        "deleted_on_leaving_roi": deleted,
    }  # fmt: skip


def run(which: str, model: dpgp.DPGP, n: int, steps: int, seed: int, repeats: int, out: Path) -> dict:
    units = "ft" if which == "us101" else None  # the US-101 frames file records no unit
    scale = osc.UNITS["ft"] if units else 1.0
    gen, exp, sizes = [], [], []
    for r in range(repeats):
        t0 = time.perf_counter()
        scenarios = model.sample_scenarios(n, steps=steps, seed=seed)
        t1 = time.perf_counter()
        target = out / f"{which}_{r}"
        paths = scenarios.to_openscenario(target, model, units=units, seed=seed, description=f"bench {which}")
        t2 = time.perf_counter()
        gen.append(t1 - t0)
        exp.append(t2 - t1)
        sizes.append(sum(p.stat().st_size for p in paths))
    kind = "pedestrian" if which == "eth" else "vehicle"
    t0 = time.perf_counter()
    result = check(paths, scenarios.to_pandas(), scale, kind)
    result["check_seconds"] = time.perf_counter() - t0
    g, e = statistics.median(gen), statistics.median(exp)
    result.update({
        "model": which, "scenarios": n, "steps": steps, "vehicles": int(scenarios.counts.sum()),
        "generation_s": g, "export_s": e, "generation_ms_per_scenario": 1e3 * g / n,
        "export_ms_per_scenario": 1e3 * e / n, "export_over_generation": e / g, "bytes": int(statistics.median(sizes)),
        "runs": {"generation_s": gen, "export_s": exp},
    })  # fmt: skip
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--iterations", type=int, default=20, help="Gibbs sweeps when a model is fitted here")
    ap.add_argument("--us101-model", help="a US-101 model file to use instead of fitting one")
    ap.add_argument("--eth-model", help="an ETH model file to use instead of fitting one")
    ap.add_argument("--only", choices=("us101", "eth"))
    ap.add_argument("--out", help="directory for the files (default: a temporary one, removed)")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args()

    t0 = time.perf_counter()
    osc.require_scenariogeneration()
    print(f"scenariogeneration import: {time.perf_counter() - t0:.2f} s (once per process, not in the export times)")
    print(f"schema: {osc.schema_path()} (OpenSCENARIO 1.{osc.OSC_MINOR})")
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out) if args.out else Path(tmp)
        for which in ("us101", "eth"):
            if args.only and which != args.only:
                continue
            given = args.us101_model if which == "us101" else args.eth_model
            model = dpgp.DPGP.load(given) if given else fit_model(which, args.iterations, args.seed)
            r = run(which, model, args.n, args.steps, args.seed, args.repeats, out)
            results.append(r)
            print(
                f"{which}: {r['scenarios']} scenarios x {r['steps']} steps, {r['vehicles']} {('pedestrians' if which == 'eth' else 'vehicles')}, "
                f"{r['vertices']} trajectory rows, {r['deleted_on_leaving_roi']} deleted on leaving the ROI\n"
                f"  valid against the XSD: {r['files'] - r['invalid']} of {r['files']}; round trip max |error| "
                f"t {r['max_error']['t']:.1e} s, x {r['max_error']['x']:.1e} m, y {r['max_error']['y']:.1e} m "
                f"({'all within' if r['within_tolerance'] else 'NOT within'} 1e-6; deletions wrong in {r['wrong_deletions']} files)\n"
                f"  generation {r['generation_ms_per_scenario']:.2f} ms/scenario, export {r['export_ms_per_scenario']:.2f} ms/scenario: "
                f"export / generation = {r['export_over_generation']:.3f}; {r['bytes'] / r['files'] / 1e3:.0f} kB a file; "
                f"checking took {r['check_seconds']:.0f} s"
            )  # fmt: skip
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
