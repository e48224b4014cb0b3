"""Long scenarios that switch pattern (issue 20)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

import dpgp
from dpgp.exceptions import InvalidInputError
from dpgp.generate import long as long_mod
from dpgp.generate.long import lane_scale, learn_area, learn_entries, sample_long_scenarios
from dpgp.generate.motion import motion_model


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


def test_the_recorded_area_holds_the_tracks_and_not_what_lies_between(model):
    fit = model._fitted()
    area = learn_area(fit, 2.0)
    assert area.contains(fit.frames.xy).all()
    # the tracks cross the box along two bands (15-25 m); the corners outside them are not roads
    assert not area.contains(np.array([[2.0, 2.0], [37.0, 38.0], [-50.0, 20.0], [1e9, 1e9]])).any()
    # points between two recorded positions of one track are on its path
    assert area.contains(np.array([[20.0, 19.0]])).all()


def test_long_scenarios_keep_their_vehicles_on_the_recorded_paths(model):
    fit = model._fitted()
    area = learn_area(fit, lane_scale(motion_model(fit)))
    for s in model.sample_scenarios(3, duration=60.0, seed=2, dynamics=True):
        assert area.contains(s.table[["x", "y"]].to_numpy()).all()


def test_blocks_do_not_change_a_mean_scenario(model, monkeypatch):
    # the drivers' states cross the block boundaries (motion_rollouts' drivers): without new
    # entries, 0.5 s and 2 s blocks roll the same vehicles the same way
    k = model.n_patterns_
    one = SimpleNamespace(
        counts=np.zeros((k, k), int), entry_probs=np.eye(k)[0], dwell=lambda j: np.array([60.0]), dt=0.5
    )
    none = long_mod.Entries([np.zeros((0, 2))] * k, [np.zeros((0, 2))] * k, np.zeros(k))
    monkeypatch.setattr(long_mod, "learn_entries", lambda fit: none)
    fit = model._fitted()
    vehicles = motion_model(fit, agents="vehicles")  # steering, following a leader
    assert vehicles.steers
    monkeypatch.setattr(long_mod, "motion_model", lambda fit: vehicles)
    a = sample_long_scenarios(fit, one, 1, duration=10.0, seed=1, block=0.5, stochastic=False)[0]
    b = sample_long_scenarios(fit, one, 1, duration=10.0, seed=1, block=2.0, stochastic=False)[0]
    assert len(a.table) == len(b.table) > 0
    np.testing.assert_allclose(a.table[["x", "y", "vx", "vy"]], b.table[["x", "y", "vx", "vy"]], atol=1e-9)


def test_phase_schedules_keep_each_phase_to_its_own_patterns(model):
    ph = model.phases(2)
    assert model.phases(2) is ph  # cached
    (s,) = model.sample_scenarios(1, duration=60.0, seed=4, dynamics=True, phases=ph, phase_fields="in turn")
    assert s.phases is not None and set(np.unique(s.phases)) <= {0, 1}
    for p in range(2):
        seen = set(ph.pattern_runs[p][:, 0].tolist())
        assert set(np.unique(s.patterns[s.phases == p]).tolist()) <= seen
    # a phase lasts at least one of its recorded runs' lengths at a time, never less than a step
    runs = np.diff(np.flatnonzero(np.r_[True, np.diff(s.phases) != 0, True]))
    assert len(runs) >= 1
    (again,) = model.sample_scenarios(1, duration=60.0, seed=4, dynamics=True, phases=2, phase_fields="in turn")
    pd.testing.assert_frame_equal(s.table, again.table)
    with pytest.raises(InvalidInputError, match="long scenarios"):
        model.sample_scenarios(1, steps=5, phases=2)


def test_a_phase_field_is_its_patterns_together_and_vehicles_enter_where_the_phase_did(model):
    ph = model.phases(2)
    (s,) = model.sample_scenarios(1, duration=60.0, seed=4, dynamics=True, phases=ph)  # together
    shares = ph.frame_shares
    for p in np.unique(s.phases):
        assert set(np.unique(s.patterns[s.phases == p]).tolist()) == {int(np.argmax(shares[p]))}
    # the shares are the phase's frames by pattern
    for p in range(2):
        np.testing.assert_allclose(
            shares[p], np.bincount(model.labels_[ph.labels == p], minlength=shares.shape[1]) / (ph.labels == p).sum()
        )
    (turn,) = model.sample_scenarios(1, duration=60.0, seed=4, dynamics=True, phases=ph, phase_fields="in turn")
    assert not s.table.equals(turn.table)
    (again,) = model.sample_scenarios(1, duration=60.0, seed=4, dynamics=True, phases=ph)
    pd.testing.assert_frame_equal(s.table, again.table)
    with pytest.raises(InvalidInputError, match="phase_fields"):
        model.sample_scenarios(1, duration=10.0, phases=ph, phase_fields="mixed")
    with pytest.raises(InvalidInputError, match="long scenarios"):
        model.sample_scenarios(1, steps=5, phase_fields="together")
    # entries by phase: with every frame in one group, the entries of all patterns pooled
    fit = model._fitted()
    by_pattern = learn_entries(fit)
    pooled = learn_entries(fit, np.zeros(len(fit.labels), dtype=np.int64), 1)
    assert len(pooled.xy[0]) == sum(len(x) for x in by_pattern.xy)
    assert pooled.rate[0] == pytest.approx(sum(len(x) for x in by_pattern.xy) / (len(fit.labels) * 0.5))
    np.testing.assert_array_equal(np.sort(pooled.xy[0], axis=0), np.sort(np.concatenate(by_pattern.xy), axis=0))


def test_a_phase_mixture_keeps_the_patterns_that_count():
    from dpgp.generate.long import MIXTURE_MAX, MIXTURE_MIN, _mixture

    e = np.array([0.5, 0.3, 0.005, 0.195])
    assert _mixture(e) == [
        (0, pytest.approx(0.5 / 0.995)),
        (1, pytest.approx(0.3 / 0.995)),
        (3, pytest.approx(0.195 / 0.995)),
    ]
    many = np.full(20, 1 / 20)
    assert len(_mixture(many)) == MIXTURE_MAX and MIXTURE_MIN < 1 / 20


def test_a_cycle_splits_as_the_mean_cycle_or_as_one_recorded_cycle_stretched_to_the_mean(model):
    from dataclasses import replace

    # frames: cycles of 16 and 12, each stretched to their mean, 14, as its stages split it
    recorded = np.array([[6, 10], [10, 2]])
    ph = replace(model.phases(2), cycle=True, cycles=recorded)
    (s,) = model.sample_scenarios(1, duration=90.0, seed=5, dynamics=True, phases=ph, cycle_splits="recorded")
    pairs, runs, stage = _stage_pairs(s)
    assert len(pairs) >= 4
    assert set(pairs) <= {(5, 9), (12, 2)} and len(set(pairs)) == 2  # 6 * 14 / 16 = 5.25 -> 5, ...
    if stage[0] == 1:  # a scenario that starts mid-cycle takes its stage from a recorded cycle too
        assert runs[0] in (9, 2)
    # by default every cycle splits as the recorded cycles do on average (a fixed-time signal)
    (s,) = model.sample_scenarios(1, duration=90.0, seed=5, dynamics=True, phases=ph)
    pairs, runs, stage = _stage_pairs(s)
    assert len(pairs) >= 4 and set(pairs) == {(8, 6)}
    with pytest.raises(InvalidInputError, match="cycle_splits"):
        model.sample_scenarios(1, duration=10.0, phases=ph, cycle_splits="drawn")


def _stage_pairs(s):
    """The complete cycles' (stage 0, stage 1) durations in steps, every run's length, each run's stage."""
    runs_at = np.flatnonzero(np.r_[True, np.diff(s.phases) != 0])
    runs = np.diff(np.r_[runs_at, len(s.phases)])
    runs[0] -= 1  # the first step is t = 0
    stage = s.phases[runs_at]
    return [(runs[i], runs[i + 1]) for i in range(len(runs) - 2) if stage[i] == 0], runs, stage  # the last is cut


def test_drivers_take_up_the_fields_of_a_new_phase_when_it_begins(model, monkeypatch):
    # the core's renewal (Rust test: renewed drivers take up the new field) is asked for on the
    # first block of every new phase, and only there; "in turn" keeps the earlier schedule
    calls = []
    real = long_mod.motion_rollouts

    def spy(*args, **kw):
        calls.append((kw["mixtures"], kw["renew"], kw["drivers"] is not None))
        return real(*args, **kw)

    monkeypatch.setattr(long_mod, "motion_rollouts", spy)
    ph = model.phases(2)
    (s,) = model.sample_scenarios(1, duration=60.0, seed=4, dynamics=True, phases=ph)
    mixtures = [c[0][0] for c in calls]
    changed = [i > 0 and mixtures[i] != mixtures[i - 1] for i in range(len(calls))]
    assert any(changed) and [c[1] for c in calls] == changed
    assert all(c[2] for c, new in zip(calls, changed) if new)
    calls.clear()
    model.sample_scenarios(1, duration=60.0, seed=4, dynamics=True, phases=ph, phase_fields="in turn")
    assert not any(c[1] for c in calls)


def test_the_ego_of_a_long_scenario_is_the_first_vehicle_to_come_to_the_point(model):
    """ego=(x, y[, heading]): the first vehicle (by time, the nearest at that time) within a lane's
    width of the point, along the heading; an oracle per vehicle from the table. Criticality
    measures take long scenarios and, with ego=True, their own egos."""
    from dpgp.generate.criticality import criticality

    fit = model._fitted()
    reach = lane_scale(motion_model(fit))
    for ego, heading in (((20.0, 20.0), None), ((20.0, 20.0, 90.0), 90.0), ((5.0, 20.0, 0.0), 0.0)):
        scen = sample_long_scenarios(fit, model.transitions_, 3, 15.0, seed=4, ego=ego)
        for sc in scen:
            tab = sc.table
            d = np.hypot(tab["x"] - ego[0], tab["y"] - ego[1])
            ok = d <= reach
            if heading is not None:
                angle = np.degrees(np.arctan2(tab["vy"], tab["vx"])) - heading
                ok &= (np.abs((angle + 180) % 360 - 180) <= 45) & (np.hypot(tab["vx"], tab["vy"]) >= 0.5)
            firsts = [
                (g["t"].min(), d[g.index][g["t"] == g["t"].min()].min(), v) for v, g in tab[ok].groupby("vehicle")
            ]
            want = min(firsts)[2] if firsts else -1
            assert sc.ego == want
            if want >= 0:
                rows = sc.to_pandas()
                assert (rows["ego"] == (rows["vehicle"] == want)).all()
                # the table as a grid: vehicle i is column i, absent rows NaN
                at = np.rint(tab["t"].to_numpy() / sc.dt).astype(int)
                np.testing.assert_array_equal(sc.positions[at, tab["vehicle"]], tab[["x", "y"]].to_numpy())
                assert sc.in_roi.sum() == len(tab) and np.isnan(sc.positions[~sc.in_roi]).all()
        chosen = [sc for sc in scen if sc.ego >= 0]
        assert chosen, "no scenario has an ego here: move the point"
        own = criticality(chosen, ego=True)
        same = criticality(chosen, ego=np.array([sc.ego for sc in chosen]))
        for name in ("ttc", "gap", "pet", "deceleration"):
            np.testing.assert_array_equal(own.per_scene()[name], same.per_scene()[name])
        egos = np.array([sc.ego for sc in chosen])[own.pairs["scene"]]
        assert np.all((own.pairs["a"] == egos) | (own.pairs["b"] == egos))
    assert "ego" not in sample_long_scenarios(fit, model.transitions_, 1, 5.0, seed=4)[0].to_pandas()
    from dpgp.generate.scenarios import Ego

    with pytest.raises(InvalidInputError, match="placed"):
        sample_long_scenarios(fit, model.transitions_, 1, 5.0, seed=4, ego=Ego(20.0, 20.0, placed=True))
    with pytest.raises(InvalidInputError, match="ego"):
        sample_long_scenarios(fit, model.transitions_, 1, 5.0, seed=4, ego=(1.0,))
