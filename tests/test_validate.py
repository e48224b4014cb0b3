"""The one ROI validator (dpgp._validate.check_roi) and the callers that used to have their own:
framing, simulation, generation and the empirical distributions now refuse the same inputs with
the same message."""

from __future__ import annotations

import numpy as np
import pytest

import dpgp
from dpgp._validate import check_roi, inside_roi

BAD = [
    None, "0123", (0, 1, 2), (0, 1, 2, 3, 4), (1, 0, 0, 1), (0, 1, 1, 1), (0, np.nan, 0, 1), (0, np.inf, 0, 1),
    (True, 2, 0, 1), ("0", "1", "0", "1"), ((0, 1), (0, 1)), (-1.7e308, 1.7e308, 0, 1), (0, 2**1100, 0, 1),
]  # fmt: skip


@pytest.mark.parametrize("roi", [(0, 1, 2, 3), [0.0, 1.5, -2, 3], np.array([0, 1, 2, 3.0]), (np.int64(0), 1, 2, 3)])
def test_good_rois_come_back_as_float_tuples(roi):
    box = check_roi(roi)
    assert box == tuple(float(v) for v in roi) and all(type(v) is float for v in box)


@pytest.mark.parametrize("roi", BAD, ids=repr)
def test_bad_rois_are_refused_everywhere_alike(roi):
    with pytest.raises(dpgp.InvalidInputError) as want:
        check_roi(roi)
    assert "roi" in str(want.value)
    frames = dpgp.datasets.synthetic("intersection", n_frames=6, seed=0)
    tracks = frames.to_pandas().rename(columns={"frame": "t"}).assign(track=lambda d: np.arange(len(d)) % 5)
    callers = [
        lambda: frames.crop(roi),
        lambda: dpgp.EmpiricalDistributions([1.0, 1.0], [[1.0]], roi),
    ]
    if roi is not None:  # None means "no cropping" to make_frames and "the data's box" to from_frames
        callers += [
            lambda: dpgp.make_frames(tracks, roi=roi),
            lambda: dpgp.EmpiricalDistributions.from_frames(frames, roi=roi),
        ]
    for call in callers:
        with pytest.raises(dpgp.InvalidInputError) as got:
            call()
        assert str(got.value) == str(want.value)


def test_simulate_and_generate_use_it(fitted_tiny):
    model = fitted_tiny
    for call in (
        lambda: model.simulate(0, steps=2, roi=(1, 0, 0, 1)),
        lambda: model.sample_scenarios(1, steps=2, roi="abcd"),
    ):
        with pytest.raises(dpgp.InvalidInputError, match=r"roi must be \(x_min, x_max, y_min, y_max\), four finite"):
            call()


@pytest.fixture(scope="module")
def fitted_tiny():
    frames = dpgp.datasets.synthetic("intersection", n_frames=20, seed=0)
    return dpgp.DPGP(iterations=2, seed=0, progress=False, noise_var=0.49).fit(frames)


def test_inside_roi_includes_the_edges_and_takes_any_leading_shape():
    xy = np.array([[[0.0, 0.0], [1.0, 1.0], [1.0001, 0.5], [np.nan, 0.5]]])
    np.testing.assert_array_equal(inside_roi(xy, (0, 1, 0, 1)), [[True, True, False, False]])
