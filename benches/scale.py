"""Whole-fit benchmarks of the scalable engine (issue "Fits that scale"). Each configuration runs in
its own process, so that its peak resident memory is its own.

    python benches/scale.py synthetic [--sizes 1000 10000 100000] [--sweeps 20]
    python benches/scale.py us101 [--sweeps 60]          # likelihood x proposal on NGSIM US-101
    python benches/scale.py one KIND N LIKELIHOOD PROPOSAL SWEEPS   # one configuration, JSON out
    python benches/scale.py truth [--frames 1000000] [--sweeps 10]   # found state vs the truth
    python benches/scale.py defaults [--sizes 100000 1000000] [--sweeps 20] [--samplers auto collapsed]
                                     [--max-seconds 1200] [--markdown FILE]   # every default

``--markdown FILE`` (synthetic, us101) also writes the table as a docs page stamped with the commit,
the machine and the date (benches/tables.py), e.g. ``docs/performance/scale.md``.

``synthetic``: dpgp.datasets.synthetic highway and intersection scenes at each size, exact (up to
1,000 frames, beyond which it does not fit in time or memory) and hsgp, default proposal; prints
the median seconds per sweep, initialisation seconds, peak RSS, K and the ARI against the truth.

``defaults``: synthetic highway scenes (``dpgp.datasets.synthetic("highway", n, seed=1)``) fitted with
every default (``DPGP(iterations=S, seed=1)``; ``--samplers`` adds ``sampler=...`` unless it is
``auto``), each in its own process with a wall-time cap: median and slowest seconds per sweep, the
whole fit's seconds, initialisation, the fit's peak resident memory (the data's generation apart),
K, ARI against the truth, and the cores busy over the fit (process CPU seconds over wall seconds).
The standing check of the issue "A sampler that mixes and
scales": 100k and 1M frames.

``truth``: a fit of synthetic highway frames with every default, then the same chain continued
from the true labels: whether the fit's state is the posterior's mode (log joint densities, K,
ARI of both; docs/subcluster.md#measured).

``us101``: the 1000 US-101 frames under the paper's model constants (σ_n² = 1, Gamma(10, 1)) in
all four combinations of likelihood and proposal, then the new defaults. For each: median
seconds per sweep, and the effective sample size (bulk, Vehtari et al. 2021) of the log joint
density and of K over the sweeps after a burn-in of a fifth, per second of those sweeps.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ngsim_us101_frames.tsv"
PAPER = {"noise_var": 1.0, "length_scale_prior": (10.0, 1.0)}


def one(kind: str, n: int, likelihood: str, proposal: str, sweeps: int, paper: bool) -> dict:
    import dpgp
    from dpgp.diagnostics import ess_bulk

    frames = dpgp.read_frames(DATA) if kind == "us101" else dpgp.datasets.synthetic(kind, n, seed=0)
    t = time.perf_counter()
    kw = dict(PAPER) if paper else {}
    m = dpgp.DPGP(iterations=sweeps, likelihood=likelihood, proposal=proposal, seed=1, progress=False, **kw)
    m.fit(frames)
    total = time.perf_counter() - t
    sec = np.asarray(m.history_["seconds"])
    burn = len(sec) // 5
    lj, k = np.asarray(m.history_["log_joint"]), np.asarray(m.history_["n_patterns"], dtype=float)
    out = {
        "data": kind, "frames": len(frames), "likelihood": m.likelihood_, "proposal": proposal,
        "M": None if m.basis_ is None else m.basis_.size, "sweeps": len(sec),
        "median_sweep_s": float(np.median(sec)), "init_s": m.init_seconds_, "fit_s": total,
        "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
        "K": m.n_patterns_, "noise_var": tuple(round(float(x), 4) for x in m.noise_var_),
        "accepted": list(m._sampler.proposal_counts()),
    }  # fmt: skip
    if frames.labels is not None:
        out["ari"] = dpgp.adjusted_rand_index(m.labels_, frames.labels)
    if len(sec) - burn >= 8:
        s = float(sec[burn:].sum())
        out["ess_logjoint_per_s"] = ess_bulk(lj[burn:]) / s
        out["ess_k_per_s"] = ess_bulk(k[burn:]) / s if np.ptp(k[burn:]) > 0 else float("nan")
    return out


def one_defaults(kind: str, n: int, sweeps: int, sampler: str) -> dict:
    """One fit of ``n`` synthetic frames with every default (and ``sampler`` unless "auto") for
    ``sweeps`` sweeps: the sweeps' seconds from ``history_``, the whole fit's wall and CPU seconds
    (the cores busy: CPU over wall, initialisation included), and the fit's own peak memory (the
    data's generation is measured apart: it runs first, its peak is ``data_rss_gb``)."""
    import os

    import dpgp

    t = time.perf_counter()
    frames = dpgp.datasets.synthetic(kind, n, seed=1)
    data_s = time.perf_counter() - t
    data_rss = _rss_gb()
    _reset_peak()
    kw = {} if sampler == "auto" else {"sampler": sampler}
    w0, c0 = time.perf_counter(), sum(os.times()[:2])
    m = dpgp.DPGP(iterations=sweeps, seed=1, progress=False, **kw).fit(frames)
    wall, cpu = time.perf_counter() - w0, sum(os.times()[:2]) - c0
    sec = np.asarray(m.history_["seconds"], dtype=float)
    return {
        "data": kind, "frames": len(frames), "points": frames.n_points, "sampler": getattr(m, "sampler_", "collapsed"),
        "likelihood": m.likelihood_, "M": None if m.basis_ is None else m.basis_.size, "sweeps": len(sec),
        "median_sweep_s": float(np.median(sec)), "max_sweep_s": float(np.max(sec)), "fit_s": wall,
        "cores_busy": cpu / wall, "init_s": m.init_seconds_, "data_s": data_s, "data_rss_gb": data_rss,
        "peak_rss_gb": _peak_gb(), "K": m.n_patterns_, "ari": dpgp.adjusted_rand_index(m.labels_, frames.labels),
        "log_joint": float(m.history_["log_joint"][-1]),
    }  # fmt: skip


def truth(n: int, sweeps: int) -> dict:
    """Whether a fit's state is the posterior's mode or a local one: fit ``n`` synthetic highway
    frames with every default, then continue the same chain from the true labels (each true
    pattern with the hyperparameters of the fitted pattern holding most of it); log joint
    densities, K and ARI of both."""
    import collections

    import dpgp

    frames = dpgp.datasets.synthetic("highway", n, seed=1)
    m = dpgp.DPGP(iterations=sweeps, seed=1, progress=False).fit(frames)
    found = {"K": m.n_patterns_, "ari": dpgp.adjusted_rand_index(m.labels_, frames.labels),
             "log_joint": m.history_["log_joint"][-1]}  # fmt: skip
    true = np.asarray(frames.labels)
    pairs = collections.Counter(zip(true.tolist(), m.labels_.tolist()))
    main = [max((c, k) for (t, k), c in pairs.items() if t == g)[1] for g in range(int(true.max()) + 1)]
    noise = None if m.pattern_noise_var_ is None else np.asarray(m.pattern_noise_var_)[main]
    m._set_state(true, np.asarray(m.length_scales_)[main], m.alpha_, noise)
    m._sync()
    m.set_params(iterations=sweeps).fit(frames, warm_start=True)
    h = m.history_
    return {"frames": n, "sweeps": sweeps, "found": found,
            "from_truth": {"K": h["n_patterns"][sweeps:], "ari": dpgp.adjusted_rand_index(m.labels_, frames.labels),
                           "log_joint": h["log_joint"][-1],
                           "moves": {k: sum(h[k][sweeps:]) for k in ("split_proposed", "split_accepted",
                                                                    "merge_proposed", "merge_accepted")}}}  # fmt: skip


def _rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def _reset_peak() -> None:
    """Reset the kernel's peak-RSS mark (Linux ``clear_refs`` 5), so that the fit's peak is its own."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def _peak_gb() -> float:
    """The peak resident memory since the last reset (``VmHWM``), else the process's maximum."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1e6
    except OSError:
        pass
    return _rss_gb()


def run(*args: object, timeout: float | None = None) -> dict:
    try:
        r = subprocess.run([sys.executable, __file__, *map(str, args)], capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"did not finish in {timeout:g} s", "args": args}
    if r.returncode != 0:
        return {
            "error": r.stderr.strip().splitlines()[-1] if r.stderr.strip() else f"exit {r.returncode}",
            "args": args,
        }
    return json.loads(r.stdout.strip().splitlines()[-1])


def show(rows: list[dict], cols: list[str]) -> None:
    def fmt(v: object) -> str:
        if isinstance(v, float):
            return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"
        return str(v)

    print(" | ".join(cols))
    for r in rows:
        print(" | ".join(fmt(r.get(c, "")) for c in cols) + ("" if "error" not in r else f"  ERROR {r['error']}"))
    sys.stdout.flush()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("synthetic")
    s.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000])
    s.add_argument("--sweeps", type=int, default=20)
    s.add_argument("--markdown", metavar="FILE", help="also write the table as a stamped docs page")
    u = sub.add_parser("us101")
    u.add_argument("--sweeps", type=int, default=60)
    u.add_argument("--markdown", metavar="FILE", help="also write the table as a stamped docs page")
    o = sub.add_parser("one")
    for name in ("kind", "n", "likelihood", "proposal", "sweeps", "paper"):
        o.add_argument(name)
    d = sub.add_parser("defaults")
    d.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    d.add_argument("--sweeps", type=int, default=20)
    d.add_argument("--samplers", nargs="+", default=["auto"], help="auto, subcluster, collapsed")
    d.add_argument("--max-seconds", type=float, default=1200, help="wall-time cap of each configuration")
    d.add_argument("--markdown", metavar="FILE", help="also write the table as a stamped docs page")
    tr = sub.add_parser("truth")
    tr.add_argument("--frames", type=int, default=1_000_000)
    tr.add_argument("--sweeps", type=int, default=10)
    od = sub.add_parser("one-defaults")
    for name in ("kind", "n", "sweeps", "sampler"):
        od.add_argument(name)
    a = ap.parse_args()
    if a.cmd == "one":
        print(json.dumps(one(a.kind, int(a.n), a.likelihood, a.proposal, int(a.sweeps), a.paper == "True")))
        return
    if a.cmd == "truth":
        print(json.dumps(truth(a.frames, a.sweeps)))
        return
    if a.cmd == "one-defaults":
        print(json.dumps(one_defaults(a.kind, int(a.n), int(a.sweeps), a.sampler)))
        return
    if a.cmd == "defaults":
        cols = ["frames", "sampler", "likelihood", "M", "sweeps", "median_sweep_s", "max_sweep_s", "fit_s",
                "cores_busy", "init_s", "peak_rss_gb", "data_rss_gb", "K", "ari"]  # fmt: skip
        rows = []
        for n in a.sizes:
            for sampler in a.samplers:
                rows.append(run("one-defaults", "highway", n, a.sweeps, sampler, timeout=a.max_seconds))
                show(rows[-1:], cols)
        print()
        show(rows, cols)
        if a.markdown:
            intro = (
                'Synthetic highway scenes (`dpgp.datasets.synthetic("highway", n, seed=1)`, about 12 vehicles a\n'
                "frame, three true patterns) fitted with every default, each configuration in its own process:\n"
                "median and slowest seconds per sweep, the whole fit's seconds, the cores busy over the fit (CPU\n"
                "seconds over wall seconds), initialisation, the fit's peak resident memory (the data's generation\n"
                "apart: data_rss_gb), K and the adjusted Rand index against the truth."
            )
            _markdown(a.markdown, "Scaling with every default", intro, rows, cols)
        return
    if a.cmd == "synthetic":
        rows = []
        cols = [
            "data",
            "frames",
            "likelihood",
            "M",
            "sweeps",
            "median_sweep_s",
            "init_s",
            "fit_s",
            "peak_rss_gb",
            "K",
            "ari",
        ]
        for kind in ("highway", "intersection"):
            for n in a.sizes:
                for lik in ("exact", "hsgp") if n <= 1000 else ("hsgp",):
                    # exact costs tens of seconds per sweep here: a few sweeps give its speed
                    sweeps = a.sweeps if lik == "hsgp" else min(a.sweeps, 2)
                    rows.append(run("one", kind, n, lik, "informed", sweeps, True))
                    show(rows[-1:], cols)
        print()
        show(rows, cols)
        if a.markdown:
            intro = (
                "Whole fits of `dpgp.datasets.synthetic` scenes under the paper's model constants (σ_n² = 1,\n"
                "Gamma(10, 1) length scales), informed proposals, each configuration in its own process:\n"
                "median seconds per sweep, initialisation, peak resident memory, K and the adjusted Rand index\n"
                "against the true patterns. Exact runs at most 2 sweeps and only up to 1,000 frames."
            )
            _markdown(a.markdown, "Scaling on synthetic scenes", intro, rows, cols)
    else:
        rows = []
        cols = [
            "likelihood",
            "proposal",
            "M",
            "sweeps",
            "median_sweep_s",
            "K",
            "ess_logjoint_per_s",
            "ess_k_per_s",
            "accepted",
            "noise_var",
        ]
        for lik in ("exact", "hsgp"):
            for prop in ("full", "informed"):
                rows.append(run("one", "us101", 0, lik, prop, a.sweeps, True))
                show(rows[-1:], cols)
        rows.append(
            {**run("one", "us101", 0, "auto", "informed", a.sweeps, False), "proposal": "informed (all defaults)"}
        )
        print()
        show(rows, cols)
        if a.markdown:
            intro = (
                "The 1000 NGSIM US-101 frames (the shared data) under the paper's constants in every combination\n"
                "of likelihood and proposal, then every default: median seconds per sweep, K, and the bulk\n"
                "effective sample size of the log joint density and of K per second of the sweeps after burn-in."
            )
            _markdown(a.markdown, "NGSIM US-101: likelihood × proposal", intro, rows, cols)


def _markdown(path: str, title: str, intro: str, rows: list[dict], cols: list[str]) -> None:
    import tables  # benches/tables.py, beside this script

    ok = [r for r in rows if "error" not in r]
    failed = [r for r in rows if "error" in r]
    note = "".join(f"\n\nFailed: `{r['args']}`: {r['error']}" for r in failed)
    tables.write_page(path, title, intro, tables.markdown_table(ok, cols) + note, tables._command())


if __name__ == "__main__":
    main()
