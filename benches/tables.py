"""Markdown tables of benchmark results for the documentation site, stamped with where they came from.

A table in ``docs/performance/`` is written by the bench that measured it (``--markdown FILE``), or
rendered here from results a bench recorded earlier; no figure in the docs is typed by hand:

    python benches/scale.py synthetic --sizes 200 2000 --sweeps 10 --markdown docs/performance/scale.md
    python benches/tables.py engine-cost [--markdown docs/performance/engine-cost.md]
    python benches/tables.py cargo-bench [--markdown docs/performance/cargo-bench.md]   # after cargo bench

Every page carries the stamp: the commit (``git rev-parse --short HEAD``, marked ``+dirty`` when the
tree had uncommitted changes), the CPU model, the core count, the date and the command.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _git(*args: str) -> str:
    r = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)
    return r.stdout.strip() if r.returncode == 0 else ""


def cpu_model() -> str:
    """The CPU's model name (from /proc/cpuinfo on Linux, else what platform reports)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def stamp(command: str, commit: str | None = None, date: str | None = None, recorded: str | None = None) -> str:
    """The provenance line of a table: commit, machine, date and the command that regenerates it.

    ``recorded``: for results measured earlier and only rendered now, the commit that recorded
    them; the machine and date are then the renderer's, and the stamp says so.
    """
    if recorded is not None:
        date = date or datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        return (
            f"Recorded in the commit `{recorded}` (the results file does not name the machine); rendered on\n"
            f"{cpu_model()} ({os.cpu_count()} cores), {date}, by `{command}`."
        )
    if commit is None:
        commit = _git("rev-parse", "--short", "HEAD") or "unknown"
        if _git("status", "--porcelain", "--untracked-files=no"):
            commit += "+dirty"
    date = date or datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return (
        f"Generated at commit `{commit}` on {cpu_model()} ({os.cpu_count()} cores), {date}, by\n"
        f"`{command}`. Timings on a shared machine are noisy: compare rows of one run, not runs."
    )


def _cell(v: object) -> str:
    if v is None or v == "":
        return "—"
    if isinstance(v, float):
        if v != v:
            return "—"
        return f"{v:.3g}" if abs(v) < 1000 else f"{v:,.0f}"
    return str(v).replace("|", "\\|")


def markdown_table(rows: Iterable[dict], cols: Sequence[str], headers: Sequence[str] | None = None) -> str:
    """A GitHub/mkdocs Markdown table of ``rows`` (dicts) over ``cols``; floats to 3 significant digits."""
    headers = list(headers or cols)
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(_cell(r.get(c)) for c in cols) + " |" for r in rows]
    return "\n".join(lines)


def write_page(path: str | os.PathLike, title: str, intro: str, table: str, command: str, **stamp_kw: str) -> None:
    """Write a docs page: title, what the table measures, the table, and its stamp."""
    text = f"# {title}\n\n{intro.strip()}\n\n{table}\n\n{stamp(command, **stamp_kw)}\n"
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(text, encoding="utf-8")
    print(f"wrote {path}", file=sys.stderr)


def _command() -> str:
    return "python " + " ".join([os.path.relpath(sys.argv[0], ROOT), *sys.argv[1:]])


def engine_cost(markdown: str | None) -> None:
    """Median seconds per sweep of the engine-cost calibration runs (benches/engine_cost.py)."""
    path = ROOT / "benches" / "results" / "engine_cost_calibration.jsonl"
    groups: dict[tuple, list[dict]] = {}
    for line in path.read_text().splitlines():
        if line.strip():
            r = json.loads(line)
            groups.setdefault((r["scene"], r["frames"], r["engine"], r["M"]), []).append(r)
    rows = [
        {
            "scene": scene,
            "frames": frames,
            "engine": engine,
            "M": m,
            "sweeps": len(rs),
            "median_s": statistics.median(r["seconds"] for r in rs),
            "points": int(sum(rs[0]["frame_sizes"])),
        }
        for (scene, frames, engine, m), rs in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1], kv[0][2]))
    ]
    cols = ["scene", "frames", "points", "engine", "M", "sweeps", "median_s"]
    table = markdown_table(rows, cols, ["scene", "frames", "points", "engine", "M", "sweeps", "s / sweep (median)"])
    if markdown is None:
        print(table)
        return
    # The runs were recorded earlier: stamp them with the commit that recorded the file, not HEAD.
    recorded = _git("log", "-1", "--format=%h %cs", "--", str(path.relative_to(ROOT))).split() or ["unknown", ""]
    intro = (
        'The sweeps that calibrate `likelihood="auto"`\'s cost model (`dpgp.model.engine_cost`), as recorded in\n'
        "`benches/results/engine_cost_calibration.jsonl` by `python benches/engine_cost.py`: the median\n"
        "seconds of the recorded sweeps of each scene, size and engine."
    )
    write_page(markdown, "Engine cost calibration", intro, table, _command(), recorded=f"{recorded[0]}, {recorded[1]}")


def cargo_bench(markdown: str | None) -> None:
    """Criterion's point estimates (target/criterion/*/new/estimates.json) after `cargo bench -p dpgp-core`."""
    base = ROOT / "target" / "criterion"
    rows = []
    for est in sorted(base.glob("**/new/estimates.json")):
        bench = est.parent.parent.relative_to(base).as_posix()
        if bench.endswith("/report") or "report" in bench.split("/"):
            continue
        e = json.loads(est.read_text())
        rows.append({"bench": bench, "median_us": e["median"]["point_estimate"] / 1e3})
    if not rows:
        sys.exit("no criterion results under target/criterion: run `cargo bench -p dpgp-core` first")
    table = markdown_table(rows, ["bench", "median_us"], ["benchmark (group/parameter)", "median (µs)"])
    if markdown is None:
        print(table)
        return
    intro = (
        "Criterion's median time per iteration of each Rust benchmark (`benches/gp.rs`, `benches/sweep.rs`,\n"
        "`benches/hsgp.rs`): kernel assembly, Cholesky, the log marginal likelihood, frame scoring, a sweep\n"
        "and the HSGP kernels. Regenerate with `nice cargo bench -p dpgp-core` followed by the command below."
    )
    write_page(markdown, "Rust kernels (cargo bench)", intro, table, _command())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    for name in ("engine-cost", "cargo-bench"):
        sub.add_parser(name).add_argument("--markdown", metavar="FILE", help="write a stamped docs page")
    a = ap.parse_args()
    {"engine-cost": engine_cost, "cargo-bench": cargo_bench}[a.cmd](a.markdown)


if __name__ == "__main__":
    main()
