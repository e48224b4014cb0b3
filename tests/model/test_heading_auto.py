"""The two ``auto`` choices for fields over heading (issue 34): ``likelihood="auto"`` with
``inputs="position+heading"`` (the cost model with hsgp's basis ``2J + 1`` times the position one,
the accuracy probe with the headings; auto's fit bitwise the explicit engine's), and
``inputs="auto"`` (position without tracks; with tracks, the held-out evidence rule)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import dpgp
from dpgp.exceptions import InvalidInputError
from dpgp.model import engine_cost as ec
from dpgp.model import estimator
from dpgp.model.estimator import DPGP, HEADING_EVIDENCE, choose_inputs

from heading_roads import two_way_road

HEADED = "position+heading"
J = DPGP._heading_harmonics()  # the harmonics rule: 3 under today's prior and cap


@pytest.fixture(scope="module")
def road() -> dpgp.Frames:
    frames = dpgp.make_frames(two_way_road(), dt=1.0)
    return frames[: int(0.7 * len(frames))]


def _same_heading_fit(a: DPGP, b: DPGP) -> None:
    np.testing.assert_array_equal(a.labels_, b.labels_)
    np.testing.assert_array_equal(a.heading_scales_, b.heading_scales_)
    np.testing.assert_array_equal(a.length_scales_, b.length_scales_)
    assert a.history_["log_joint"] == b.history_["log_joint"]


# --- likelihood="auto" over heading ---------------------------------------------------------------


def test_the_heading_basis_multiplies_m_in_hsgp_cost_only():
    n, frames, m = [40, 300, 900], [3, 5, 4] * 50, 60
    pos, head = ec.choose(n, frames, m, None), ec.choose(n, frames, m, None, harmonics=3)
    assert ec.heading_basis_size(m, 3) == 7 * m and head.basis == 7 * m and head.heading_functions == 7
    assert (
        ec.heading_basis_size(m, 3, 4) == m + 24
        and ec.choose(n, frames, m, None, harmonics=3, heading_size=4).basis == m + 24
    )
    assert pos.basis == m and pos.heading_functions == 1
    assert head.hsgp_seconds == ec.sweep_seconds("hsgp", n, frames, 7 * m)
    assert head.exact_seconds == pos.exact_seconds  # exact's product kernel costs the position one's
    up = ec.choose_upfront([2] * 5, m, None, harmonics=3)
    assert up is not None and up.basis == 7 * m and up.hsgp_seconds == ec.sweep_seconds("hsgp", [], [2] * 5, 7 * m)
    with pytest.raises(ValueError):
        ec.heading_basis_size(m, -1)


def test_the_probe_reads_the_kernel_the_heading_fit_runs():
    """Opposite lanes 0.2 m apart: over positions alone the GP must bend between opposite
    velocities within centimetres, which only exact can (a gap far over the tolerance); with the
    headings (what the fit runs) the two engines agree."""
    frames = dpgp.make_frames(two_way_road(n_vehicles=16, gap=0.2), dt=1.0)
    xy, v, h = frames.xy, frames.v, frames.prev_heading
    params = dpgp.GPParams((10.0, 10.0), tuple(v.var(0)), (1.0, 1.0), tuple(v.mean(0)))
    basis = dpgp.hsgp.Basis(tuple(xy.mean(0)), (60.0, 10.0), (8, 4))
    scales = tuple(s * 1.2 for s in ec.PROBE_HEADING_SCALES)
    blind = ec.resolution_gap(xy, v, params, basis)
    headed = ec.resolution_gap(xy, v, params, dataclasses.replace(basis, harmonics=J), h, scales)
    assert blind > 2 * ec.PROBE_TOLERANCE and headed < ec.PROBE_TOLERANCE / 4, (blind, headed)
    with pytest.raises(ValueError, match="together"):
        ec.resolution_gap(xy, v, params, basis, h)


def test_auto_heading_fit_is_what_the_cost_model_predicts(road):
    """The small two-way road, today's coefficients: exact's worst case is fast enough, so auto
    runs exact up front; engine_choice_ holds the cost model's figures (hsgp's on the sub-cluster
    sampler it would run on, with M = m_x m_y + 2J m'_x m'_y) and the fit is bitwise
    likelihood="exact"'s."""
    kw = dict(iterations=3, seed=1, progress=False, n_basis=(12, 4), inputs=HEADED)
    auto = DPGP(**kw).fit(road)
    m = 12 * 4
    # The heading blocks' position functions: min(m, max(ceil(m / 4), 10)) per axis.
    heading_size = 10 * 4
    assert (estimator.HEADING_BASIS_STRIDE, estimator.HEADING_BASIS_MIN_COUNT) == (4, 10)
    predicted = ec.choose_upfront(road.sizes, m, auto.memory_budget_, True, J, heading_size)
    assert predicted is not None and predicted.engine == "exact"
    choice = auto.engine_choice_
    assert {k: choice[k] for k in predicted.to_dict()} == predicted.to_dict()
    big_m = m + 2 * J * heading_size
    assert choice["basis"] == big_m and choice["heading_functions"] == 2 * J + 1
    assert choice["exact_seconds"] == ec.sweep_seconds("exact", [road.n_points], road.sizes)
    assert choice["hsgp_seconds"] == ec.sweep_seconds("subcluster", [road.n_points], road.sizes, big_m)
    assert choice["sampler"]["sampler"] == "collapsed" and choice["inputs"] == {"inputs": HEADED, "why": "given"}
    assert auto.likelihood_ == "exact" and auto.inputs_ == HEADED
    _same_heading_fit(auto, DPGP(**kw, likelihood="exact").fit(road))


@pytest.mark.parametrize("winner", ["exact", "hsgp"])
def test_auto_heading_after_the_probe_is_the_engine_it_picks(road, monkeypatch, winner):
    """Undecided up front, auto initialises hsgp over heading, predicts both engines from its
    pattern sizes (hsgp at M = m_x m_y + 2J m'_x m'_y) and, where hsgp is faster, probes with
    the headings: the fit is bitwise the explicit engine's, heading length scales included."""
    m = 12 * 4
    big_m = m + 2 * J * 10 * 4  # heading blocks on min(m, max(ceil(m / 4), 10)) position functions per axis
    # hsgp over heading would run on the sub-cluster sampler: its coefficients are those costed.
    if winner == "exact":  # exact pays n³, hsgp a flat half of exact's worst case per point
        flat = (
            0.5 * road.n_points**3 / ec.HSGP_MARGIN / ec.features("subcluster", [road.n_points], road.sizes, big_m)[0]
        )
        coefficients = {"exact": (0.0, 0.0, 1.0), "subcluster": (flat, 0.0, 0.0)}
    else:  # exact's per-frame cost dwarfs hsgp's
        coefficients = {"exact": (1.0, 0.0, 0.0), "subcluster": (1e-9, 0.0, 0.0)}
    monkeypatch.setattr(ec, "COEFFICIENTS", coefficients)
    kw = dict(iterations=2, seed=2, progress=False, n_basis=(12, 4), inputs=HEADED)
    auto = DPGP(**kw).fit(road)
    choice = auto.engine_choice_
    assert choice["sizes_from"] == "hsgp initialisation" and auto.likelihood_ == winner
    assert choice["basis"] == big_m and choice["heading_functions"] == 2 * J + 1
    if winner == "hsgp":  # the probe ran, with the headings, and found hsgp accurate here
        assert choice["resolution_gap"] is not None and choice["resolution_gap"] <= ec.PROBE_TOLERANCE
        assert len(choice["probe_gaps"]) == len(ec.PROBE_SEEDS)
        assert auto.basis_ is not None and auto.engine_info()["heading"]["harmonics"] == J
        assert auto.engine_info()["heading"]["heading_counts"] == [10, 4]
    else:
        assert choice["resolution_gap"] is None and auto.basis_ is None
    assert choice["inputs"] == {"inputs": HEADED, "why": "given"}
    _same_heading_fit(auto, DPGP(**kw, likelihood=winner).fit(road))


# --- inputs="auto" --------------------------------------------------------------------------------


def test_choose_inputs_follows_the_evidence_rule():
    assert choose_inputs(False)["inputs"] == "position" and "no tracks" in choose_inputs(False)["why"]
    today = choose_inputs(True)
    assert today["inputs"] == "position" and today["evidence"] == {k: list(v) for k, v in HEADING_EVIDENCE.items()}
    losing = [name for name, margins in HEADING_EVIDENCE.items() if min(margins) <= 0]
    assert losing and all(name in today["why"].split("not on ")[1] for name in losing)
    worst = min(m for margins in HEADING_EVIDENCE.values() for m in margins)
    assert f"{worst:+.2f}" in today["why"]
    assert choose_inputs(True, {"a": (0.3, 0.1), "b": (0.2,)})["inputs"] == HEADED
    assert choose_inputs(True, {"a": (0.3, 0.0)})["inputs"] == "position"  # not better is not better
    assert choose_inputs(True, {})["inputs"] == "position"  # nothing measured
    blocked = choose_inputs(True, {"a": (0.3,)}, blocked="dynamics='sticky'")
    assert blocked["inputs"] == "position" and "sticky" in blocked["why"]


def test_auto_inputs_today_fits_position_and_says_why(road):
    assert DPGP().inputs == "position"  # the default stays the paper's model
    kw = dict(iterations=2, seed=1, progress=False, likelihood="exact")
    auto = DPGP(**kw, inputs="auto").fit(road)
    assert auto.inputs == "auto" and auto.inputs_ == "position" and not hasattr(auto, "heading_scales_")
    why = auto.engine_choice_["inputs"]
    assert why["inputs"] == "position" and why["evidence"]["sumo_grid"] == list(HEADING_EVIDENCE["sumo_grid"])
    np.testing.assert_array_equal(auto.labels_, DPGP(**kw).fit(road).labels_)
    no_tracks = dpgp.Frames(road.ids, road.offsets, road.xy, road.v)
    blind = DPGP(**kw, inputs="auto").fit(no_tracks)
    assert blind.inputs_ == "position" and "no tracks" in blind.engine_choice_["inputs"]["why"]


@pytest.fixture
def heading_wins(monkeypatch):
    """Evidence under which auto takes the heading form on frames with tracks."""
    monkeypatch.setattr(estimator, "HEADING_EVIDENCE", {"peachtree": (0.4, 0.2), "sumo_grid": (0.1,)})


def test_auto_inputs_with_favourable_evidence_is_the_heading_fit(road, heading_wins, tmp_path):
    kw = dict(iterations=2, seed=1, progress=False, likelihood="exact")
    auto = DPGP(**kw, inputs="auto").fit(road)
    assert auto.inputs_ == HEADED and auto.engine_choice_["inputs"]["inputs"] == HEADED
    _same_heading_fit(auto, DPGP(**kw, inputs=HEADED).fit(road))
    # the file keeps the setting and the input that ran; the loaded model computes over heading
    auto.save(tmp_path / "m.npz")
    back = DPGP.load(tmp_path / "m.npz")
    assert back.inputs == "auto" and back.inputs_ == HEADED
    assert back.engine_choice_ == auto.engine_choice_
    np.testing.assert_array_equal(back.heading_scales_, auto.heading_scales_)
    np.testing.assert_array_equal(back.score_samples(road), auto.score_samples(road))
    # settings the heading form cannot run with keep fields over position, saying why
    sticky = DPGP(**kw, inputs="auto", dynamics="sticky").fit(road)
    assert sticky.inputs_ == "position" and "sticky" in sticky.engine_choice_["inputs"]["why"]
    # a fresh fit resolves afresh (no stale inputs_ from the last one)
    auto.set_params(inputs="position").fit(road)
    assert auto.inputs_ == "position" and auto.engine_choice_["inputs"]["why"] == "given"
    with pytest.raises(InvalidInputError, match="fit_chains does not run fields over heading"):
        dpgp.fit_chains(road, n_chains=2, iterations=2, inputs="auto", likelihood="exact")


def test_inputs_setting_is_checked(road):
    with pytest.raises(InvalidInputError, match="inputs must be one of"):
        DPGP(inputs="heading").fit(road)
