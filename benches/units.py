"""Unit invariance on real data (issue 9): NGSIM US-101 in feet and converted to metres, fitted
with every default from the same seed on the first 70% of the frames (split in time), compared
on the partition (ARI) and on the held-out log density of the last 30%, which must agree up to
the Jacobian of the change of units (2 log c per vehicle).

    python benches/units.py [--iterations 20] [--proposal informed|full] [--frames 1000]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import dpgp
from dpgp.evaluate import split_in_time

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ngsim_us101_frames.tsv"
FT = 0.3048  # metres per foot


def scaled(frames: dpgp.Frames, c: float) -> dpgp.Frames:
    return dpgp.Frames(frames.ids, frames.offsets, frames.xy * c, frames.v * c, frames.labels)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=20)
    ap.add_argument("--proposal", default="informed", choices=("informed", "full"))
    ap.add_argument("--frames", type=int, default=1000)
    args = ap.parse_args()
    train, test = split_in_time(dpgp.read_frames(DATA)[: args.frames])
    fits = {}
    for unit, c in (("ft", 1.0), ("m", FT)):
        t = time.perf_counter()
        m = dpgp.DPGP(iterations=args.iterations, seed=0, progress=False, proposal=args.proposal, store_labels=True)
        m.fit(scaled(train, c))
        score = m.score_samples(scaled(test, c), positions=False)
        fits[unit] = (m, score, time.perf_counter() - t)
    (ft, s_ft, t_ft), (me, s_m, t_m) = fits["ft"], fits["m"]
    jac = 2 * test.sizes * np.log(FT)
    ari = [dpgp.adjusted_rand_index(a, b) for a, b in zip(ft.label_trace_, me.label_trace_)]
    print(f"US-101, {len(train)} train / {len(test)} test frames, {args.iterations} sweeps, proposal={args.proposal}")
    print(
        f"  K: ft {ft.n_patterns_}, m {me.n_patterns_}; ARI of the final partitions {ari[-1]:.4f} (min over sweeps {min(ari):.4f})"
    )
    print(f"  noise ft {ft.noise_var_}, m / FT^2 {tuple(np.asarray(me.noise_var_) / FT**2)}")
    print(
        f"  held-out log density per vehicle: ft {s_ft.sum() / test.n_points:.6f}, "
        f"m + Jacobian {(s_m + jac).sum() / test.n_points:.6f}, max |difference| per frame {np.max(np.abs(s_m + jac - s_ft)):.2e}"
    )
    print(f"  seconds: ft {t_ft:.1f}, m {t_m:.1f}")


if __name__ == "__main__":
    main()
