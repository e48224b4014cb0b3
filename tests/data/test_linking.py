"""Tracks for frames that have none (``dpgp.link_tracks``, issue 34).

Oracles: hand-built frames whose links are known (vehicles that pass close, one that appears,
one that stands, a missing frame); the SUMO junction framed by ``make_frames`` from its tracks,
whose previous steps the linking of the same frames without tracks must give back."""

from __future__ import annotations

import math

import numpy as np
import pytest

import dpgp
from dpgp.data.timeorder import time_order
from dpgp.exceptions import InvalidInputError
from dpgp.generate.motion import consecutive_pairs

from conftest import data_file as real


def _frames(rows: list[tuple[int, float, float, float, float]]) -> dpgp.Frames:
    ids = np.array(sorted({r[0] for r in rows}))
    by = {i: [r[1:] for r in rows if r[0] == i] for i in ids}
    sizes = [len(by[i]) for i in ids]
    a = np.array([x for i in ids for x in by[i]], dtype=np.float64)
    return dpgp.Frames(ids, np.r_[0, np.cumsum(sizes)], a[:, :2], a[:, 2:])


def _hand() -> dpgp.Frames:
    """dt = 1 s. A: east at 2 m/s along y = 0, braking to 1 m/s. B: west at 2 m/s along y = 1
    (they pass within a metre of each other between frames 2 and 3). C: appears at frame 1,
    north at 1 m/s. D: stands at (20, 20). Frame 4 is missing: frame 5 starts every track anew."""
    rows = []
    ax, bx = 0.0, 10.0
    for t, av in enumerate((2.0, 2.0, 2.0, 1.0)):
        rows.append((t, ax, 0.0, av, 0.0))
        rows.append((t, bx, 1.0, -2.0, 0.0))
        if t >= 1:
            rows.append((t, 5.0, -3.0 + (t - 1), 0.0, 1.0))
        rows.append((t, 20.0, 20.0, 0.0, 0.0))
        nxt = (2.0, 2.0, 1.0, 1.0)[t]
        ax += 0.5 * (av + nxt)
        bx -= 2.0
    rows += [(5, 30.0, 0.0, 1.0, 0.0), (5, 20.0, 20.0, 0.0, 0.0)]
    return _frames(rows)


def test_hand_built_frames_are_linked_as_their_vehicles_moved():
    f = dpgp.link_tracks(_hand(), dt=1.0)
    df = f.to_pandas()
    track = {(int(r.frame), round(r.x, 3), round(r.y, 3)): int(r.track) for r in df.itertuples()}
    a = [track[(t, x, 0.0)] for t, x in enumerate((0.0, 2.0, 4.0, 5.5))]
    b = [track[(t, x, 1.0)] for t, x in enumerate((10.0, 8.0, 6.0, 4.0))]
    c = [track[(t, 5.0, float(t - 4))] for t in (1, 2, 3)]
    d = [track[(t, 20.0, 20.0)] for t in range(4)]
    for ids in (a, b, c, d):
        assert len(set(ids)) == 1
    assert len({a[0], b[0], c[0], d[0]}) == 4
    # the missing frame 4 ends every track: frame 5 starts new ones
    assert {track[(5, 30.0, 0.0)], track[(5, 20.0, 20.0)]}.isdisjoint({a[0], b[0], c[0], d[0]})
    # previous steps as make_frames gives them: A's at frame 3 is its 2 m/s east step
    rows = {(int(r.frame), round(r.x, 3), round(r.y, 3)): r for r in df.itertuples()}
    r = rows[(3, 5.5, 0.0)]
    assert (r.prev_vx, r.prev_vy, r.prev_heading) == (2.0, 0.0, 0.0)
    assert rows[(2, 5.0, -2.0)].prev_heading == pytest.approx(math.pi / 2)
    assert math.isnan(rows[(1, 5.0, -3.0)].prev_heading)  # C's first appearance
    assert math.isnan(rows[(3, 20.0, 20.0)].prev_heading)  # D never moved
    assert math.isnan(rows[(5, 30.0, 0.0)].prev_heading)
    assert f.summary.dt == 1.0 and f.summary.n_tracks == len(set(f.tracks.tolist()))


def test_linked_frames_are_timed_on_the_grid_of_dt_and_their_tracks_are_consecutive():
    """Frame numbers two apart at 0.5 s a step (frame 8 of the hand-built 4 missing): ids become
    seconds, the time order finds each run, and every linked step of a track is one dt pair."""
    f0 = _hand()
    numbered = dpgp.Frames(2 * f0.ids + 10, f0.offsets, f0.xy, 0.5 * f0.v)  # 1 m/s at dt = 2 s
    f = dpgp.link_tracks(numbered, dt=2.0)
    np.testing.assert_allclose(f.ids, [10.0, 12.0, 14.0, 16.0, 20.0])
    order = time_order(f)
    assert order.dt == 2.0 and [s.tolist() for s in order.sequences()] == [[0, 1, 2, 3], [4]]
    a, b = consecutive_pairs(f, f.summary.dt)
    fr = f.frame_of_row
    assert len(a) == 11  # A, B and D three steps each, C two (it appears at the second frame)
    assert np.all(f.tracks[a] == f.tracks[b]) and np.all(fr[b] == fr[a] + 1)
    # every row with a previous step is the end of exactly one consecutive pair
    has_prev = np.flatnonzero(~np.isnan(f.prev_v[:, 0]))
    assert set(b.tolist()) == set(has_prev.tolist())


def test_the_step_is_estimated_when_the_frames_do_not_say_it():
    f = dpgp.link_tracks(_hand())
    assert f.summary.dt == pytest.approx(1.0, rel=0.03)
    np.testing.assert_array_equal(f.tracks, dpgp.link_tracks(_hand(), dt=1.0).tracks)


def test_a_gate_below_the_prediction_error_links_nothing():
    f = dpgp.link_tracks(_hand(), dt=1.3, gate=0.1)  # a wrong step: every moving prediction misses
    moving = np.hypot(f.v[:, 0], f.v[:, 1]) > 0
    assert np.all(np.isnan(f.prev_heading[moving]))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"dt": 0}, "dt must be a positive"),
        ({"dt": float("nan")}, "dt must be a positive"),
        ({"gate": -1}, "gate must be a positive"),
        ({"length_unit": "km"}, "length_unit"),
        ({"heading_min_speed": -1}, "heading_min_speed"),
    ],
)
def test_bad_settings_say_what_to_fix(kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        dpgp.link_tracks(_hand(), **kwargs)


def test_frames_out_of_time_order_or_without_motion_are_refused():
    f = _hand()
    backwards = dpgp.Frames(f.ids[::-1].copy(), f.offsets, f.xy, f.v)
    with pytest.raises(InvalidInputError, match="time order"):
        dpgp.link_tracks(backwards, dt=1.0)
    still = dpgp.Frames(f.ids, f.offsets, f.xy, np.zeros_like(f.v))
    with pytest.raises(InvalidInputError, match="no vehicle moves"):
        dpgp.link_tracks(still)


def test_linking_the_sumo_junction_gives_back_the_previous_steps_of_its_tracks():
    tracks = dpgp.read_tracks(real("sumo_grid_intersection_fcd.xml.gz"), preset="sumo")
    want = dpgp.make_frames(tracks, dt=0.5)
    bare = dpgp.Frames(want.ids, want.offsets, want.xy, want.v)
    got = dpgp.link_tracks(bare, length_unit="m")
    assert got.summary.dt == pytest.approx(0.5, rel=0.03)
    same_v = np.all(np.isclose(got.prev_v, want.prev_v, equal_nan=True), axis=1)
    same_h = np.isclose(got.prev_heading, want.prev_heading, equal_nan=True)
    assert same_v.mean() > 0.99 and same_h.mean() > 0.99, (same_v.mean(), same_h.mean())
    # no linked track holds two recorded vehicles (a track may split where a link was missed)
    for t in np.unique(got.tracks):
        assert len(np.unique(want.tracks[got.tracks == t])) == 1
