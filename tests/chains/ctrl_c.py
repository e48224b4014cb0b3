"""Ctrl-C at a chosen moment of a chains fit (issue 37), shared by ``tests/chains/test_ctrl_c.py``
(each moment once, in CI) and ``benches/ctrl_c.py`` (each moment 20 times beside a load).

A child process runs :func:`dpgp.fit_chains` on synthetic frames (2 chains of 2-sweep blocks,
for ever) with ``DPGP_TRACE=1``, on local worker processes or on a Dask ``LocalCluster`` of 2
worker processes that it starts itself, so that they share its process group as they would in a
terminal. :func:`run` reads the child's output line by line and, at the first line that marks the
moment, sends SIGINT to the whole group (what Ctrl-C in a terminal does): no sleep decides when.
:func:`problems` says what went wrong, if anything.
"""

from __future__ import annotations

import os
import queue
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

BLOCK = 2  # sweeps per block in the child
BACKENDS = ("local", "dask")

# The moments, each the first trace event (``dpgp-trace PID EVENT``) that matches, after
# ``chains start`` (the child's own import of dpgp comes before it).
POINTS = {
    "start": r"chains start",  # fit_chains entered: no worker process of its own, no task yet
    "import": r"import",  # a worker process starts importing dpgp (Dask: for its first task)
    "first block": r"task chain\d-block0 start",  # a chain's first block runs on a worker
    "a block": r"task chain\d-block2 start",  # a later block runs; two of its chain's are in
    # Local only: a worker has sent half of a block's result (and stalls there, CTRL_C_TEAR).
    "result in flight": r"result half sent",
}
LOCAL_ONLY = ("result in flight",)

# What fit_chains costs a child that has taken Ctrl-C, at most (the Dask cluster's close included).
BOUND_SECONDS = 20.0

SCRIPT = r'''
import os
import sys


class _ImportMark:
    """The moment this process starts importing dpgp (a worker: unpickling its first task)."""

    def find_spec(self, name, path=None, target=None):
        if name == "dpgp":
            sys.meta_path.remove(self)
            sys.stderr.write(f"dpgp-trace {os.getpid()} import\n")
            sys.stderr.flush()
        return None


sys.meta_path.insert(0, _ImportMark())

if __name__ == "__mp_main__" and os.environ.get("CTRL_C_TEAR"):
    # A local worker: send the first half of a block's result, say so, and stall, as if Ctrl-C
    # stopped it in the middle of the send.
    import struct
    import time
    from multiprocessing import connection

    _send_bytes = connection.Connection._send_bytes

    def _half(self, buf):
        view = memoryview(buf)
        if len(view) > 1000:  # a block's result (settings resolved or a call are smaller)
            self._send(struct.pack("!i", len(view)) + bytes(view[: len(view) // 2]))
            sys.stderr.write(f"dpgp-trace {os.getpid()} result half sent\n")
            sys.stderr.flush()
            time.sleep(600)
        _send_bytes(self, buf)

    connection.Connection._send_bytes = _half

if __name__ == "__main__":
    import signal
    import warnings

    # Ctrl-C as a terminal's foreground job takes it, however the runner was started: one started
    # with `&` or nohup hands its children SIGINT ignored, and Python keeps it ignored.
    signal.signal(signal.SIGINT, signal.default_int_handler)

    import dpgp

    client = cluster = None
    if sys.argv[1] == "dask":
        import distributed

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cluster = distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                               dashboard_address=None, worker_dashboard_address=None,
                                               silence_logs=50)
        client = distributed.Client(cluster)
    frames = dpgp.datasets.synthetic("intersection", n_frames=60, seed=0)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            chains = dpgp.fit_chains(frames, 2, client=client, iterations=10**6, block=int(sys.argv[2]),
                                     progress=False)
        print("kept", chains.n_sweeps, "|", chains.stop_reason_, "|", *[str(w.message) for w in caught], flush=True)
    except KeyboardInterrupt as e:
        print("nothing kept |", e, flush=True)
    finally:
        if client is not None:
            client.close()
            cluster.close()
'''


@dataclass
class Outcome:
    """One run: SIGINT sent at ``point``; the child's exit ``seconds`` later (None: it did not
    exit within the bound and was killed), fit_chains' return ``returned`` seconds later (the
    rest is the script's own end: closing a Dask cluster), its output and what it kept."""

    point: str
    backend: str
    seconds: float | None = None
    returncode: int | None = None
    returned: float | None = None
    lines: list[str] = field(default_factory=list)
    marked: bool = False  # the moment's marker was seen and SIGINT sent
    left_behind: list[int] = field(default_factory=list)  # pids of the group still alive after the exit

    @property
    def received(self) -> Counter[str]:
        """Blocks the driver received, per chain (its trace)."""
        found = (re.search(r" block (chain\d+)-block\d+ received$", line) for line in self.lines)
        return Counter(m.group(1) for m in found if m)

    @property
    def kept(self) -> int | None:
        """Sweeps the child's chains hold (None: it kept nothing, or did not say)."""
        for line in self.lines:
            if line.startswith("kept "):
                return int(line.split()[1])
        return None


def run(point: str, backend: str, bound: float = BOUND_SECONDS, startup: float = 180.0) -> Outcome:
    """Start the child, send SIGINT to its group at ``point``'s first marker, time its exit."""
    with tempfile.NamedTemporaryFile("w", suffix=".py", prefix="dpgp_ctrl_c_", delete=False) as f:
        f.write(SCRIPT)
    script = Path(f.name)
    env = {**os.environ, "DPGP_TRACE": "1", **({"CTRL_C_TEAR": "1"} if point == "result in flight" else {})}
    cmd = [sys.executable, str(script), backend, str(BLOCK)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                            start_new_session=True)  # fmt: skip
    lines: queue.Queue[tuple[float, str] | None] = queue.Queue()
    reader = threading.Thread(target=_read, args=(proc, lines), daemon=True)
    reader.start()
    out, sent = Outcome(point, backend), 0.0
    try:
        out.marked = _until_marker(lines, out.lines, POINTS[point], time.monotonic() + startup)
        if out.marked:
            sent = time.monotonic()
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(timeout=bound)
            out.seconds = time.monotonic() - sent
    except subprocess.TimeoutExpired:
        pass
    finally:
        out.left_behind = _group(proc.pid)
        if proc.poll() is None or out.left_behind:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        reader.join(timeout=10)
        script.unlink()
    out.returncode = proc.returncode
    while not lines.empty():
        item = lines.get()
        if item is not None:
            out.lines.append(item[1])
            if out.marked and item[1].startswith(("kept ", "nothing kept")):
                out.returned = item[0] - sent
    return out


def _read(proc: subprocess.Popen, lines: queue.Queue) -> None:
    """Each line of the child's output with the time it came."""
    assert proc.stdout is not None
    for line in proc.stdout:
        lines.put((time.monotonic(), line.rstrip("\n")))
    lines.put(None)


def _until_marker(lines: queue.Queue, seen: list[str], pattern: str, deadline: float) -> bool:
    """Read lines until the marker of ``pattern`` after ``chains start``; False at the end of the
    output or at the deadline."""
    started = False
    while time.monotonic() < deadline:
        try:
            item = lines.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            return False
        if item is None:
            return False
        line = item[1]
        seen.append(line)
        event = line.split(" ", 2)[2] if line.startswith("dpgp-trace ") else None
        started = started or event == "chains start"
        if started and event is not None and re.fullmatch(pattern, event):
            return True
    return False


def _group(pgid: int, grace: float = 5.0) -> list[int]:
    """Processes of the group still running (not zombies) after up to ``grace`` seconds."""
    import psutil

    deadline = time.monotonic() + grace
    while True:
        alive = []
        for p in psutil.process_iter(["status"]):
            try:
                if os.getpgid(p.pid) == pgid and p.info["status"] != psutil.STATUS_ZOMBIE:
                    alive.append(p.pid)
            except (ProcessLookupError, psutil.Error):
                pass
        if not alive or time.monotonic() > deadline:
            return alive
        time.sleep(0.1)


def problems(out: Outcome) -> list[str]:
    """What is wrong with a run: no marker, a late or failed exit, processes left behind, a
    finished block lost, a local worker that died of the Ctrl-C (its traceback)."""
    if not out.marked:
        return [f"the marker of {out.point!r} never came"]
    found = []
    if out.seconds is None:
        found.append("still running after the bound: killed")
    elif out.returncode != 0:
        found.append(f"exit status {out.returncode}")
    if out.left_behind:
        found.append(f"processes left behind: {out.left_behind}")
    received = [n for n in out.received.values() if n]
    if out.kept is None:
        if not any(line.startswith("nothing kept") for line in out.lines):
            found.append("said neither what it kept nor that it kept nothing")
        elif received:
            found.append(f"kept nothing, yet blocks were received: {dict(out.received)}")
    else:
        # Every block received is kept; the chains are cut to the shortest one that has a block.
        if out.kept != BLOCK * min(received, default=0):
            found.append(f"kept {out.kept} sweeps of blocks received {dict(out.received)}")
        if not any("interrupted (Ctrl-C)" in line and "keep every finished block" in line for line in out.lines):
            found.append("no word of the interruption")
    if out.point == "a block" and not received:
        found.append("a block was running after two of its chain's, yet nothing was kept")
    if out.backend == "local" and any(line.startswith("Traceback") for line in out.lines):
        found.append("a traceback: a process died of the Ctrl-C")
    return found


def summary(outcomes: list[Outcome]) -> str:
    """A markdown table per point and backend: runs passed, median and maximum seconds from
    SIGINT to the child's exit, and to fit_chains' return."""
    rows = [
        "| point | backend | passed | exit: median s | exit: max s | return: median s | return: max s |",
        "|---|---|---|---|---|---|---|",
    ]
    for backend in BACKENDS:
        for point in POINTS:
            mine = [o for o in outcomes if o.point == point and o.backend == backend]
            if not mine:
                continue
            ok = sum(not problems(o) for o in mine)
            exits = [o.seconds for o in mine if o.seconds is not None]
            returns = [o.returned for o in mine if o.returned is not None]
            rows.append(f"| {point} | {backend} | {ok}/{len(mine)} | {_stats(exits)} | {_stats(returns)} |")
    return "\n".join(rows)


def _stats(seconds: list[float]) -> str:
    return f"{statistics.median(seconds):.2f} | {max(seconds):.2f}" if seconds else "- | -"
