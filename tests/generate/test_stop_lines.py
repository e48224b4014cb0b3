"""Red signals' stop lines learned from a recording (issue 20; dpgp.generate.stop_lines)."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

import dpgp
from dpgp.generate.free_speeds import learn_free_speeds
from dpgp.generate.stop_lines import StopLines, learn_stop_lines, red_in

DT, CYCLE, SPEED, JAM = 0.5, 40.0, 8.0, 7.5
VEHICLES = SimpleNamespace(agents="vehicles", jam=JAM, lateral=1.8)


def _green(approach: int, t: float) -> bool:
    """Approach 0 (east) is green in the first half of each cycle, approach 1 (north) in the second."""
    return (t % CYCLE < CYCLE / 2) == (approach == 0)


def _signal_tracks(seed: int = 0, cycles: int = 8) -> pd.DataFrame:
    """A fixed-time signal: eastbound vehicles along y = 0 stop at x = 40, northbound ones along
    x = 45 at y = -5, one lane each, every 4-6 s. A vehicle that reaches its line at red, or
    while vehicles still queue there, stands a jam distance behind the last of them (at the line
    if none) and leaves at green, half a second after the one ahead (a queue starts up); speed
    changes are instant."""
    rng = np.random.default_rng(seed)
    rows, track = [], 0
    for approach in (0, 1):
        line = 40.0  # along the lane from where it enters
        queue: list[tuple[float, float]] = []  # (leave, cross) of the vehicles so far
        t = rng.uniform(0, 4)
        while t < cycles * CYCLE - 20:
            reach = t + line / SPEED
            ahead = [q for q in queue if q[1] > reach]  # still queued when it arrives
            if not ahead and _green(approach, reach):
                stand, leave, cross = line, reach, reach  # drives through
            else:
                stand = line - JAM * len(ahead)
                leave = max(t + stand / SPEED, ahead[-1][0] + 0.5 if ahead else 0.0)
                while not _green(approach, leave):
                    leave = (np.floor(leave / DT) + 1) * DT
                cross = leave + (line - stand) / SPEED
            queue.append((leave, cross))
            for s in np.arange(np.ceil(t / DT) * DT, cross + 40.0 / SPEED, DT):
                if t + stand / SPEED <= s < leave:
                    p, v = stand, 0.0
                elif s >= leave:
                    p, v = stand + SPEED * (s - leave), SPEED
                else:
                    p, v = SPEED * (s - t), SPEED
                xy = (p, 0.0) if approach == 0 else (45.0, p - 45.0)
                vxy = (v, 0.0) if approach == 0 else (0.0, v)
                rows.append((track, round(s, 6), *xy, *vxy))
            track += 1
            t += rng.uniform(4, 6)
    return pd.DataFrame(rows, columns=["track", "t", "x", "y", "vx", "vy"])


@pytest.fixture(scope="module")
def frames():
    return dpgp.make_frames(_signal_tracks(), dt=DT)


def _signal_phases(frames) -> np.ndarray:
    """Each frame's signal phase: 0 while the eastbound approach is green, 1 while the northbound is."""
    t = np.asarray(frames.ids, dtype=np.float64)
    return np.where(t % CYCLE < CYCLE / 2, 0, 1)


def test_the_lines_stand_where_the_queue_fronts_stood_and_are_red_where_vehicles_stopped(frames):
    lines = learn_stop_lines(SimpleNamespace(frames=frames), _signal_phases(frames), 2, VEHICLES)
    assert len(lines) == 2
    east = int(np.argmax(lines.heading[:, 0]))
    north = 1 - east
    np.testing.assert_allclose(lines.at[east], [40.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(lines.heading[east], [1.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(lines.at[north], [45.0, -5.0], atol=1e-9)
    np.testing.assert_allclose(lines.heading[north], [0.0, 1.0], atol=1e-9)
    # each line is red in the other approach's phase: there vehicles came to a stand as its
    # queue's front, and only the tail of a queue leaving at the end of green passed; in its own
    # phase they passed and none stopped
    np.testing.assert_array_equal(lines.red[:, east], [False, True])
    np.testing.assert_array_equal(lines.red[:, north], [True, False])
    for i, p in ((east, 0), (north, 1)):
        assert lines.stops[p, i] == 0 and lines.passes[p, i] > 40
        assert lines.stops[1 - p, i] > 30 and lines.passes[1 - p, i] < lines.stops[1 - p, i] / 4
    # the core's form: the red lines of a phase, (x, y, heading)
    assert lines.in_force(0) == [(45.0, -5.0, 0.0, 1.0)]
    assert lines.in_force(1) == [(40.0, 0.0, 1.0, 0.0)]
    assert "red in phases [1]" in lines.summary()


def test_phases_with_the_same_red_lines_are_one_signal_phase(signal_model):
    z = np.zeros((4, 3), dtype=np.int64)
    four = StopLines(
        np.zeros((3, 2)),
        np.tile([1.0, 0.0], (3, 1)),
        np.array([[1, 0, 1], [0, 1, 0], [0, 1, 0], [1, 0, 1]], bool),
        z,
        z,
    )
    np.testing.assert_array_equal(four.signal_groups(), [0, 1, 1, 0])
    assert "signal phases by their red lines: [0, 1, 1, 0]" in four.summary()
    # on the synthetic signal (40 s cycle, 20 s each way): two signal phases of about 20 s
    signal = signal_model.signal_phases(2)
    assert signal.counts.shape == (2, 2)
    for k in range(2):
        dwell = signal.dwell(k, censored=False)
        assert len(dwell) >= 5 and 15.0 <= np.mean(dwell) <= 25.0, dwell


def test_the_plot_draws_every_line_in_its_signal_phases_colour(signal_model):
    ax = dpgp.plot.stop_lines(signal_model, 2)
    lines = signal_model.stop_lines(2)
    bars = [a for a in ax.lines if a.get_gid() == "stop line"]
    assert len(bars) == len(lines) == 2
    groups = lines.signal_groups()
    for bar, i in zip(bars, range(len(lines))):
        (red,) = np.flatnonzero(lines.red[:, i])
        assert bar.get_color() == f"C{groups[red]}"
        np.testing.assert_allclose(np.mean(bar.get_xydata(), axis=0), lines.at[i])  # centred on the line
    assert "2 stop lines" in ax.get_title()


def test_a_line_is_red_where_enough_vehicles_stopped_and_fewer_than_half_passed():
    passes = np.array([0, 0, 2, 3, 10, 0])
    stops = np.array([1, 2, 4, 3, 9, 3])
    # (0, 1) and (0, 2): too few stopped; (2, 4): 3/8; (3, 3): 4/8, not fewer than half;
    # (10, 9): 11/21; (0, 3): 1/5
    np.testing.assert_array_equal(red_in(passes, stops), [False, False, True, False, False, True])


def test_without_evidence_of_stopping_a_line_is_green_and_pedestrians_have_none(frames):
    # one phase holding every frame: more vehicles passed each line than stopped there over the
    # whole cycle, so neither is red
    one = learn_stop_lines(SimpleNamespace(frames=frames), np.zeros(len(frames.sizes), dtype=np.int64), 1, VEHICLES)
    assert len(one) == 2 and np.all(one.passes > one.stops) and not one.red.any()
    walkers = SimpleNamespace(agents="pedestrians", jam=float("nan"), lateral=float("nan"))
    none = learn_stop_lines(SimpleNamespace(frames=frames), _signal_phases(frames), 2, walkers)
    assert len(none) == 0 and none.red.shape == (2, 0) and none.in_force(1) == []
    # free-flowing traffic (every line green): no queue fronts, no lines
    free = dpgp.make_frames(_signal_tracks().assign(vx=SPEED, vy=0.0, x=lambda d: d.t * SPEED), dt=DT)
    assert len(learn_stop_lines(SimpleNamespace(frames=free), _signal_phases(free), 2, VEHICLES)) == 0


def test_the_queue_spacing_comes_from_the_recording_not_the_fitted_jam_distance(frames):
    # a car-following fit may give a jam distance far from the recorded queues' spacing (7.5
    # here); with half of it every queued vehicle would look like a queue's front
    short = SimpleNamespace(agents="vehicles", jam=3.5, lateral=1.8)
    a = learn_stop_lines(SimpleNamespace(frames=frames), _signal_phases(frames), 2, VEHICLES)
    b = learn_stop_lines(SimpleNamespace(frames=frames), _signal_phases(frames), 2, short)
    np.testing.assert_array_equal(a.at, b.at)
    np.testing.assert_array_equal(a.red, b.red)


@pytest.fixture(scope="module")
def signal_model():
    return dpgp.DPGP(iterations=2, seed=0, progress=False).fit(dpgp.make_frames(_signal_tracks(cycles=5), dt=DT))


def test_a_red_line_stops_a_vehicle_through_the_binding_and_others_do_not(signal_model):
    # a driver that keeps its wish (τ = ∞) heading east at 8 from x = 10: through the core's
    # rollout it stands at a red line at x = 40 for eastbound traffic (its centre at most half a
    # jam distance past it), and drives through without it or with a line for northbound traffic
    from dpgp.generate.motion import motion_model
    from dpgp.generate.rollout import motion_rollouts

    fit = signal_model._fitted()
    base = motion_model(fit)
    motion = replace(base, tau=np.full(len(base.tau), np.inf), tau_rollout=None)
    mixture = [[(k, float(w)) for k, w in enumerate(fit.weights)]]

    def end(stops):
        (sim,) = motion_rollouts(
            fit, [0], [np.array([[10.0, 0.0]])], [np.array([[8.0, 0.0]])], steps=40, dt=DT, seeds=None,
            roi=(-1e3, 1e3, -1e3, 1e3), low_data_threshold=None, dynamics="interactive", motion=motion,
            support=True, mixtures=mixture, stops=stops,
        )  # fmt: skip
        return sim.positions[-1, 0], sim.velocities[-1, 0]

    x, v = end([[(40.0, 0.0, 1.0, 0.0)]])
    assert 38.0 < x[0] <= 40.0 + motion.jam / 2 and np.hypot(*v) < 1e-9
    for stops in (None, [[(40.0, 0.0, 0.0, 1.0)]], [[]]):
        x, v = end(stops)
        assert x[0] == pytest.approx(10.0 + 40 * DT * 8.0) and v[0] == pytest.approx(8.0)
    with pytest.raises(dpgp.InvalidInputError, match="stop line"):
        end([[(40.0, 0.0, 0.0, 0.0)]])
    with pytest.raises(dpgp.exceptions.ShapeError, match="one list of stop lines per rollout"):
        end([[], []])


def test_fields_are_raised_to_the_free_speeds_through_the_binding(signal_model):
    # a vehicle heading east at 8 from x = 10 following the fields (mean mode): a map without
    # any free speed changes nothing; one of 15 m/s eastbound everywhere takes it further, and
    # eastbound only: heading north, the same map changes nothing
    from dpgp.generate.motion import motion_model
    from dpgp.generate.rollout import motion_rollouts

    fit = signal_model._fitted()
    mixture = [[(k, float(w)) for k, w in enumerate(fit.weights)]]

    def run(free, start=(10.0, 0.0), v=(8.0, 0.0)):
        (sim,) = motion_rollouts(
            fit, [0], [np.array([start])], [np.array([v])], steps=20, dt=DT, seeds=None,
            roi=(-1e3, 1e3, -1e3, 1e3), low_data_threshold=None, dynamics="interactive", motion=motion_model(fit),
            support=True, mixtures=mixture, free_speeds=free,
        )  # fmt: skip
        return sim.positions

    none = np.full((40, 40, 8), np.nan)
    east = none.copy()
    east[:, :, 0] = 15.0
    plain = run(None)
    np.testing.assert_array_equal(run((-100.0, -100.0, 5.0, none)), plain)
    assert run((-100.0, -100.0, 5.0, east))[-1, 0, 0] > plain[-1, 0, 0] + 5.0
    north = run(None, (45.0, -40.0), (0.0, 8.0))
    np.testing.assert_array_equal(run((-100.0, -100.0, 5.0, east), (45.0, -40.0), (0.0, 8.0)), north)
    with pytest.raises(dpgp.exceptions.ShapeError, match="8 heading sectors"):
        run((0.0, 0.0, 5.0, np.ones((2, 2, 4))))
    with pytest.raises(dpgp.InvalidInputError, match="positive cell"):
        run((0.0, 0.0, 0.0, none))


def test_long_scenarios_pass_each_phase_its_red_lines(signal_model, monkeypatch):
    from dpgp.generate import long as long_mod

    calls, free = [], []
    real = long_mod.motion_rollouts

    def spy(*args, **kw):
        calls.append((kw["mixtures"][0], kw["stops"]))
        free.append(kw["free_speeds"])
        return real(*args, **kw)

    monkeypatch.setattr(long_mod, "motion_rollouts", spy)
    ph = signal_model.phases(2)
    lines = signal_model.stop_lines(ph)  # what the estimator shows is what generation uses
    again = learn_stop_lines(signal_model._fitted(), ph.labels, 2, long_mod.motion_model(signal_model._fitted()))
    np.testing.assert_array_equal(lines.at, again.at)
    np.testing.assert_array_equal(signal_model.stop_lines(2).red, lines.red)
    assert len(lines) == 2 and lines.red.sum(axis=0).tolist() == [1, 1]
    (s,) = signal_model.sample_scenarios(1, duration=60.0, seed=3, dynamics=True, phases=ph)
    mixture_of = {tuple(long_mod._mixture(ph.frame_shares[p])): p for p in range(2)}
    seen = {mixture_of[tuple(m)] for m, _ in calls}
    assert seen == {0, 1}  # both phases came
    for m, stops in calls:
        assert stops == [lines.in_force(mixture_of[tuple(m)])]
    # the fields are raised to the recorded free speeds (the map of the training frames)
    fit = signal_model._fitted()
    want = learn_free_speeds(fit, long_mod.lane_scale(long_mod.motion_model(fit)), long_mod.motion_model(fit))
    assert want is not None and all(f is not None for f in free)
    for f in free:
        assert f[:3] == want.core()[:3]
        np.testing.assert_array_equal(f[3], want.speeds)
    calls.clear()
    free.clear()
    (off,) = signal_model.sample_scenarios(1, duration=60.0, seed=3, dynamics=True, phases=ph, stop_lines=False)
    assert calls and all(stops is None for _, stops in calls) and all(f is None for f in free)
    free.clear()
    signal_model.sample_scenarios(1, duration=20.0, seed=3, dynamics=True, phases=ph, free_speeds=False)
    assert free and all(f is None for f in free)
    with pytest.raises(dpgp.InvalidInputError, match="long scenarios"):
        signal_model.sample_scenarios(1, steps=5, stop_lines=True)
