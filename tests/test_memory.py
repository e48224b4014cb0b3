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
