"""Shared test fixtures: the real data in ../shared/data (skipped with a reason where absent)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# CI runs the property tests on a fixed set of examples, so that a run is reproducible; locally
# they keep exploring new ones.
settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def data_file(name: str) -> Path:
    path = DATA / name
    if not path.exists():
        pytest.skip(f"real data file {path} is absent (it lives in ../shared/data beside the repo)")
    return path


@pytest.fixture(scope="session")
def us101_path() -> Path:
    return data_file("ngsim_us101_frames.tsv")


@pytest.fixture(scope="session")
def lankershim_path() -> Path:
    return data_file("ngsim_lankershim_frames.csv")


def interrupt_after(args: list[str], seconds: float, timeout: float) -> tuple[int, str, str, float]:
    """Run ``args`` (a Python fit that prints ``fitting`` when it starts), send it Ctrl-C
    ``seconds`` after that line, and wait up to ``timeout`` for it to end: (return code, the rest
    of its stdout, its stderr, seconds from Ctrl-C to its end). The process never outlives this."""
    import signal
    import subprocess
    import time

    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "fitting"
        time.sleep(seconds)
        proc.send_signal(signal.SIGINT)
        sent = time.perf_counter()
        out, err = proc.communicate(timeout=timeout)
        return proc.returncode, out, err, time.perf_counter() - sent
    finally:
        proc.kill()
