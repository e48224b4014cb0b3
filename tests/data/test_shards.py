"""Sharded frames (issue 33): Frames.to_parquet(directory, shards=N), dpgp.read_frames(directory),
one shard read alone, make_frames(out=, shards=), atomic writes, and damaged directories."""

from __future__ import annotations

import json
import os
import shutil
import tracemalloc

import numpy as np
import pandas as pd
import pytest

import dpgp
from dpgp.data import _shardfile, shards
from dpgp.data.read import detect_format

from conftest import data_file as real


def assert_same_frames(a: dpgp.Frames, b: dpgp.Frames) -> None:
    """Equal points, velocities, offsets, ids (and their dtype), labels, track ids and summary."""
    assert len(a) == len(b) and a.n_points == b.n_points
    assert a.ids.dtype == b.ids.dtype and np.array_equal(a.ids, b.ids)
    assert np.array_equal(a.offsets, b.offsets)
    assert np.array_equal(a.xy, b.xy) and np.array_equal(a.v, b.v)
    assert (a.labels is None) == (b.labels is None)
    if a.labels is not None:
        assert a.labels.dtype == b.labels.dtype and np.array_equal(a.labels, b.labels)
    assert (a.tracks is None) == (b.tracks is None)
    if a.tracks is not None:
        assert np.array_equal(a.tracks, b.tracks)
    assert a.summary == b.summary


@pytest.fixture(scope="module")
def highway() -> dpgp.Frames:
    return dpgp.datasets.synthetic("highway", 500, seed=0)


def _scene_tracks() -> pd.DataFrame:
    """Two scenes of two tracks each, 0-4.9 s at 10 Hz, in feet with NGSIM-like size columns."""
    t = np.arange(0, 5, 0.1)
    n = len(t)
    return pd.DataFrame(
        {
            "track": np.repeat([0, 1, 2, 3], n),
            "t": np.tile(t, 4),
            "x": np.tile(t, 4) * 30.0 + np.repeat([0.0, 5, 0, 5], n),
            "y": np.repeat([0.0, 12, 0, 12], n),
            "scene": np.repeat(["east", "east", "west", "west"], n),
        }
    )


# --- round trips ---------------------------------------------------------------------------------


@pytest.mark.parametrize("n_shards", [1, 3, 7])
def test_synthetic_round_trip(highway, tmp_path, n_shards):
    out = tmp_path / "frames"
    m = highway.to_parquet(out, shards=n_shards)
    assert sorted(os.listdir(out)) == sorted([s.file for s in m.shards] + ["manifest.json"])
    assert m.n_shards == n_shards and m.n_frames == 500 and m.n_points == highway.n_points
    assert [s.start for s in m.shards][0] == 0 and m.shards[-1].stop == 500
    back = dpgp.read_frames(out)
    assert_same_frames(highway, back)
    assert back.labels is not None and np.array_equal(back.labels, highway.labels)
    # the manifest read alone says the same as the one the write returned
    assert shards.read_manifest(out) == m


def test_us101_round_trip(us101_path, tmp_path):
    frames = dpgp.read_frames(us101_path)
    m = frames.to_parquet(tmp_path / "us101", shards=5)
    back = dpgp.read_frames(tmp_path / "us101")
    assert_same_frames(frames, back)
    assert len(back) == 1000 and back.n_points == 14833
    # ids 1..1000 are times one step apart: one run, in order
    assert m.dt == 1.0 and m.in_time_order and m.n_sequences == 1
    assert [s.continues for s in m.shards] == [False, True, True, True, True]


def test_make_frames_writes_shards_with_summary_units_and_time_order(tmp_path):
    tracks = _scene_tracks()
    expected = dpgp.make_frames(tracks, dt=0.5, units="ft->m")
    got = dpgp.make_frames(tracks, dt=0.5, units="ft->m", out=tmp_path / "f", shards=4)
    assert_same_frames(expected, got)
    back = dpgp.read_frames(tmp_path / "f")
    assert_same_frames(expected, back)
    assert isinstance(back.summary, dpgp.FramingSummary) and back.summary.n_scenes == 2
    assert back.ids[0] == ("east", 0.0) and back.ids[-1] == ("west", 4.5)
    m = shards.read_manifest(tmp_path / "f")
    assert m.ids == {"kind": "pair"} and m.tracks and m.units == "m" == back.summary.length_unit
    assert m.dt == 0.5 and m.in_time_order and m.n_sequences == 2  # one run per scene
    # 20 frames, 10 per scene, in 4 shards of 5: the third starts the second scene
    assert [(s.start, s.stop) for s in m.shards] == [(0, 5), (5, 10), (10, 15), (15, 20)]
    assert [s.continues for s in m.shards] == [False, True, False, True]


def test_make_frames_keeps_real_framing_provenance(tmp_path):
    peachtree = dpgp.read_ngsim(real("ngsim_peachtree_raw.csv"))
    expected = dpgp.make_frames(peachtree, dt=0.5, units="ft->m")
    dpgp.make_frames(peachtree, dt=0.5, units="ft->m", out=tmp_path / "p", shards=3)
    back = dpgp.read_frames(tmp_path / "p")
    assert_same_frames(expected, back)
    s = back.summary
    assert s.length_unit == "m" and s.object_type == "vehicle" and s.object_size is not None
    assert isinstance(s.object_size, tuple) and s.object_size == expected.summary.object_size
    assert shards.read_manifest(tmp_path / "p").units == "m"


@pytest.mark.parametrize(
    "ids",
    [
        np.array(["a", "bb", "c", "d"]),
        np.array(["a", "bb", "c", "d"], dtype=object),
        np.array([0.5, 1.5, 2.5, 4.0]),
        np.array([3, 1, 2, 2], dtype=np.uint16),
        np.array(["2020-01-01", "2020-01-02", "2020-01-03", "2020-01-05"], dtype="datetime64[ns]"),
    ],
)
def test_ids_labels_and_tracks_keep_their_values_and_dtypes(tmp_path, ids):
    labels = np.array(["p", "q", "p", "r"], dtype=object)
    frames = dpgp.Frames(ids, [0, 1, 3, 4, 6], np.arange(12.0).reshape(6, 2), -np.ones((6, 2)), labels, np.arange(6))
    frames.to_parquet(tmp_path / "f", shards=3)
    assert_same_frames(frames, dpgp.read_frames(tmp_path / "f"))


# --- one shard alone -----------------------------------------------------------------------------


def test_read_shard_equals_the_slice_and_shards_make_up_the_whole(highway, tmp_path):
    m = highway.to_parquet(tmp_path / "f", shards=4)
    parts = []
    for i, info in enumerate(m.shards):
        part, start = shards.read_shard(tmp_path / "f", i)
        assert start == info.start and len(part) == info.n_frames and part.n_points == info.points
        assert_same_frames(highway[info.start : info.stop], part)
        parts.append(part)
    assert sum(len(p) for p in parts) == len(highway)
    assert np.array_equal(np.concatenate([p.ids for p in parts]), highway.ids)
    assert np.array_equal(np.concatenate([p.xy for p in parts]), highway.xy)
    assert np.array_equal(np.concatenate([p.v for p in parts]), highway.v)
    assert np.array_equal(np.concatenate([p.labels for p in parts]), highway.labels)
    assert np.array_equal(np.concatenate([p.sizes for p in parts]), highway.sizes)
    # iterating, and reading by a manifest already read, give the same shards
    for (a, sa), (b, sb) in zip(shards.iter_shards(tmp_path / "f"), (shards.read_shard(m, i) for i in range(4))):
        assert sa == sb
        assert_same_frames(a, b)


def test_shards_balance_vehicles_and_hold_at_least_one_frame_each():
    rng = np.random.default_rng(1)
    sizes = rng.integers(1, 40, 1000)
    offsets = np.r_[0, np.cumsum(sizes)]
    bounds = _shardfile.shard_bounds(offsets, 8)
    assert bounds[0] == 0 and bounds[-1] == 1000 and np.all(np.diff(bounds) >= 1)
    points = np.diff(offsets[bounds])
    assert points.max() - points.min() <= 2 * sizes.max()  # within a frame or two of even
    # as many shards as frames: one frame each, even where one frame holds most vehicles
    skewed = np.r_[0, np.cumsum([1000, 1, 1, 1, 1])]
    assert list(_shardfile.shard_bounds(skewed, 5)) == [0, 1, 2, 3, 4, 5]
    assert list(_shardfile.shard_bounds(skewed, 2)) == [0, 1, 5]
    assert list(_shardfile.shard_bounds(np.array([0, 3]), 1)) == [0, 1]


def test_time_order_with_gaps_and_frames_out_of_order(tmp_path):
    ids = np.array([0.0, 1.0, 2.0, 5.0, 6.0, 10.0])
    frames = dpgp.Frames(ids, np.arange(7), np.zeros((6, 2)), np.ones((6, 2)))
    m = frames.to_parquet(tmp_path / "a", shards=3)
    assert m.dt == 1.0 and m.in_time_order and m.n_sequences == 3
    assert [(s.start, s.stop) for s in m.shards] == [(0, 2), (2, 4), (4, 6)]
    assert [s.continues for s in m.shards] == [False, True, True]  # 1 -> 2 and 5 -> 6 are one step
    shuffled = frames[[0, 1, 2, 4, 3, 5]]  # ids 0, 1, 2, 6, 5, 10
    m = shuffled.to_parquet(tmp_path / "b", shards=2)
    assert not m.in_time_order  # kept in the order given, and said so
    # the second shard starts at 6, whose predecessor 5 is not the first shard's last frame
    assert [(s.start, s.continues) for s in m.shards] == [(0, False), (3, False)]
    assert_same_frames(shuffled, dpgp.read_frames(tmp_path / "b"))
    words = dpgp.Frames(np.array(["x", "y"]), np.arange(3), np.zeros((2, 2)), np.ones((2, 2)))
    m = words.to_parquet(tmp_path / "c", shards=2)
    assert m.dt is None and m.n_sequences is None and [s.continues for s in m.shards] == [None, None]


def test_dpgp_read_recognises_a_directory_of_shards(highway, tmp_path):
    highway.to_parquet(tmp_path / "f", shards=2)
    assert detect_format(tmp_path / "f") == "frames"
    assert_same_frames(highway, dpgp.read(tmp_path / "f"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(dpgp.DataFormatError, match="manifest.json is missing"):
        dpgp.read(tmp_path / "empty")


# --- atomic writes -------------------------------------------------------------------------------


def _fail_on_second_shard(monkeypatch, error):
    original = _shardfile._write_shard
    calls = []

    def write(file, *args, **kwargs):
        calls.append(file)
        if len(calls) == 2:
            assert os.path.exists(calls[0])  # a shard was written: the failure is mid-write
            raise error
        original(file, *args, **kwargs)

    monkeypatch.setattr(_shardfile, "_write_shard", write)
    return calls


@pytest.mark.parametrize("error", [OSError(28, "No space left on device"), KeyboardInterrupt()])
def test_a_failure_mid_write_leaves_nothing(highway, tmp_path, monkeypatch, error):
    calls = _fail_on_second_shard(monkeypatch, error)
    with pytest.raises(type(error)):
        highway.to_parquet(tmp_path / "f", shards=3)
    assert len(calls) == 2
    assert not (tmp_path / "f").exists()
    assert os.listdir(tmp_path) == []  # and no temporary directory left beside it


def test_a_failed_overwrite_keeps_the_old_frames(highway, tmp_path, monkeypatch):
    old = highway[:100]
    old.to_parquet(tmp_path / "f", shards=2)
    _fail_on_second_shard(monkeypatch, OSError(5, "I/O error"))
    with pytest.raises(OSError, match="I/O error"):
        highway.to_parquet(tmp_path / "f", shards=3, overwrite=True)
    assert_same_frames(old, dpgp.read_frames(tmp_path / "f"))
    assert os.listdir(tmp_path) == ["f"]


def test_a_failed_final_rename_puts_the_old_frames_back(highway, tmp_path, monkeypatch):
    old = highway[:100]
    old.to_parquet(tmp_path / "f", shards=2)
    rename = os.rename

    def refuse_the_new(src, dst):
        if str(src).endswith(".tmp"):
            raise PermissionError(13, "Permission denied", src)
        rename(src, dst)

    monkeypatch.setattr(_shardfile.os, "rename", refuse_the_new)
    with pytest.raises(PermissionError):
        highway.to_parquet(tmp_path / "f", shards=3, overwrite=True)
    monkeypatch.undo()
    assert_same_frames(old, dpgp.read_frames(tmp_path / "f"))
    assert os.listdir(tmp_path) == ["f"]


def test_overwrite_rules(highway, tmp_path):
    out = tmp_path / "f"
    highway[:50].to_parquet(out, shards=2)
    with pytest.raises(FileExistsError, match="not empty; pass overwrite=True"):
        highway.to_parquet(out, shards=3)
    assert_same_frames(highway[:50], dpgp.read_frames(out))
    m = highway.to_parquet(out, shards=3, overwrite=True)
    assert m.n_shards == 3 and sorted(os.listdir(out)) == sorted([s.file for s in m.shards] + ["manifest.json"])
    assert_same_frames(highway, dpgp.read_frames(out))
    # never a directory of other files, even with overwrite=True
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="holds no sharded frames"):
        highway.to_parquet(other, shards=2, overwrite=True)
    assert os.listdir(other) == ["notes.txt"]
    # an empty directory is a free place; a file is not
    (tmp_path / "empty").mkdir()
    highway.to_parquet(tmp_path / "empty", shards=2)
    assert_same_frames(highway, dpgp.read_frames(tmp_path / "empty"))
    (tmp_path / "file").write_text("x")
    with pytest.raises(FileExistsError, match="this path is a file"):
        highway.to_parquet(tmp_path / "file", shards=2, overwrite=True)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        highway.to_parquet(tmp_path / "no" / "such", shards=2)


def test_overwrite_through_a_symbolic_link_replaces_the_directory_it_names(highway, tmp_path):
    highway[:50].to_parquet(tmp_path / "real", shards=2)
    os.symlink(tmp_path / "real", tmp_path / "link")
    highway.to_parquet(tmp_path / "link", shards=3, overwrite=True)
    assert os.path.islink(tmp_path / "link") and sorted(os.listdir(tmp_path)) == ["link", "real"]
    assert_same_frames(highway, dpgp.read_frames(tmp_path / "real"))
    assert shards.read_manifest(tmp_path / "link").n_shards == 3


# --- bad arguments -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("n_shards", "match"),
    [
        (0, "shards must be 1 or more, got 0"),
        (-2, "shards must be 1 or more"),
        (2.5, "whole number"),
        (True, "whole number"),
        ("2", "whole number"),
        (501, "shards=501 is more than the 500 frames"),
    ],
)
def test_bad_numbers_of_shards(highway, tmp_path, n_shards, match):
    with pytest.raises(dpgp.InvalidInputError, match=match):
        highway.to_parquet(tmp_path / "f", shards=n_shards)
    assert os.listdir(tmp_path) == []


def test_other_bad_arguments(highway, tmp_path):
    with pytest.raises(dpgp.InvalidInputError, match="overwrite must be True or False"):
        highway.to_parquet(tmp_path / "f", shards=2, overwrite="yes")
    with pytest.raises(dpgp.InvalidInputError, match="must be a path"):
        highway.to_parquet(42, shards=2)
    with pytest.raises(dpgp.InvalidInputError, match="give out=directory too"):
        dpgp.make_frames(_scene_tracks(), shards=2)
    with pytest.raises(dpgp.InvalidInputError, match="shards must be 1 or more"):
        dpgp.make_frames(_scene_tracks(), out=tmp_path / "m", shards=0)
    complex_ids = dpgp.Frames(np.array([1j, 2j]), np.arange(3), np.zeros((2, 2)), np.ones((2, 2)))
    with pytest.raises(dpgp.InvalidInputError, match="cannot be stored in Parquet"):
        complex_ids.to_parquet(tmp_path / "c")
    mixed = dpgp.Frames(np.array([1, "a"], dtype=object), np.arange(3), np.zeros((2, 2)), np.ones((2, 2)))
    with pytest.raises(dpgp.InvalidInputError, match="frame ids cannot be stored in Parquet"):
        mixed.to_parquet(tmp_path / "m")
    assert os.listdir(tmp_path) == []
    highway.to_parquet(tmp_path / "f", shards=2)
    with pytest.raises(dpgp.InvalidInputError, match=r"shard 2 is out of range: .* holds 2 shards \(0 to 1\)"):
        shards.read_shard(tmp_path / "f", 2)
    with pytest.raises(dpgp.InvalidInputError, match="named by its number"):
        shards.read_shard(tmp_path / "f", "0")
    with pytest.raises(dpgp.InvalidInputError, match="column names apply to a table"):
        dpgp.read_frames(tmp_path / "f", x="x")
    with pytest.raises(FileNotFoundError):
        dpgp.read_frames(tmp_path / "nothing")


# --- damaged directories -------------------------------------------------------------------------


@pytest.fixture
def written(highway, tmp_path):
    m = highway.to_parquet(tmp_path / "f", shards=3)
    return tmp_path / "f", m


def test_a_truncated_shard_is_a_data_format_error_naming_it(written, highway):
    out, m = written
    path = out / m.shards[1].file
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(dpgp.DataFormatError, match=rf"{m.shards[1].file}: shard 1 is not a readable Parquet file"):
        dpgp.read_frames(out)
    with pytest.raises(dpgp.DataFormatError, match=m.shards[1].file):
        shards.read_shard(out, 1)
    # a worker of another shard is not affected
    part, start = shards.read_shard(out, 2)
    assert_same_frames(highway[start:], part)


def test_a_missing_shard_or_manifest_is_a_data_format_error_naming_it(written):
    out, m = written
    os.remove(out / m.shards[0].file)
    with pytest.raises(dpgp.DataFormatError, match=rf"{m.shards[0].file}: shard 0 of 3 is missing"):
        dpgp.read_frames(out)
    os.remove(out / "manifest.json")
    with pytest.raises(dpgp.DataFormatError, match=r"manifest.json is missing"):
        shards.read_shard(out, 1)
    with pytest.raises(dpgp.DataFormatError, match=r"manifest.json is missing"):
        shards.read_manifest(out)


def _edit_manifest(out, edit):
    doc = json.loads((out / "manifest.json").read_text())
    edit(doc)
    (out / "manifest.json").write_text(json.dumps(doc))


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d.update(version=99), "written by a newer dpgp"),
        (lambda d: d.update(format="something else"), "not a manifest of dpgp sharded frames"),
        (lambda d: d["shards"][1].update(frames=[160, 300]), "do not follow on from frame"),
        (lambda d: d.update(n_points=d["n_points"] + 1), "the shards hold 500 frames"),
        (lambda d: d["shards"][0].update(file="../elsewhere.parquet"), "is not a file name in the directory"),
        (lambda d: d.update(ids={"kind": "array", "dtype": "complex128"}), "has the dtype"),
        (lambda d: d.update(summary={"dt": 0.5}), "'summary' is not a framing summary"),
        (lambda d: d["time_order"].update(dt=-1), "not a positive number of seconds"),
    ],
)
def test_a_damaged_manifest_is_a_data_format_error_naming_it(written, edit, match):
    out, _ = written
    _edit_manifest(out, edit)
    with pytest.raises(dpgp.DataFormatError, match=match) as e:
        dpgp.read_frames(out)
    assert "manifest.json" in str(e.value)


def test_unreadable_manifest(written):
    out, _ = written
    (out / "manifest.json").write_text('{"format": "dpgp sharded')
    with pytest.raises(dpgp.DataFormatError, match="manifest.json: not a readable manifest"):
        dpgp.read_frames(out)


def test_a_shard_of_another_write_is_refused(written, highway, tmp_path):
    out, m = written
    other = highway.to_parquet(tmp_path / "other", shards=2)
    shutil.copy(tmp_path / "other" / other.shards[0].file, out / m.shards[0].file)
    with pytest.raises(dpgp.DataFormatError, match=rf"{m.shards[0].file}: its own record .* belongs to another write"):
        shards.read_shard(out, 0)


def test_a_shard_whose_rows_do_not_match_is_refused(written):
    import pyarrow.parquet as pq

    out, m = written
    path = out / m.shards[2].file
    table = pq.read_table(path)
    x = table.column("x").to_numpy().copy()
    x[3] = np.nan
    pq.write_table(table.set_column(table.column_names.index("x"), "x", [x]), path)
    with pytest.raises(dpgp.DataFormatError, match=r"column 'x' holds 1 NaN or infinite value"):
        shards.read_shard(out, 2)
    fn = table.column("frame_number").to_numpy().copy()
    fn[5:] += 1
    pq.write_table(table.set_column(0, "frame_number", [fn]), path)
    with pytest.raises(dpgp.DataFormatError, match="frame_number column does not run through frames"):
        shards.read_shard(out, 2)
    pq.write_table(table.drop(["vy"]), path)
    with pytest.raises(dpgp.DataFormatError, match=r"no column\(s\) \['vy'\]"):
        shards.read_shard(out, 2)


# --- memory --------------------------------------------------------------------------------------


def test_neither_writing_nor_reading_holds_a_second_copy(tmp_path):
    rng = np.random.default_rng(0)
    sizes = rng.integers(5, 20, 40_000)
    n = int(sizes.sum())
    frames = dpgp.Frames(
        np.arange(len(sizes)), np.r_[0, np.cumsum(sizes)], rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    )
    size = frames.xy.nbytes + frames.v.nbytes
    frames[:10].to_parquet(tmp_path / "warm-up")  # first use imports and caches (pandas, pyarrow): not measured
    dpgp.read_frames(tmp_path / "warm-up")
    tracemalloc.start()
    try:
        frames.to_parquet(tmp_path / "f", shards=8)
        _, write_peak = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        back = dpgp.read_frames(tmp_path / "f")
        _, read_peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert_same_frames(frames, back)
    # writing works shard by shard (an eighth of the rows at a time); reading fills the final
    # arrays shard by shard: about one copy, never two (the numpy side; pyarrow's pool is apart)
    assert write_peak < 0.5 * size, (write_peak, size)
    assert read_peak < 1.5 * size, (read_peak, size)


def test_a_fit_on_a_directory_of_one_shard_is_the_fit_on_its_frames(tmp_path):
    """A directory is fitted as its shards (docs/guide/cluster.md): one shard is the fit on the
    frames in memory, number for number; several shards are a chain of their own, the same for
    the same seed."""
    frames = dpgp.datasets.synthetic("highway", 60, seed=3)
    frames.to_parquet(tmp_path / "one", shards=1)
    frames.to_parquet(tmp_path / "three", shards=3)
    # The settings a directory's fit resolves from a sample given, and its engine and sampler.
    given = dict(iterations=3, seed=2, progress=False, likelihood="hsgp", sampler="subcluster", noise_var=0.5)
    a = dpgp.DPGP(**given).fit(frames)
    b = dpgp.DPGP(**given).fit(tmp_path / "one")
    np.testing.assert_array_equal(a.labels_, b.labels_)
    assert a.history_["log_joint"] == b.history_["log_joint"]
    np.testing.assert_array_equal(b.predict(str(tmp_path / "one")), a.predict(frames))
    c, d = (dpgp.DPGP(iterations=3, seed=2, progress=False).fit(tmp_path / "three") for _ in range(2))
    np.testing.assert_array_equal(c.labels_, d.labels_)
    assert len(c.labels_) == len(frames) and c.n_patterns_ >= 1


def test_a_file_path_given_to_fit_says_how_to_read_it(tmp_path):
    (tmp_path / "frames.csv").write_text("frame,x,y,vx,vy\n0,0,0,1,1\n")
    with pytest.raises(dpgp.ShapeError, match="read_frames"):
        dpgp.DPGP(iterations=1, progress=False).fit(tmp_path / "frames.csv")


def test_the_command_line_fits_a_directory_of_shards(tmp_path):
    from dpgp.cli import main

    dpgp.datasets.synthetic("highway", 40, seed=4).to_parquet(tmp_path / "shards", shards=2)
    argv = ["fit", str(tmp_path / "shards"), "-o", str(tmp_path / "model.npz"), "--iterations", "2", "--no-progress"]
    assert main(argv) == 0
    model = dpgp.DPGP.load(tmp_path / "model.npz")
    assert len(model.labels_) == 40
