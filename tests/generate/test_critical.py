"""Importance-sampled scenarios (issue 35): exact likelihood ratios of the tilted starting frames
(against a direct computation of both probabilities), weights of mean 1, and an event's rate from
tilted scenes agreeing with crude Monte Carlo of the natural generator."""

from __future__ import annotations

import math

import numpy as np
import pytest

import dpgp
from dpgp.exceptions import InvalidInputError
from dpgp.generate.critical import MAX_SHIFT, Tilt, learn_tilt, natural_frames
from dpgp.generate.criticality import Estimate, Event, criticality


@pytest.fixture(scope="module")
def model() -> dpgp.DPGP:
    frames = dpgp.datasets.synthetic("intersection", n_frames=60, seed=8)
    return dpgp.DPGP(iterations=3, seed=3, progress=False).fit(frames)


def test_the_weights_are_the_ratio_of_the_frames_probabilities(model) -> None:
    labels = model.labels_
    # naturally: a pattern by its weight, then one of its frames uniformly
    direct = np.array([model.weights_[k] / np.sum(labels == k) for k in labels])
    np.testing.assert_allclose(natural_frames(model), direct, rtol=1e-15)
    assert natural_frames(model).sum() == pytest.approx(1.0, abs=1e-12)
    q = np.random.default_rng(0).uniform(0.2, 3.0, size=len(labels))
    scenes = model.sample_scenarios(3000, steps=1, seed=5, tilt=q)
    q = q / q.sum()
    np.testing.assert_allclose(scenes.weights, direct[scenes.sources] / q[scenes.sources], rtol=1e-14)
    np.testing.assert_array_equal(scenes.patterns, labels[scenes.sources])
    # each scene starts from its source frame: its vehicles are a subset of the frame's positions
    frames = model.frames_
    for s in range(5):
        start = scenes.simulations[s].positions[0][scenes.simulations[s].in_roi[0]]
        f = frames[int(scenes.sources[s])]
        assert all(np.any(np.all(np.isclose(f.xy, p), axis=1)) for p in start)
    # E_q[w] = 1: the mean weight within 4 standard errors, the exact expectation to rounding
    w = scenes.weights
    assert abs(w.mean() - 1) <= 4 * w.std(ddof=1) / math.sqrt(len(w))
    assert float(np.sum(q * direct / q)) == pytest.approx(1.0, abs=1e-12)
    # the natural probabilities as a tilt: every weight exactly 1
    natural = model.sample_scenarios(50, steps=1, seed=5, tilt=natural_frames(model))
    np.testing.assert_allclose(natural.weights, 1.0, rtol=1e-14)


def test_a_tilted_estimate_agrees_with_crude_monte_carlo(model) -> None:
    # braking at the bound (9 m/s²) within 3 steps: in 6 % of natural scenes, from some frames far
    # more often than from others (over 8 steps, 17 %: reached in the first round, little to tilt)
    event = "deceleration>8.9"
    tilt, levels = learn_tilt(model, event, per_round=300, rounds=4, steps=3, seed=1)
    assert np.all(tilt.frames > 0) and tilt.frames.sum() == pytest.approx(1.0)
    assert tilt.shift is not None and 0 < math.hypot(*tilt.shift) <= MAX_SHIFT
    tilted = model.sample_scenarios(3000, steps=3, seed=2, tilt=tilt)
    crude = model.sample_scenarios(3000, steps=3, seed=3)
    a, b = tilted.estimate(event), crude.estimate(event)
    assert crude.weights is None and b.ess == pytest.approx(3000) and b.hits > 30
    assert abs(a.rate - b.rate) <= 4 * math.hypot(a.stderr, b.stderr), (a, b)
    # the tilt draws the event more often than nature does
    assert a.hits > 1.5 * b.hits, (a.hits, b.hits, levels)
    assert a.interval[0] <= a.rate <= a.interval[1] and a.per_hour == pytest.approx(a.rate * 3600 / 1.5)
    # measures computed once give the same estimate; batches combine by their hits and weights
    per = criticality(tilted).per_scene()
    assert tilted.estimate(event, measures=per) == a
    hit = Event.parse(event).happened(per)
    halves = [
        Estimate.of(hit[s], tilted.weights[s], event=event, seconds=1.5) for s in (slice(0, 1500), slice(1500, None))
    ]
    joined = Estimate.of(np.r_[hit[:1500], hit[1500:]], np.r_[tilted.weights[:1500], tilted.weights[1500:]],
                         event=event, seconds=1.5)  # fmt: skip
    assert joined == a and sum(h.hits for h in halves) == a.hits
    assert a.rate == pytest.approx(np.mean([h.rate for h in halves]))
    with pytest.raises(InvalidInputError, match="weights"):
        Estimate.of(hit, tilted.weights[:-1])


def test_an_estimates_acceleration_is_crude_monte_carlos_scenes_for_its_error() -> None:
    rng = np.random.default_rng(4)
    hit = rng.random(4000) < 0.05
    natural = Estimate.of(hit)  # natural draws: the binomial variance, (n - 1) / n of it
    assert natural.acceleration == pytest.approx(3999 / 4000, rel=1e-12)
    # a tilt that draws the event in every scene, with weights near the rate: many crude scenes
    # for each of its own; weights that vary widely cost more than crude Monte Carlo
    w_good = 0.05 * (1 + 0.1 * rng.standard_normal(4000))
    good = Estimate.of(np.ones(4000, dtype=bool), w_good)
    want = good.rate * (1 - good.rate) / np.var(w_good, ddof=1)  # stderr² n = the weights' variance
    assert good.acceleration == pytest.approx(want, rel=1e-9) and good.acceleration > 100
    w_bad = np.where(rng.random(4000) < 0.001, 50.0, 0.0)
    bad = Estimate.of(np.ones(4000, dtype=bool), w_bad)
    assert bad.acceleration < 1
    assert math.isnan(Estimate.of(np.zeros(10, dtype=bool)).acceleration)
    assert Estimate.of(np.ones(10, dtype=bool), np.full(10, 0.2)).acceleration == math.inf
    assert "x crude Monte Carlo" in str(natural)


def test_a_shifted_innovation_is_weighed_exactly(model) -> None:
    """One innovation per scene drawn from N(mu, I): weights of mean 1, the natural generator at
    mu = 0 bit for bit, and an event's estimate agreeing with crude Monte Carlo."""
    p = natural_frames(model)
    plain = model.sample_scenarios(40, steps=6, seed=4, tilt=p)
    zero = model.sample_scenarios(40, steps=6, seed=4, tilt=Tilt(p, (0.0, 0.0)))
    for a, b in zip(plain, zero):
        np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(zero.weights, 1.0)
    shifted = model.sample_scenarios(4000, steps=6, seed=5, tilt=Tilt(None, (-2.0, 0.5)))
    w = shifted.weights
    assert np.all(np.isfinite(w) & (w > 0)) and np.std(w) > 0.1
    assert abs(w.mean() - 1) <= 4 * w.std(ddof=1) / math.sqrt(len(w)), w.mean()
    # the shifted innovation is drawn around the shift (where its vehicle was still there)
    z = shifted.picks[np.all(np.isfinite(shifted.picks), axis=1)]
    assert len(z) > 1000 and np.allclose(z.mean(axis=0), [-2.0, 0.5], atol=0.15)
    event = "deceleration>8.9"
    crude = model.sample_scenarios(4000, steps=6, seed=6).estimate(event)
    a = shifted.estimate(event)
    assert crude.hits > 30 and abs(a.rate - crude.rate) <= 4 * math.hypot(a.stderr, crude.stderr), (a, crude)
    for bad in ((1.0,), (np.nan, 0.0), "up"):
        with pytest.raises(InvalidInputError, match="shift"):
            model.sample_scenarios(2, steps=1, tilt=Tilt(None, bad))  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="stochastic"):
        model.sample_scenarios(2, steps=1, tilt=Tilt(None, (1.0, 0.0)), stochastic=False)


def test_events_and_tilts_are_checked(model) -> None:
    assert Event.parse("ttc < 1.5") == Event("ttc", 1.5)
    assert str(Event.parse("deceleration>4")) == "deceleration>4"
    for bad in ("ttc>1", "speed<3", "ttc<x", "ttc<inf", ""):
        with pytest.raises(InvalidInputError, match="event"):
            Event.parse(bad)
    n = len(model.labels_)
    for bad in (np.ones(n - 1), -np.ones(n), np.zeros(n), np.r_[0.0, np.ones(n - 1)], "flat"):
        with pytest.raises(InvalidInputError, match="tilt"):
            model.sample_scenarios(2, steps=1, tilt=bad)
    with pytest.raises(InvalidInputError, match="tilt"):
        model.sample_scenarios(2, steps=1, tilt=np.ones(n), dynamics="field")
    scenes = model.sample_critical(20, "collision", per_round=50, rounds=2, seed=0, steps=4)
    assert scenes.weights.shape == (20,) and np.all(scenes.weights > 0)
    for bad in ({"per_round": 0}, {"rounds": 0}, {"rounds": 1.5}, {"per_round": True}):
        with pytest.raises(InvalidInputError, match="round"):
            learn_tilt(model, "collision", steps=2, **bad)


def test_tilted_scenes_export_to_valid_openscenario(model, tmp_path) -> None:
    from dpgp.generate import openscenario as osc

    scenes = model.sample_critical(3, "gap<1.0", per_round=40, rounds=2, seed=1, steps=6, ego=(0.0, 0.0))
    for p in scenes.to_openscenario(tmp_path / "xosc", model, units="m"):
        assert osc.validate(p) == [], p
        assert "Ego" in set(osc.read_openscenario(p)["entity"])
