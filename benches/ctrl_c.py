"""Ctrl-C at every moment of a chains fit, 20 times each, beside a load (issue 37).

    nice -n 5 python benches/ctrl_c.py            # 20 runs per moment and backend beside 2 busy
                                                  # processes per core and 8 GB of memory held
    nice -n 5 python benches/ctrl_c.py --runs 3 --busy 0 --memory-gb 0 --backends local

A run is tests/chains/ctrl_c.py's: a child fits chains for ever, SIGINT goes to its whole process
group at the moment's trace marker (start, import, first block, a block; and on local processes
a block's result half sent), and the run passes if the child exits within 20 s, leaves no
process behind and kept every block its driver had received. Prints each run, then a table per
moment and backend: runs passed, median and maximum seconds from SIGINT to the child's exit and
to fit_chains' return (the rest is the script closing its Dask cluster). ``--out`` keeps every
run as JSON lines. The load is started here and stopped at the end, however the bench ends.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "chains"))

import ctrl_c  # noqa: E402

_HOG = """
import sys, time
import numpy as np
held = np.ones(int(float(sys.argv[1]) * 2**30) // 8)  # touched: resident, not just reserved
print("held", flush=True)
while True:
    time.sleep(60)
"""


def start_load(busy: int, memory_gb: float) -> list[subprocess.Popen]:
    """``busy`` processes spinning on a core each, and one holding ``memory_gb`` GB."""
    load = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
    if memory_gb > 0:
        hog = subprocess.Popen([sys.executable, "-c", _HOG, str(memory_gb)], stdout=subprocess.PIPE, text=True)
        load.append(hog)
        assert hog.stdout is not None and hog.stdout.readline().strip() == "held"
    return load


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--busy", type=int, default=2 * (os.cpu_count() or 1), help="busy processes")
    parser.add_argument("--memory-gb", type=float, default=8.0)
    parser.add_argument("--backends", default=",".join(ctrl_c.BACKENDS))
    parser.add_argument("--points", default=",".join(ctrl_c.POINTS))
    parser.add_argument("--out", type=Path, help="every run as JSON lines")
    args = parser.parse_args()
    cases = [
        (p, b)
        for b in args.backends.split(",")
        for p in args.points.split(",")
        if b == "local" or p not in ctrl_c.LOCAL_ONLY
    ]
    print(f"load: {args.busy} busy processes on {os.cpu_count()} cores, {args.memory_gb:g} GB held", flush=True)
    outcomes = []
    load = start_load(args.busy, args.memory_gb)
    try:
        for point, backend in cases:
            for i in range(args.runs):
                out = ctrl_c.run(point, backend)
                outcomes.append(out)
                found = ctrl_c.problems(out)
                print(
                    f"{backend:5} {point:16} {i:2}  exit {out.seconds}  return {out.returned}  kept {out.kept}  {found or 'ok'}",
                    flush=True,
                )
                if found:
                    print("\n".join("    " + line for line in out.lines[-40:]), flush=True)
                if args.out is not None:
                    with args.out.open("a") as f:
                        f.write(
                            json.dumps({**vars(out), "problems": found, "busy": args.busy, "memory_gb": args.memory_gb})
                            + "\n"
                        )
    finally:
        for p in load:
            p.kill()
            p.wait()
    print(ctrl_c.summary(outcomes))


if __name__ == "__main__":
    main()
