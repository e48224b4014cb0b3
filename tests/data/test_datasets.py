"""dpgp.datasets.synthetic: deterministic per seed, exact label proportions, vehicles in the ROI,
and patterns that the model can tell apart."""

from __future__ import annotations

import numpy as np
import pytest

import dpgp
from dpgp import datasets

KINDS = ["highway", "intersection"]


def same_frames(a, b) -> bool:
    return (
        np.array_equal(a.offsets, b.offsets)
        and np.array_equal(a.xy, b.xy)
        and np.array_equal(a.v, b.v)
        and np.array_equal(a.labels, b.labels)
    )


@pytest.mark.parametrize("kind", KINDS)
def test_same_seed_same_frames_other_seed_other_frames(kind):
    a = datasets.synthetic(kind, n_frames=50, seed=7)
    assert same_frames(a, datasets.synthetic(kind, n_frames=50, seed=7))
    b = datasets.synthetic(kind, n_frames=50, seed=8)
    assert not np.array_equal(a.labels, b.labels) and not np.array_equal(a.xy[:20], b.xy[:20])


@pytest.mark.parametrize(
    "kind, n, counts",
    [
        ("highway", 200, [100, 50, 50]),
        ("highway", 7, [3, 2, 2]),
        ("intersection", 200, [60, 60, 40, 40]),
        ("intersection", 101, [31, 30, 20, 20]),
    ],
)
def test_labels_have_the_stated_proportions(kind, n, counts):
    frames = datasets.synthetic(kind, n_frames=n, seed=1)
    props = [share for _, share in datasets.patterns(kind)]
    assert sum(props) == pytest.approx(1.0)
    assert np.bincount(frames.labels, minlength=len(props)).tolist() == counts
    assert np.abs(np.array(counts) / n - props).max() <= 1 / n
    assert len(frames) == n and frames.labels.dtype.kind == "i"
    assert not np.array_equal(frames.labels, np.sort(frames.labels)) or n < 10  # shuffled


@pytest.mark.parametrize("kind", KINDS)
def test_vehicle_counts_and_positions(kind):
    frames = datasets.synthetic(kind, n_frames=300, seed=2, vehicles=(5, 9))
    assert frames.sizes.min() == 5 and frames.sizes.max() == 9
    x0, x1, y0, y1 = datasets.roi(kind)
    lo, hi = frames.xy.min(axis=0), frames.xy.max(axis=0)
    assert lo[0] >= x0 - 1.5 and hi[0] <= x1 + 1.5 and lo[1] >= y0 - 1.5 and hi[1] <= y1 + 1.5
    assert isinstance(frames, dpgp.Frames)


def test_highway_velocities_are_the_documented_fields():
    frames = datasets.synthetic("highway", n_frames=400, seed=3, noise=0.0)
    rows = frames.labels[frames.frame_of_row]
    free = rows == 0
    lane = np.clip(np.round((frames.xy[:, 0] - 2) / 4), 0, 3).astype(int)
    np.testing.assert_allclose(frames.v[free, 1], np.array([32, 30, 28, 26])[lane[free]])
    np.testing.assert_allclose(frames.v[free, 0], 0.0, atol=1e-12)
    change = rows == 1  # lateral speed only in the lane change, and leftwards
    assert frames.v[change, 0].min() < -1.5 and frames.v[change, 0].max() <= 1e-12
    assert np.all(frames.v[rows == 2, 1] <= 24 + 1e-9)


def test_intersection_queues_stand_still_and_through_traffic_moves():
    frames = datasets.synthetic("intersection", n_frames=200, seed=4, noise=0.0)
    rows = frames.labels[frames.frame_of_row]
    speed = np.hypot(frames.v[:, 0], frames.v[:, 1])
    np.testing.assert_allclose(speed[rows == 3], 0.0)
    assert set(np.round(speed[rows == 0], 9)) == {0.0, 12.0}
    assert set(np.round(speed[rows == 2], 9)) == {0.0, 7.0}
    frame_moving = np.bincount(frames.frame_of_row, weights=speed > 0)
    assert np.all(frame_moving[frames.labels != 3] >= 4)  # 60% of at least 8 vehicles move


def test_noise_has_the_stated_standard_deviation():
    clean = datasets.synthetic("highway", n_frames=300, seed=5, noise=0.0)
    noisy = datasets.synthetic("highway", n_frames=300, seed=5, noise=0.7)
    np.testing.assert_array_equal(clean.xy, noisy.xy)
    assert np.std(noisy.v - clean.v) == pytest.approx(0.7, rel=0.05)


@pytest.mark.parametrize(
    "bad",
    [
        dict(kind="roundabout"),
        dict(kind=None),
        dict(n_frames=0),
        dict(n_frames="10"),
        dict(n_frames=2.5),
        dict(vehicles=(0, 3)),
        dict(vehicles=(5, 4)),
        dict(vehicles=3),
        dict(vehicles=(1, 2, 3)),
        dict(n_frames=10**6, vehicles=(1, 10**9)),
        dict(noise=float("nan")),
        dict(noise="loud"),
        dict(seed=-1),
        dict(seed="x"),
    ],
)
def test_bad_arguments_raise(bad):
    with pytest.raises(dpgp.InvalidInputError):
        datasets.synthetic(**bad)


# Stream speeds of each pattern, in label order (module docstring).
SPEEDS = {
    "highway": [{26, 28, 30, 32}, {18, 20, 22}, {3, 12, 18, 24}],
    "intersection": [{0, 12}, {0, 12}, {0, 7}, {0}],
}


@pytest.mark.parametrize("kind", KINDS)
def test_large_draw_keeps_the_documented_properties(kind):
    n = 20_000
    frames = datasets.synthetic(kind, n_frames=n, seed=12, vehicles=(3, 11), noise=0.1)
    props = np.array([share for _, share in datasets.patterns(kind)])
    counts = np.bincount(frames.labels, minlength=len(props))
    assert counts.sum() == n and np.abs(counts - n * props).max() < 1
    assert frames.sizes.min() == 3 and frames.sizes.max() == 11
    assert set(np.unique(frames.sizes)) == set(range(3, 12))  # every count in the range occurs
    speed = np.hypot(frames.v[:, 0], frames.v[:, 1])
    rows = frames.labels[frames.frame_of_row]
    for k, speeds in enumerate(SPEEDS[kind]):
        off = np.min(np.abs(speed[rows == k, None] - np.array(sorted(speeds))[None, :]), axis=1)
        assert off.max() < 0.1 * 6  # within six noise standard deviations of a stream speed


def test_large_draw_splits_vehicles_over_lanes_as_documented():
    frames = datasets.synthetic("highway", n_frames=5_000, seed=13, vehicles=(4, 15))
    free = np.flatnonzero(frames.labels == 0)  # four lanes, a quarter of the vehicles each
    for i in free[:500]:
        f = frames[int(i)]
        lane = np.clip(np.round((f.x - 2) / 4), 0, 3).astype(int)
        assert np.bincount(lane, minlength=4).min() >= len(f) // 4
