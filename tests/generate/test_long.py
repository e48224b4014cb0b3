"""Long scenarios that switch pattern (issue 20)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

import dpgp
from dpgp.exceptions import InvalidInputError
from dpgp.generate.long import learn_entries, sample_long_scenarios


def _tracks(seed: int = 0, n_tracks: int = 24, steps: int = 20, dt: float = 0.5) -> pd.DataFrame:
    """Vehicles crossing a 40 m box along x or along y, entering at staggered times."""
    rng = np.random.default_rng(seed)
    rows = []
    for tr in range(n_tracks):
        t0 = rng.integers(0, 40) * dt
        east = tr % 2 == 0
        p = np.array([0.0, rng.uniform(15, 25)]) if east else np.array([rng.uniform(15, 25), 0.0])
        v = np.array([4.0, 0.0]) if east else np.array([0.0, 4.0])
        for s in range(steps):
            rows.append((tr, t0 + s * dt, *(p + s * dt * v + rng.normal(0, 0.05, 2)), *v))
    return pd.DataFrame(rows, columns=["track", "t", "x", "y", "vx", "vy"])


@pytest.fixture(scope="module")
def model():
    frames = dpgp.make_frames(_tracks(), dt=0.5)
    return dpgp.DPGP(iterations=2, seed=0, progress=False).fit(frames)


def test_entries_are_the_track_starts_after_a_recordings_first_frame(model):
    fit = model._fitted()
    e = learn_entries(fit)
    f = fit.frames
    t_row = f.ids[f.frame_of_row]
    starts = pd.Series(t_row).groupby(f.tracks).min()
    expected = int((starts > f.ids.min()).sum())  # one unbroken recording: entries after its start
    assert sum(len(x) for x in e.xy) == expected
    k = fit.n_patterns
    frames_k = np.bincount(fit.labels, minlength=k)
    assert np.allclose(e.rate * frames_k * 0.5, [len(x) for x in e.xy])


def test_patterns_switch_by_the_transitions_and_dwell_given(model):
    k = model.n_patterns_
    cyclic = SimpleNamespace(
        counts=np.roll(np.eye(k, dtype=int), 1, axis=1) if k > 1 else np.ones((1, 1), int),
        entry_probs=np.eye(k)[0],
        dwell=lambda j: np.array([5.0]),
        dt=0.5,
    )
    (s,) = sample_long_scenarios(model._fitted(), cyclic, 1, duration=30.0, seed=3)
    assert len(s.t) == 61 and s.patterns[0] == 0
    runs = np.diff(np.flatnonzero(np.r_[True, np.diff(s.patterns) != 0, True]))
    if k > 1:  # every 5 s (10 steps) the next pattern in the cycle; the first step is t = 0
        assert runs[0] == 11 and np.all(runs[1:-1] == 10)
        assert np.all(np.diff(s.patterns)[np.diff(s.patterns) != 0] % k == 1)
    assert np.allclose(np.rint(s.table.t / 0.5) * 0.5, s.table.t)
    x0, x1, y0, y1 = model._fitted().roi
    assert s.table.x.between(x0, x1).all() and s.table.y.between(y0, y1).all()
    assert s.table.vehicle.max() >= s.table[s.table.t == 0].shape[0]  # new vehicles entered


def test_long_scenarios_are_seeded_and_come_from_the_estimator(model):
    a = model.sample_scenarios(2, duration=20.0, seed=5, dynamics=True)
    b = model.sample_scenarios(2, duration=20.0, seed=5, dynamics=True)
    assert len(a) == 2
    for x, y in zip(a, b):
        pd.testing.assert_frame_equal(x.table, y.table)
        assert np.array_equal(x.patterns, y.patterns)
    with pytest.raises(InvalidInputError, match="duration"):
        model.sample_scenarios(1, duration=-1.0)


def test_same_seed_same_result_with_one_or_two_threads():
    frames = dpgp.make_frames(_tracks(seed=1), dt=0.5)
    runs = []
    for threads in (1, 2):
        m = dpgp.DPGP(iterations=2, seed=0, progress=False, n_threads=threads).fit(frames)
        runs.append((m.transitions_, m.sample_scenarios(2, duration=15.0, seed=7, dynamics=True)))
    (t1, s1), (t2, s2) = runs
    assert np.array_equal(t1.counts, t2.counts) and np.array_equal(t1.runs, t2.runs)
    for a, b in zip(s1, s2):
        pd.testing.assert_frame_equal(a.table, b.table)
