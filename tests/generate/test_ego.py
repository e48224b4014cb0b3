"""The ego vehicle of generated scenarios (issue 35): chosen by rule (nearest a point at the start,
heading that way) or placed by the user (the first vehicle of every scene), named ``Ego`` in OpenSCENARIO files (valid against the schema, its trajectory
the chosen vehicle's) and ``s{scenario}_ego`` in SUMO's, and the pairs criticality measures
relative to it."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import dpgp
from dpgp.exceptions import InvalidInputError
from dpgp.generate import openscenario as osc
from dpgp.generate.criticality import criticality
from dpgp.generate.motion import motion_model
from dpgp.generate.scenarios import Ego, choose_ego, natural_frames


@pytest.fixture(scope="module")
def model() -> dpgp.DPGP:
    frames = dpgp.datasets.synthetic("highway", n_frames=40, seed=3, vehicles=(3, 8))
    return dpgp.DPGP(iterations=2, seed=0, progress=False).fit(frames)


def test_the_ego_is_the_vehicle_nearest_the_point_heading_that_way() -> None:
    xy = np.array([[[0.0, 0.0], [10.0, 0.0], [3.0, 4.0], [1.0, 0.0]]])
    v = np.array([[[5.0, 0.0], [-5.0, 0.0], [0.0, 0.2], [0.0, 6.0]]])
    inside = np.array([[True, True, True, False]])
    sim = SimpleNamespace(positions=xy, velocities=v, in_roi=inside)
    assert choose_ego([sim], (1.0, 0.0)).tolist() == [0]  # vehicle 3 is nearer but outside the ROI
    assert choose_ego([sim], (9.0, 0.0), heading=0.0).tolist() == [0]  # vehicle 1 heads west
    assert choose_ego([sim], (9.0, 0.0), heading=170.0).tolist() == [1]
    assert choose_ego([sim], (3.0, 4.0), heading=90.0).tolist() == [-1]  # too slow to head anywhere
    assert choose_ego([sim], (3.0, 4.0)).tolist() == [2]


def test_generated_egos_export_and_measure(model, tmp_path) -> None:
    point = (0.0, 0.0)
    plain = model.sample_scenarios(5, steps=8, seed=2)
    sc = model.sample_scenarios(5, steps=8, seed=2, ego=point)
    assert plain.ego is None
    for a, b in zip(plain, sc):  # the same scenarios, an ego named
        np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(sc.ego, choose_ego(sc.simulations, point))
    assert np.all(sc.ego >= 0)
    # OpenSCENARIO: the ego's object is named Ego and follows the chosen vehicle
    paths = sc.to_openscenario(tmp_path / "xosc", model, units="m")
    table = sc.to_pandas()
    for s, p in enumerate(paths):
        assert osc.validate(p) == [], p
        back = osc.read_openscenario(p)
        ego = back[back["entity"] == "Ego"]
        want = table[(table["scenario"] == s) & (table["vehicle"] == sc.ego[s])]
        assert len(ego) == len(want) > 0
        np.testing.assert_allclose(ego["x"].to_numpy(), want["x"].to_numpy(), atol=1e-6)
        assert f"vehicle{sc.ego[s]}" not in set(back["entity"])
    # SUMO: the ego's id
    sc.to_sumo(tmp_path / "fcd.xml")
    text = (tmp_path / "fcd.xml").read_text()
    assert all(f'id="s{s}_ego"' in text for s in range(5)) and f'id="s0_v{sc.ego[0]}"' not in text
    # criticality relative to each scenario's ego: only its pairs
    mine = criticality(sc, ego=True)
    everyone = criticality(sc)
    keep = (everyone.pairs["a"] == sc.ego[everyone.pairs["scene"]]) | (
        everyone.pairs["b"] == sc.ego[everyone.pairs["scene"]]
    )
    for k in mine.pairs:
        np.testing.assert_array_equal(mine.pairs[k], everyone.pairs[k][keep])


def test_bad_egos_are_refused_before_any_work(model) -> None:
    for bad in ("front", (1.0,), (1.0, 2.0, 3.0, 4.0), (np.nan, 0.0)):
        with pytest.raises(InvalidInputError, match="ego"):
            model.sample_scenarios(2, steps=2, ego=bad)
    with pytest.raises(InvalidInputError, match="long scenarios"):
        model.sample_scenarios(1, duration=2.0, ego=(0.0, 0.0))
    with pytest.raises(InvalidInputError, match="own ego"):
        criticality(model.sample_scenarios(2, steps=2), ego=True)


def test_a_placed_ego_starts_every_scene_where_the_user_put_it(model) -> None:
    fit = model._fitted()
    x0, x1, y0, y1 = fit.roi
    at = (0.5 * (x0 + x1), 0.5 * (y0 + y1))
    scenes = model.sample_scenarios(60, steps=6, seed=4, ego=Ego(*at, placed=True))
    assert scenes.ego.tolist() == [0] * 60
    spacing = motion_model(fit).spacing
    for s, sim in enumerate(scenes):
        np.testing.assert_array_equal(sim.positions[0, 0], at)
        # the others are the source frame's vehicles, none closer to it than the pattern's spacing
        others = sim.positions[0, 1:]
        assert np.all(np.hypot(*(others - np.array(at)).T) >= spacing[scenes.patterns[s]] - 1e-9)
        assert np.all(np.isfinite(sim.velocities[0, 0])) and sim.in_roi[0, 0]
    # the measures against it, and its frame tilt's weights unchanged by it (it is not drawn)
    mine = criticality(scenes, ego=True)
    assert len(mine.pairs["a"]) and np.all((mine.pairs["a"] == 0) | (mine.pairs["b"] == 0))
    p = natural_frames(model)
    q = np.random.default_rng(1).uniform(0.5, 2.0, len(p))
    tilted = model.sample_scenarios(30, steps=2, seed=5, tilt=q, ego=Ego(*at, placed=True))
    np.testing.assert_allclose(tilted.weights, p[tilted.sources] / (q / q.sum())[tilted.sources], rtol=1e-14)
    assert tilted.ego.tolist() == [0] * 30
    # refused: outside the ROI, with the pure-field generator
    with pytest.raises(InvalidInputError, match="ROI"):
        model.sample_scenarios(2, steps=1, ego=Ego(x1 + 100.0, y1, placed=True))
    with pytest.raises(InvalidInputError, match="field"):
        model.sample_scenarios(2, steps=1, ego=Ego(*at, placed=True), dynamics="field")
    with pytest.raises(InvalidInputError, match="ego"):
        model.sample_scenarios(2, steps=1, ego=Ego(float("nan"), 0.0, placed=True))
