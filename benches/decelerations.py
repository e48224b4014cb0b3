"""Generated against recorded criticality (issue 35): per 8 s scene, the hardest deceleration (50th,
90th, 99th percentiles and largest), the shares of scenes whose vehicles' boxes touch, with a
time to collision under 1 s and with a post-encroachment time under 1 s, and the medians of the
least time to collision and gap, for ``--scenes`` scenes of every default of
``sample_scenarios`` against the recorded test period cut into scenes of as many steps.

    python benches/decelerations.py [--only us101_linked,sumo_junction,peachtree] [--models DIR] [--scenes 3000]

``--models DIR``: the fits of ``benches/realism.py --models DIR`` (fitted there when absent, its
settings: the training 70 %, 20 sweeps, seed 0), so that a change to generation is compared
before and after on the same fits.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import dpgp
from dpgp.evaluate import split_in_time
from dpgp.generate.criticality import criticality, default_size

sys.path.insert(0, str(Path(__file__).resolve().parent))
from realism import datasets  # noqa: E402  (benches/realism.py, this folder)

STEPS = 16


def row(per: dict[str, np.ndarray]) -> str:
    d = per["deceleration"]
    q = " / ".join(f"{np.percentile(d, p):.1f}" for p in (50, 90, 99))
    return (
        f"{q} / {d.max():.1f}   touching {np.mean(per['collision']):.4f}   ttc<1s {np.mean(per['ttc'] < 1.0):.4f}"
        f"   pet<1s {np.mean(per['pet'] < 1.0):.4f}   median ttc {np.median(per['ttc']):.2f} s"
        f"   median gap {np.median(per['gap']):.2f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", default="us101_linked,sumo_junction,peachtree")
    ap.add_argument("--models", type=Path, help="folder of benches/realism.py's fits")
    ap.add_argument("--scenes", type=int, default=3000)
    args = ap.parse_args()
    sets = datasets()
    for name in args.only.split(","):
        load, unit = sets[name]
        frames, _ = load()
        train, test = split_in_time(frames)
        path = None if args.models is None else args.models / f"{name}-position-exact-20-thin1.npz"
        if path is not None and path.exists():
            model = dpgp.DPGP.load(path)
        else:  # as benches/realism.py fits (and keeps) it
            model = dpgp.DPGP(iterations=20, seed=0, progress=False).fit(train)
            if path is not None:
                path.parent.mkdir(parents=True, exist_ok=True)
                model.save(path)
        size = default_size(frames.summary)
        recorded = criticality(test, steps=STEPS, size=size).per_scene()
        generated = criticality(model.sample_scenarios(args.scenes, steps=STEPS, seed=5), size=size).per_scene()
        print(f"{name}: hardest deceleration ({unit}/s²) p50 / p90 / p99 / largest")
        print(f"  recorded  ({len(recorded['deceleration'])} scenes): {row(recorded)}")
        print(f"  generated ({args.scenes} scenes): {row(generated)}")


if __name__ == "__main__":
    main()
