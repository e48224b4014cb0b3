"""DPGP(inputs="position+heading") (issue 34): fields over position and each vehicle's previous
heading, fitted by the collapsed sampler on either engine, scored with the frames' headings."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import dpgp
from dpgp.exceptions import InvalidInputError


def two_way_road(n_vehicles: int = 24, seed: int = 0) -> pd.DataFrame:
    """Opposite lanes 3 m apart: eastbound at y = 0, westbound at y = 3, one vehicle entering
    every 2 s on alternate lanes, tracks sampled at 1 s."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n_vehicles):
        east = i % 2 == 0
        speed = 10.0 + rng.normal(0, 0.5)
        for t in range(2 * i, 2 * i + 8):
            s = speed * (t - 2 * i)
            x = s if east else 70.0 - s
            rows.append((i, float(t), x, 0.0 if east else 3.0, speed if east else -speed, rng.normal(0, 0.1)))
    return pd.DataFrame(rows, columns=["track", "t", "x", "y", "vx", "vy"])


@pytest.fixture(scope="module")
def road() -> tuple[dpgp.Frames, dpgp.Frames]:
    frames = dpgp.make_frames(two_way_road(), dt=1.0)
    assert frames.prev_heading is not None
    n = len(frames)
    return frames[: int(0.7 * n)], frames[int(0.7 * n) :]


@pytest.mark.parametrize("likelihood", ["exact", "hsgp"])
def test_heading_fields_fit_and_score_with_the_frames_headings(road, likelihood: str) -> None:
    train, test = road
    kw = dict(iterations=6, seed=1, progress=False, likelihood=likelihood, n_basis=(12, 4))
    blind = dpgp.DPGP(**kw).fit(train)
    headed = dpgp.DPGP(**kw, inputs="position+heading").fit(train)
    assert headed.sampler_ == "collapsed"
    assert headed.heading_scales_.shape == (headed.n_patterns_,)
    assert np.all(np.isfinite(headed.heading_scales_)) and np.all(headed.heading_scales_ > 0)
    p = headed.predict_proba(test)
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    # Two lanes 3 m apart and opposite: the heading is worth density (0.15 nats a vehicle when written).
    per_vehicle = test.sizes.sum()
    gain = (
        headed.score_samples(test, positions=False).sum() - blind.score_samples(test, positions=False).sum()
    ) / per_vehicle
    assert gain > 0.05, gain


def test_same_seed_same_chain_whatever_the_thread_count(road) -> None:
    train, _ = road
    fits = [
        dpgp.DPGP(iterations=4, seed=3, progress=False, likelihood="exact", inputs="position+heading", n_threads=n).fit(
            train
        )
        for n in (1, 2)
    ]
    np.testing.assert_array_equal(fits[0].labels_, fits[1].labels_)
    np.testing.assert_array_equal(fits[0].heading_scales_, fits[1].heading_scales_)
    assert fits[0].log_joint_ == fits[1].log_joint_


def test_heading_settings_are_checked_before_any_work(road) -> None:
    train, test = road
    with pytest.raises(InvalidInputError, match="inputs must be one of"):
        dpgp.DPGP(inputs="heading").fit(train)
    with pytest.raises(InvalidInputError, match="does not choose its engine yet"):
        dpgp.DPGP(inputs="position+heading").fit(train)
    with pytest.raises(InvalidInputError, match="collapsed sampler"):
        dpgp.DPGP(inputs="position+heading", likelihood="hsgp", sampler="subcluster").fit(train)
    no_tracks = dpgp.Frames(train.ids, train.offsets, train.xy, train.v)
    with pytest.raises(InvalidInputError, match="previous heading"):
        dpgp.DPGP(inputs="position+heading", likelihood="exact", progress=False).fit(no_tracks)
    model = dpgp.DPGP(iterations=2, inputs="position+heading", likelihood="exact", progress=False).fit(train)
    with pytest.raises(InvalidInputError, match="previous heading"):
        model.score_samples(dpgp.Frames(test.ids, test.offsets, test.xy, test.v))
    with pytest.raises(InvalidInputError, match="generation"):
        model.sample_scenarios(2, steps=3)
    with pytest.raises(InvalidInputError, match="generation"):
        model.simulate(test[0], steps=3)
    with pytest.raises(InvalidInputError, match="fit_chains does not run fields over heading"):
        dpgp.fit_chains(train, n_chains=2, iterations=2, inputs="position+heading", likelihood="exact")
