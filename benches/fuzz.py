"""Fuzz dpgp's public surfaces with generated hostile inputs, each batch in a child process.

The full run (issue 11: at least 10,000 cases; about 10 minutes on 2 cores)::

    nice -n 15 python benches/fuzz.py --cases 1500 --jobs 2 --json fuzz.json

One surface, a range of cases; replay one case in this process with its draws and traceback::

    python benches/fuzz.py --surface model_use --cases 200 --start 1000
    python benches/fuzz.py --replay model_use:1234

Case ``surface:i`` is always the same case (its choices come from a generator seeded with the
surface and ``i``; see tests/fuzz_cases.py). A worker process runs a batch of cases and reports
each one before and after it runs, so a case that kills the process (a Rust panic that aborts,
an allocation failure) or runs past ``--timeout`` is pinned to that case; the runner then starts
a new worker after it. Workers run under an address-space limit (``--memory``), so a case that
asks for an impossible allocation fails fast instead of swapping the machine.

Prints cases per surface × outcome, then each distinct defect with one reproducer. Exit
status 1 if any case found a defect.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import queue
import resource
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import fuzz_cases as fc  # noqa: E402

OUTCOMES = ("valid", "typed", *fc.DEFECTS)


# --- the worker: runs cases in-process, one JSON line before and after each ----------------------
def worker(surface: str, start: int, stop: int, seed: int) -> None:
    ctx = fc.Context()
    try:
        print(json.dumps({"ready": True}), flush=True)
        for i in range(start, stop):
            print(json.dumps({"start": i}), flush=True)
            draw = fc.RandomDraw([seed, fc.SURFACES.index(surface), i])
            t = time.perf_counter()
            outcome = fc.run_case(surface, draw, ctx)
            print(
                json.dumps(
                    {
                        "done": i,
                        "kind": outcome.kind,
                        "detail": outcome.detail,
                        "seconds": time.perf_counter() - t,
                        "draws": draw.log if outcome.defect else [],
                    }
                ),
                flush=True,
            )
    finally:
        ctx.close()


def _limit_memory(megabytes: int) -> None:
    os.setsid()  # its own process group: a hang is killed with everything it started
    if megabytes:
        limit = megabytes * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))


# --- the parent: feeds ranges of cases to workers, pins crashes and hangs -----------------------------
def _cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process, all its threads (Linux /proc; 0 elsewhere)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def run_range(
    surface: str, start: int, stop: int, args: argparse.Namespace, results: list, lock: threading.Lock
) -> None:
    i = start
    while i < stop:
        cmd = [sys.executable, __file__, "--worker", surface, str(i), str(stop), "--seed", str(args.seed)]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                preexec_fn=lambda: _limit_memory(args.memory))  # fmt: skip
        lines: queue.Queue = queue.Queue()
        threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout] + [lines.put(None)], daemon=True).start()
        err_tail: collections.deque = collections.deque(maxlen=30)
        threading.Thread(target=lambda: [err_tail.append(x) for x in proc.stderr], daemon=True).start()
        current, deadline = None, time.monotonic() + args.timeout + 60  # the first case includes setup
        cpu0, wall0 = 0.0, time.monotonic()
        while True:
            try:
                line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                # A hang is --timeout seconds of the worker's CPU time, or ten times that of wall
                # time (a deadlock burns no CPU): on a shared machine a long but legitimate case
                # may wait for the CPU longer than it runs.
                used = _cpu_seconds(proc.pid) - cpu0
                if current is not None and used < args.timeout and time.monotonic() - wall0 < 10 * args.timeout:
                    deadline = time.monotonic() + max(args.timeout - used, 1.0)
                    continue
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                if current is None:
                    raise RuntimeError(f"fuzz worker hung before its first case: {''.join(err_tail)}") from None
                with lock:
                    results.append(
                        dict(
                            surface=surface,
                            case=current if current is not None else i,
                            kind="hang",
                            detail=f"no result within {args.timeout:g} s of CPU time or {10 * args.timeout:g} s",
                            seconds=args.timeout,
                            draws=[],
                        )
                    )
                break
            if line is None:  # the worker exited
                proc.wait()
                if current is not None:
                    sig = -proc.returncode if proc.returncode < 0 else None
                    how = f"killed by {signal.Signals(sig).name}" if sig else f"exit status {proc.returncode}"
                    tail = " | ".join(x.strip() for x in err_tail if x.strip())[-400:]
                    with lock:
                        results.append(
                            dict(
                                surface=surface,
                                case=current,
                                kind="crash",
                                detail=f"{how}: {tail}",
                                seconds=0.0,
                                draws=[],
                            )
                        )
                elif proc.returncode != 0 and i < stop:
                    raise RuntimeError(f"fuzz worker failed before its first case: {''.join(err_tail)}")
                break
            msg = json.loads(line)
            if "start" in msg:
                current, deadline = msg["start"], time.monotonic() + args.timeout
                cpu0, wall0 = _cpu_seconds(proc.pid), time.monotonic()
            elif "done" in msg:
                with lock:
                    results.append(
                        dict(
                            surface=surface,
                            case=msg["done"],
                            kind=msg["kind"],
                            detail=msg["detail"],
                            seconds=msg["seconds"],
                            draws=msg["draws"],
                        )
                    )
                i, current = msg["done"] + 1, None
        if current is not None:
            i = current + 1  # start the next worker after the case that crashed or hung
        elif proc.returncode == 0:
            break


def report(results: list, surfaces: list[str]) -> str:
    table = collections.Counter((r["surface"], r["kind"]) for r in results)
    width = max(len(s) for s in surfaces + ["total"])
    head = f"{'surface':<{width}} " + " ".join(f"{k:>9}" for k in OUTCOMES) + f" {'cases':>7}"
    lines = [head, "-" * len(head)]
    for s in surfaces + ["total"]:
        row = [sum(v for (ss, k), v in table.items() if k == kind and (ss == s or s == "total")) for kind in OUTCOMES]
        lines.append(f"{s:<{width}} " + " ".join(f"{v:>9}" for v in row) + f" {sum(row):>7}")
    groups: dict[str, list] = collections.defaultdict(list)
    for r in results:
        if r["kind"] in fc.DEFECTS:
            groups[fc.signature(r["surface"], fc.Outcome(r["kind"], r["detail"]))].append(r)
    if groups:
        lines += ["", f"{len(groups)} distinct defect(s) (cases, signature, first reproducer):"]
        for sig, rs in sorted(groups.items(), key=lambda kv: -len(kv[1])):
            first = min(rs, key=lambda r: r["case"])
            lines.append(f"{len(rs):>6}  {sig}")
            lines.append(
                f"        python benches/fuzz.py --replay {first['surface']}:{first['case']}   # {first['detail'][:160]}"
            )
    return "\n".join(lines)


def replay(spec: str, seed: int) -> int:
    import traceback

    surface, _, i = spec.partition(":")
    draw = fc.RandomDraw([seed, fc.SURFACES.index(surface), int(i)])
    draw.verbose = True
    ctx = fc.Context()
    orig = fc.classify_exception

    def loud(e: BaseException) -> fc.Outcome:
        traceback.print_exception(e)
        return orig(e)

    fc.classify_exception = loud
    try:
        outcome = fc.run_case(surface, draw, ctx)
    finally:
        ctx.close()
    print("draws:", *draw.log, sep="\n  ")
    print(f"outcome: {outcome.kind}: {outcome.detail}")
    return 1 if outcome.defect else 0


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--surface", action="append", choices=fc.SURFACES, help="surface(s) to fuzz (default: all)")
    p.add_argument("--cases", type=int, default=1500, help="cases per surface")
    p.add_argument("--start", type=int, default=0, help="first case number")
    p.add_argument("--jobs", type=int, default=1, help="worker processes at once")
    p.add_argument("--batch", type=int, default=500, help="cases per worker process")
    p.add_argument(
        "--timeout",
        type=float,
        default=30.0,
        help="CPU seconds (ten times as many wall seconds) before a case counts as a hang",
    )
    p.add_argument("--memory", type=int, default=4096, help="address-space limit of a worker, MiB (0: none)")
    p.add_argument("--seed", type=int, default=0, help="seed of the whole run")
    p.add_argument("--json", help="write every case's outcome here")
    p.add_argument("--replay", metavar="SURFACE:I", help="run one case here, with its draws and traceback")
    p.add_argument("--worker", nargs=3, metavar=("SURFACE", "START", "STOP"), help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.worker:
        worker(args.worker[0], int(args.worker[1]), int(args.worker[2]), args.seed)
        return 0
    if args.replay:
        return replay(args.replay, args.seed)
    surfaces = args.surface or list(fc.SURFACES)
    jobs = [(s, a, min(a + args.batch, args.start + args.cases))
            for s in surfaces for a in range(args.start, args.start + args.cases, args.batch)]  # fmt: skip
    results: list = []
    lock = threading.Lock()
    pending: queue.Queue = queue.Queue()
    for job in jobs:
        pending.put(job)
    t0 = time.perf_counter()

    def run_jobs() -> None:
        while True:
            try:
                job = pending.get_nowait()
            except queue.Empty:
                return
            run_range(*job, args, results, lock)
            print(
                f"  {job[0]} {job[1]}..{job[2] - 1} done ({time.perf_counter() - t0:.0f} s)",
                file=sys.stderr,
                flush=True,
            )

    threads = [threading.Thread(target=run_jobs) for _ in range(max(1, args.jobs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    results.sort(key=lambda r: (fc.SURFACES.index(r["surface"]), r["case"]))
    print(f"{len(results)} cases in {time.perf_counter() - t0:.0f} s (seed {args.seed})\n")
    print(report(results, surfaces))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 1 if any(r["kind"] in fc.DEFECTS for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
