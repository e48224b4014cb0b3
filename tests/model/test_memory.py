"""The memory budget: a fit that would outgrow it stops early with a typed error instead of being
killed by the operating system, and the process carries on."""

from __future__ import annotations

import subprocess
import sys

import pytest

import dpgp

SCRIPT = """
import time, dpgp
frames = dpgp.datasets.synthetic("highway", 400, seed=0)
t = time.perf_counter()
model = dpgp.DPGP(likelihood="exact", memory_budget="3MB", iterations=5, progress=False,
                  noise_var=1.0, length_scale_prior=(10.0, 1.0))
try:
    model.fit(frames)
    print("fitted")
except dpgp.MemoryBudgetError as e:
    assert isinstance(e, MemoryError) and "hsgp" in str(e), e
    print("stopped after %.1f s" % (time.perf_counter() - t))
# the process is alive and can fit again, within budget
small = dpgp.DPGP(likelihood="hsgp", iterations=1, progress=False, noise_var=1.0,
                  length_scale_prior=(10.0, 1.0)).fit(frames[:50])
print("then fitted", small.n_patterns_)
"""


def test_a_fit_past_its_budget_stops_with_a_typed_error_and_the_process_survives():
    r = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.split("\n")
    assert lines[0].startswith("stopped after"), r.stdout
    assert float(lines[0].split()[2]) < 30
    assert lines[1].startswith("then fitted")


def test_the_state_reached_is_kept_when_the_budget_stops_a_sweep():
    frames = dpgp.datasets.synthetic("intersection", 150, seed=1)
    kw = dict(likelihood="exact", iterations=30, progress=False, noise_var=1.0, length_scale_prior=(10.0, 1.0), seed=3)
    # Measure what initialisation needs, then allow a little more: a later sweep crosses it.
    probe = dpgp.DPGP(**{**kw, "iterations": 0}).fit(frames)
    budget = int(probe._sampler.memory_bytes() * 1.05)
    m = dpgp.DPGP(memory_budget=budget, **kw)
    try:
        m.fit(frames)
    except dpgp.MemoryBudgetError:
        assert len(m.labels_) == len(frames) and m.n_patterns_ >= 1
        assert m.predict(frames[:5]).shape == (5,)
    else:
        pytest.skip("this chain never crossed the budget")


def test_bad_budgets_are_typed_errors():
    for bad in ["lots", -5, 0, float("nan"), "3 parsecs"]:
        with pytest.raises(dpgp.InvalidInputError):
            dpgp.DPGP(memory_budget=bad).fit(dpgp.datasets.synthetic("highway", 5))


UNDER_ULIMIT = """
import resource, sys, time
import dpgp
from dpgp._resources import default_memory_budget, threads_reservation

likelihood, n_frames, headroom = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
frames = dpgp.datasets.synthetic("highway", n_frames, seed=0)
with open("/proc/self/status") as fh:
    used = next(int(line.split()[1]) * 1024 for line in fh if line.startswith("VmSize:"))
# ulimit -v: the headroom for the patterns on top of what the two worker threads (and their
# driver) reserve, faer's GEMM arena of twice the L3 among it: the same test whatever the cache
reserved = threads_reservation(2)
resource.setrlimit(resource.RLIMIT_AS, (used + reserved + headroom, resource.RLIM_INFINITY))
assert default_memory_budget(2) <= headroom // 2, default_memory_budget(2)
model = dpgp.DPGP(likelihood=likelihood, iterations=2, progress=False, noise_var=1.0,
                  length_scale_prior=(10.0, 1.0), n_threads=2)
try:
    model.fit(frames)
    print("fitted", model.likelihood_)
except dpgp.MemoryBudgetError:
    print("stopped")
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
@pytest.mark.parametrize(
    "likelihood, n_frames, headroom_mb, outcome",
    [
        # exact's patterns would outgrow the address space left: a typed stop
        ("exact", 400, 600, "stopped"),
        # exact's worst case (~270 MB) is over the budget the limit leaves: auto runs hsgp
        ("auto", 200, 400, "fitted hsgp"),
    ],
)
def test_the_default_budget_respects_an_address_space_limit(likelihood, n_frames, headroom_mb, outcome):
    """Under ``ulimit -v`` (or a container's cgroup limit, which the system's MemAvailable does
    not show) the default budget is half of what the limit leaves. Before, it was half of the
    machine's available memory, and both of these fits were killed (allocation failure, abort)."""
    args = [likelihood, str(n_frames), str(headroom_mb * 2**20)]
    r = subprocess.run([sys.executable, "-c", UNDER_ULIMIT, *args], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == outcome


UNDER_TIGHT_ULIMIT = """
import resource, sys
import dpgp
from dpgp import _resources

if sys.argv[1] == "fake":  # a machine whose CPU reports a 480 MiB L3 (issue 17)
    _resources._cache_sizes = lambda: (48 * 2**10, 2 * 2**20, 480 * 2**20)
frames = dpgp.datasets.synthetic("highway", 400, seed=0)
with open("/proc/self/status") as fh:
    used = next(int(line.split()[1]) * 1024 for line in fh if line.startswith("VmSize:"))
# less than one thread's GEMM arena, far more than the patterns of this fit need
room = min(_resources.gemm_arena_bytes() // 2, 600 * 2**20)
resource.setrlimit(resource.RLIMIT_AS, (used + room, resource.RLIM_INFINITY))
model = dpgp.DPGP(likelihood="exact", iterations=2, progress=False, noise_var=1.0,
                  length_scale_prior=(10.0, 1.0), n_threads=1)
try:
    model.fit(frames)
    print("fitted")
except dpgp.MemoryBudgetError as e:
    print("stopped:", e)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
@pytest.mark.parametrize("cache", ["real", "fake"])
def test_a_limit_below_the_gemm_arena_is_a_typed_stop_not_an_abort(cache):
    """faer's x86 GEMM reserves twice the L3 per thread that runs a product. Under an
    address-space limit that cannot hold even one arena, the fit stops before any work with a
    MemoryBudgetError that names it; before, the first large product aborted the interpreter
    ("memory allocation of ... bytes failed" in private_gemm_x86::gemm). "fake": the accounting
    of a CPU reporting a 480 MiB L3, on this machine."""
    r = subprocess.run([sys.executable, "-c", UNDER_TIGHT_ULIMIT, cache], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.startswith("stopped:") and "n_threads=1" in r.stdout and "L3" in r.stdout, r.stdout


def test_the_gemm_arena_is_derived_from_the_cache_as_faer_does(tmp_path, monkeypatch):
    """private-gemm-x86: each level's size over the CPUs sharing it, times the CPUs sharing an
    L1, L3 times the physical cores; arena = 2 × L3 rounded up to pages."""
    from dpgp import _resources

    def cache(cpu, index, level, kind, size, shared):
        d = tmp_path / f"cpu{cpu}" / "cache" / f"index{index}"
        d.mkdir(parents=True)
        for name, value in (("level", level), ("type", kind), ("size", size), ("shared_cpu_list", shared)):
            (d / name).write_text(f"{value}\n")

    for cpu in range(4):
        cache(cpu, 0, 1, "Data", "48K", str(cpu))
        cache(cpu, 1, 1, "Instruction", "32K", str(cpu))
        cache(cpu, 2, 2, "Unified", "2048K", str(cpu))
        cache(cpu, 3, 3, "Unified", "491520K", "0-3")  # 480 MiB shared by four CPUs
    monkeypatch.setattr(_resources, "_physical_cores", lambda: 4)
    assert _resources._cache_sizes(str(tmp_path)) == (48 * 2**10, 2 * 2**20, 480 * 2**20)
    monkeypatch.setattr(_resources, "_cache_sizes", lambda: (48 * 2**10, 2 * 2**20, 480 * 2**20))
    assert _resources.gemm_arena_bytes() == 1006632960  # the allocation the issue saw fail
    assert _resources.threads_reservation(3) == 4 * (1006632960 + 72 * 2**20)
    monkeypatch.setattr(_resources, "_cache_sizes", lambda: (0, 0, 0))  # unknown: faer's defaults
    assert _resources.gemm_arena_bytes() == 2 * 2 * 2**20  # L3 = max(2 MiB, 4 × L2 of 256 KiB), twice


def test_the_cgroup_limit_bounds_the_available_memory(tmp_path, monkeypatch):
    from dpgp import _resources

    def cgroup(limit: str, usage: str) -> None:
        (tmp_path / "max").write_text(limit + "\n")
        (tmp_path / "current").write_text(usage + "\n")
        monkeypatch.setattr(_resources, "_CGROUP_FILES", ((str(tmp_path / "max"), str(tmp_path / "current")),))

    cgroup(str(2 * 2**30), str(2**30))
    assert _resources._cgroup_available() == 2**30
    assert _resources.available_memory() <= 2**30
    cgroup("max", "123")  # v2: no limit
    assert _resources._cgroup_available() is None
    cgroup(str(2**63 - 4096), "123")  # v1: its "no limit" sentinel
    assert _resources._cgroup_available() is None
    monkeypatch.setattr(_resources, "_CGROUP_FILES", ((str(tmp_path / "absent"), str(tmp_path / "absent")),))
    assert _resources._cgroup_available() is None
