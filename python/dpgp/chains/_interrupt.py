"""Ctrl-C during :func:`dpgp.fit_chains` (issue 37): it must end the fit within seconds and keep
every finished block, wherever it lands: before the workers exist, while they import, during a
block, or while a block's result is on its way back.

Why not simply catch KeyboardInterrupt: Python raises it at whatever bytecode the main thread is
running, and some of those moments leave the run in a state it cannot get out of:

- inside ``ProcessPoolExecutor.submit``, between spawning a worker and registering it: the
  pool does not know the worker, so nothing stops it, and multiprocessing joins it at exit;
- between taking a finished block off the pending list and storing it: the block is lost;
- inside a ``__del__`` or a weakref callback: Python prints the KeyboardInterrupt and drops it,
  and the fit runs on.

So while :class:`Interrupts` is entered, Ctrl-C raises only where the driver waits (inside
:meth:`~Interrupts.interruptible`: for tasks, for a cluster), where nothing is half done; one that
arrives elsewhere is remembered and raised when the driver next waits, a moment later (one that
arrives after the last wait, while the pool closes and the chains are put together, is dropped:
the run is complete by then).

Workers must not die of the same Ctrl-C (a terminal sends it to the whole process group): a
worker killed while importing breaks the pool, and one killed in the middle of a task prints
its traceback over the user's terminal. :class:`WorkerContext` spawns them with SIGINT blocked,
which the new interpreter inherits across exec (as multiprocessing's own resource tracker is
spawned); the driver stops them itself.

``DPGP_TRACE=1`` prints a line per event (:func:`mark`) on stderr: tests wait for one to send
Ctrl-C at a chosen moment instead of sleeping.
"""

from __future__ import annotations

import multiprocessing.context
import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

TRACE = bool(os.environ.get("DPGP_TRACE"))


def mark(event: str) -> None:
    """With ``DPGP_TRACE`` set, one line ``dpgp-trace PID EVENT`` on stderr (one write, so lines
    of several processes sharing the stream do not mix)."""
    if TRACE:
        sys.stderr.write(f"dpgp-trace {os.getpid()} {event}\n")
        sys.stderr.flush()


class Interrupts:
    """While entered (in the main thread, with Python's own SIGINT handler in place; otherwise
    Python's behaviour is left as it is), Ctrl-C raises KeyboardInterrupt only inside
    :meth:`interruptible` sections."""

    def __init__(self) -> None:
        self.pending = False  # a Ctrl-C the driver has not handled yet
        self._open = 0
        self._active = False

    def __enter__(self) -> Interrupts:
        main = threading.current_thread() is threading.main_thread()
        self._active = main and signal.getsignal(signal.SIGINT) is signal.default_int_handler
        if self._active:
            signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._active:
            signal.signal(signal.SIGINT, signal.default_int_handler)

    def _handle(self, signum: int, frame: Any) -> None:
        self.pending = True
        if self._open:
            raise KeyboardInterrupt

    @contextmanager
    def interruptible(self) -> Iterator[None]:
        """A wait: Ctrl-C raises here at once, and one that came before is raised on entry."""
        if self._active and self.pending:
            raise KeyboardInterrupt
        self._open += 1
        try:
            yield
        finally:
            self._open -= 1

    def handled(self) -> None:
        """The driver has stopped after a KeyboardInterrupt: forget it, and any Ctrl-C pressed
        again while it cancelled tasks and kept blocks (the chains are returned all the same)."""
        self.pending = False


class _Worker(multiprocessing.context.SpawnProcess):
    def start(self) -> None:
        if not hasattr(signal, "pthread_sigmask"):  # Windows: no signal masks
            return super().start()
        # The spawning thread's mask is the child's: blocked across exec, so the new interpreter
        # never sees the Ctrl-C. A SIGINT meanwhile stays pending for the driver (or goes to
        # another of its threads); none is lost.
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            super().start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


class WorkerContext(multiprocessing.context.SpawnContext):
    """The "spawn" context, its processes started with SIGINT blocked."""

    Process = _Worker
