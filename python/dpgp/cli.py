"""The ``dpgp`` command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .exceptions import DpgpError


def _demo(args: argparse.Namespace) -> int:
    import numpy as np

    from . import gp

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    # A two-lane highway stretch: vehicles drift towards the right lane as y grows.
    xy = np.column_stack([rng.uniform(0, 24, 300), rng.uniform(0, 200, 300)])
    v = np.column_stack([np.where(xy[:, 0] < 12, 0.8, 0.0), 30 - 5 * (xy[:, 0] > 12)]) + rng.normal(0, 0.5, (300, 2))
    p = gp.GPParams((6.0, 40.0), signal_var=tuple(v.var(axis=0)), noise_var=0.25, mean=tuple(v.mean(axis=0)))
    print(f"log marginal likelihood of 300 synthetic vehicles: {gp.log_marginal_likelihood(xy, v, p):.2f}")
    gx, gy = np.meshgrid(np.linspace(0, 24, 12), np.linspace(0, 200, 25))
    q = np.column_stack([gx.ravel(), gy.ravel()])
    mean, var = gp.posterior(xy, v, q, p)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4, 8))
    ax.scatter(xy[:, 0], xy[:, 1], s=4, c="0.6", label="observations")
    ax.quiver(q[:, 0], q[:, 1], mean[:, 0], mean[:, 1], np.sqrt(var.sum(axis=1)), cmap="viridis")
    ax.set(xlabel="x", ylabel="y", title="GP posterior mean velocity")
    path = out / "gp_field.png"
    fig.savefig(path, dpi=100, bbox_inches="tight")
    print(f"wrote {path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dpgp", description="Learn motion patterns from traffic data.")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run on built-in synthetic data and write figures")
    demo.add_argument("--out", default="dpgp-demo", help="directory for the figures (default: ./dpgp-demo)")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    demo.set_defaults(func=_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except (DpgpError, OSError) as e:
        print(f"dpgp: error: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
