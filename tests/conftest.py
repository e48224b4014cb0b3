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

# The longest modules (their tests' seconds, measured 2026-11-30: 300 down to 45), handed to the
# workers first. xdist gives out whole modules (`--dist loadfile`) and by default the ones with
# most tests first, which put the few long tests over shards on a Dask cluster at the end: one
# core ran them while the other idled.
LONG_MODULES = (
    "test_sharded_fit.py",
    "model/test_sampler_exact.py",
    "model/test_subcluster.py",
    "model/test_split_merge_noise.py",
    "chains/test_chains.py",
    "model/test_numerics.py",
    "evaluate/test_phases.py",
    "test_sharded_heading.py",
    "test_sharded_identity.py",
    "chains/test_chains_dask.py",
    "test_sharded_interrupts.py",
    "model/test_per_pattern_noise.py",
    "model/test_sticky.py",
)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The :data:`LONG_MODULES` first, longest first; the rest as collected (a stable sort)."""
    rank = {name: i for i, name in enumerate(LONG_MODULES)}
    here = Path(__file__).resolve().parent

    def key(item: pytest.Item) -> int:
        try:
            name = item.path.resolve().relative_to(here).as_posix()
        except ValueError:
            return len(rank)
        return rank.get(name, len(rank))

    items.sort(key=key)


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
