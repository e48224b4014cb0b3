"""Frames: the ragged container and the framed-table reader."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import dpgp


def test_from_arrays_groups_by_frame_and_sorts():
    f = dpgp.Frames.from_arrays([5, 3, 5, 3, 9], [1, 2, 3, 4, 5], [0, 0, 0, 0, 0], [1, 1, 1, 1, 1], [2, 2, 2, 2, 2])
    assert len(f) == 3
    assert list(f.ids) == [3, 5, 9]
    assert list(f.sizes) == [2, 2, 1]
    assert list(f[0].x) == [2, 4] and list(f[1].x) == [1, 3]
    assert list(f[-1].vy) == [2] and len(f[2]) == 1
    sub = f[[2, 0]]
    assert list(sub.ids) == [9, 3] and list(sub.xy[:, 0]) == [5, 2, 4]
    assert list(f[1:].ids) == [5, 9]
    assert list(f[np.array([True, False, True])].ids) == [3, 9]
    with pytest.raises(IndexError):
        f[3]


def test_to_pandas_round_trip():
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 20, 300)
    x, y, vx, vy = rng.normal(size=(4, 300))
    f = dpgp.Frames.from_arrays(frame, x, y, vx, vy)
    df = f.to_pandas()
    assert list(df.columns) == ["frame", "x", "y", "vx", "vy"]
    g = dpgp.read_frames(df)
    assert np.array_equal(g.ids, f.ids) and np.array_equal(g.offsets, f.offsets)
    assert np.array_equal(g.xy, f.xy) and np.array_equal(g.v, f.v)


def test_from_arrays_errors():
    with pytest.raises(dpgp.ShapeError, match="x has 2 rows but frame has 3"):
        dpgp.Frames.from_arrays([0, 0, 1], [1, 2], [1, 2, 3], [1, 2, 3], [1, 2, 3])
    with pytest.raises(
        dpgp.InvalidInputError, match=r"vx holds 1 NaN or infinite value\(s\), first at row 0 \(a vehicle of frame 0\)"
    ):
        dpgp.Frames.from_arrays([0, 1], [1, 2], [1, 2], [np.nan, 2], [1, 2])
    with pytest.raises(dpgp.ShapeError, match="no rows"):
        dpgp.Frames.from_arrays([], [], [], [], [])


def test_read_us101_frames(us101_path):
    f = dpgp.read_frames(us101_path)
    assert len(f) == 1000 and f.n_points == 14833
    # data README says 8-19 per frame; the file holds 7-30 (checked with pandas groupby)
    assert f.sizes.min() == 7 and f.sizes.max() == 30
    speed = np.hypot(f.v[:, 0], f.v[:, 1])
    assert 5 < np.median(speed) < 80  # ft/s on a freeway


def test_read_lankershim_frames(lankershim_path):
    f = dpgp.read_frames(lankershim_path)
    assert len(f) == 25 and f.n_points == 685
    assert f.sizes.min() == 18 and f.sizes.max() == 33


def test_read_frames_names_missing_columns(tmp_path):
    p = tmp_path / "t.csv"
    pd.DataFrame({"frame": [0], "x": [1.0], "y": [2.0], "speed_x": [1.0], "vy": [0.0]}).to_csv(p, index=False)
    with pytest.raises(dpgp.DataFormatError, match="no column for 'vx'"):
        dpgp.read_frames(p)
    f = dpgp.read_frames(p, vx="speed_x")
    assert f[0].vx[0] == 1.0
    with pytest.raises(dpgp.DataFormatError, match="'nope'"):
        dpgp.read_frames(p, vx="nope")


def test_read_frames_reports_bad_values(tmp_path):
    p = tmp_path / "t.tsv"
    p.write_text("frame\tx\ty\tvx\tvy\n0\t1\t2\t3\t4\n1\t1\tabc\t3\t4\n")
    with pytest.raises(dpgp.DataFormatError, match="column 'y' has 1 missing or non-numeric"):
        dpgp.read_frames(p)
    with pytest.raises(FileNotFoundError):
        dpgp.read_frames(tmp_path / "missing.csv")
