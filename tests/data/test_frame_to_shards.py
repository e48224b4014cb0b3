"""Framing a track file straight into shards, in time windows (issue 33, dpgp.data.shards.
frame_to_shards): the frames, shards and manifest equal make_frames(read_tracks(file)) written
with to_parquet, on real NGSIM and SUMO files and on a synthetic file in shuffled row order,
with windows small enough that many window edges are crossed; bad arguments; nothing left
behind by a failure."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest

import dpgp
from dpgp.data import shards

from conftest import data_file as real


def assert_same_frames(a: dpgp.Frames, b: dpgp.Frames) -> None:
    assert len(a) == len(b) and a.n_points == b.n_points
    assert a.ids.dtype == b.ids.dtype and list(a.ids) == list(b.ids)
    assert np.array_equal(a.offsets, b.offsets)
    assert np.array_equal(a.xy, b.xy) and np.array_equal(a.v, b.v)
    assert a.tracks is not None and b.tracks is not None and np.array_equal(a.tracks, b.tracks)
    assert a.summary == b.summary
    # previous steps (issue 34): the heading carried through stops crosses windows and shards
    assert a.heading_min_speed == b.heading_min_speed is not None
    assert np.array_equal(a.prev_v, b.prev_v, equal_nan=True)
    assert np.array_equal(a.prev_heading, b.prev_heading, equal_nan=True)


def _manifest(directory) -> dict:
    doc = json.loads((directory / "manifest.json").read_text())
    doc.pop("written_by")
    return doc


def check(tmp_path, source, tracks, read_kw, frame_kw, shards_n=3, window=5.0, chunk_rows=700):
    """frame_to_shards equals make_frames(tracks).to_parquet: frames, shard cuts and manifest."""
    want = dpgp.make_frames(tracks, **frame_kw, out=tmp_path / "want", shards=shards_n)
    m = shards.frame_to_shards(
        source, tmp_path / "got", shards_n, window=window, chunk_rows=chunk_rows, **read_kw, **frame_kw
    )
    assert m.n_frames == len(want) and m.n_shards == shards_n
    assert_same_frames(dpgp.read_frames(tmp_path / "got"), want)
    assert _manifest(tmp_path / "got") == _manifest(tmp_path / "want")
    for i in range(shards_n):  # each shard alone, as a worker reads it
        part, start = shards.read_shard(tmp_path / "got", i)
        rows = slice(want.offsets[start], want.offsets[start + len(part)])
        assert np.array_equal(part.xy, want.xy[rows]) and np.array_equal(part.tracks, want.tracks[rows])
        assert np.array_equal(part.prev_v, want.prev_v[rows], equal_nan=True)
        assert np.array_equal(part.headings(), want.prev_heading[rows], equal_nan=True)
    assert sorted(os.listdir(tmp_path)) == ["got", "want"]  # no scratch left beside it
    assert not any(name.startswith(".") for name in os.listdir(tmp_path / "got"))
    return want


# --- real data ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def peachtree():
    path = real("ngsim_peachtree_raw.csv")
    return path, dpgp.read_ngsim(path)


def test_ngsim_peachtree_as_the_benchmark_frames_it(tmp_path, peachtree):
    path, tracks = peachtree
    # 10,000 rows in chunks of 700, windows of 5 s of a 100 s recording: 20 windows
    want = check(tmp_path, path, tracks, {"preset": "ngsim"}, {"roi": (-20, 30, 0, 80), "dt": 0.5})
    assert want.summary.length_unit == "ft" and want.summary.object_size is not None


def test_ngsim_smoothed_converted_and_with_a_given_max_gap(tmp_path, peachtree):
    path, tracks = peachtree
    frame_kw = {"dt": 0.2, "smoothing": (5, 2), "units": "ft->m", "max_gap": 0.35}
    check(tmp_path, path, tracks, {"preset": "ngsim"}, frame_kw, shards_n=4, window=2.0, chunk_rows=1500)


def test_ngsim_duplicates_trips_and_clashes_as_read_ngsim(tmp_path, peachtree):
    """Repeated rows are dropped, a trip's long jump in Frame_ID splits it, rows in shuffled
    order; a clashing row (same trip and frame, other values) is refused as read_ngsim does."""
    path, _ = peachtree
    lines = open(path, encoding="utf-8-sig").read().splitlines()
    head, rows = lines[0], lines[1:3001]
    rng = np.random.default_rng(5)
    rows = rows + [rows[i] for i in rng.integers(0, len(rows), 40)]  # exact duplicates
    jumped = [r.split(",", 2) for r in rows if r.startswith("352,")]  # one vehicle's trip, moved later
    rows += [f"{v},{int(f) + 600},{rest}" for v, f, rest in jumped]
    rows = [rows[i] for i in rng.permutation(len(rows))]
    (tmp_path / "ngsim.csv").write_text("\n".join([head, *rows]) + "\n", encoding="utf-8")
    tracks = dpgp.read_ngsim(tmp_path / "ngsim.csv")
    report = tracks.attrs["dpgp"]["report"]
    assert report["exact_duplicate_rows_dropped"] > 0 and report["trips_split_at_time_jumps"] > 0
    (tmp_path / "run").mkdir()
    check(tmp_path / "run", tmp_path / "ngsim.csv", tracks, {"preset": "ngsim"}, {"dt": 0.5}, window=4.0)

    clash = rows[0].split(",")
    clash[-2] = str(float(clash[-2]) + 1.0)  # Time_Headway changed; the trip and frame kept
    (tmp_path / "clash.csv").write_text("\n".join([head, *rows, ",".join(clash)]) + "\n", encoding="utf-8")
    with pytest.raises(dpgp.DataFormatError, match="same frame"):
        dpgp.read_ngsim(tmp_path / "clash.csv")
    with pytest.raises(dpgp.DataFormatError, match="same frame"):
        shards.frame_to_shards(tmp_path / "clash.csv", tmp_path / "out", preset="ngsim", window=4.0)
    assert not (tmp_path / "out").exists()


def test_sumo_fcd_xml_streams(tmp_path):
    path = real("sumo_grid_intersection_fcd.xml.gz")
    tracks = dpgp.read_tracks(path, preset="sumo")
    check(tmp_path, path, tracks, {"preset": "sumo"}, {"dt": 0.5}, window=30.0, chunk_rows=5000)


def test_sumo_differenced_and_smoothed_in_a_roi(tmp_path):
    path = real("sumo_grid_intersection_fcd.xml.gz")
    tracks = dpgp.read_tracks(path)  # .xml.gz: SUMO without saying so
    frame_kw = {"dt": 0.3, "velocity": "diff", "smoothing": (7, 2), "roi": (200, 280, 200, 280)}
    check(tmp_path, path, tracks, {}, frame_kw, shards_n=5, window=7.0, chunk_rows=3000)


def test_eth_ucy_headerless_text(tmp_path):
    path = real("eth_ucy_biwi_eth.txt")
    tracks = dpgp.read_tracks(path, preset="eth_ucy")
    want = check(tmp_path, path, tracks, {"preset": "eth_ucy"}, {"dt": 0.4}, shards_n=2, window=30.0, chunk_rows=1000)
    assert want.summary.object_type == "pedestrian"


# --- synthetic, shuffled -------------------------------------------------------------------


@pytest.fixture(scope="module")
def shuffled(tmp_path_factory):
    """Tracks with gaps, uneven sampling, single samples and sizes, in shuffled row order."""
    rng = np.random.default_rng(3)
    parts = []
    for i in range(60):
        n = int(rng.integers(1, 80))
        steps = rng.uniform(0.05, 0.3, n)
        if n > 10:
            steps[n // 2] = 2.0  # longer than max_gap: a gap
        t = rng.uniform(0, 100) + np.cumsum(steps)
        parts.append(
            pd.DataFrame(
                {
                    "vehicle": f"v{i:03d}",
                    "time": t,
                    "x": np.cumsum(rng.normal(1, 0.3, n)),
                    "y": rng.normal(0, 1, n) + t,
                    "length": rng.uniform(3, 6),
                    "width": rng.uniform(1.5, 2.5),
                    "rec": "b" if i < 30 else "a",
                }
            )
        )
    df = pd.concat(parts).sample(frac=1, random_state=1)
    root = tmp_path_factory.mktemp("tracks")
    df.to_csv(root / "tracks.csv", index=False)
    df.to_parquet(root / "tracks.parquet", row_group_size=500)
    return root


@pytest.mark.parametrize("file", ["tracks.csv", "tracks.parquet"])
def test_shuffled_file_equals_reading_it_whole(tmp_path, shuffled, file):
    read_kw = {"id": "vehicle", "t": "time", "sort": True}
    tracks = dpgp.read_tracks(shuffled / file, **read_kw)
    want = check(tmp_path, shuffled / file, tracks, read_kw, {"dt": 0.25}, shards_n=4, window=4.0, chunk_rows=300)
    assert want.summary.n_gaps > 0 and want.summary.object_size is not None


def test_shuffled_file_smoothed_with_tiny_windows(tmp_path, shuffled):
    read_kw = {"id": "vehicle", "t": "time", "sort": True}
    tracks = dpgp.read_tracks(shuffled / "tracks.csv", **read_kw)
    # windows of 0.7 s: the margin spans many of them
    check(tmp_path, shuffled / "tracks.csv", tracks, read_kw, {"dt": 0.25, "smoothing": (5, 3)}, window=0.7)


def test_a_track_named_by_two_columns(tmp_path, shuffled):
    df = pd.read_csv(shuffled / "tracks.csv")
    number = df.pop("vehicle").str[1:].astype(int)
    df["group"], df["member"] = number // 7, number % 7
    df.to_csv(tmp_path / "two.csv", index=False)
    read_kw = {"id": ["group", "member"], "t": "time", "sort": True}
    tracks = dpgp.read_tracks(tmp_path / "two.csv", **read_kw)
    (tmp_path / "run").mkdir()
    check(tmp_path / "run", tmp_path / "two.csv", tracks, read_kw, {"dt": 0.3, "smoothing": (3, 1)}, window=1.5)


def test_scenes_are_framed_scene_by_scene(tmp_path, shuffled):
    read_kw = {"id": "vehicle", "t": "time", "scene": "rec", "sort": True}
    tracks = dpgp.read_tracks(shuffled / "tracks.csv", **read_kw)
    want = check(tmp_path, shuffled / "tracks.csv", tracks, read_kw, {"dt": 0.25}, shards_n=4, window=4.0)
    assert want.summary.n_scenes == 2 and isinstance(want.ids[0], tuple)


# --- errors ------------------------------------------------------------------------------------


def test_unsorted_rows_are_refused_without_sort_as_read_tracks_does(tmp_path, shuffled):
    with pytest.raises(dpgp.InvalidInputError):
        dpgp.read_tracks(shuffled / "tracks.csv", id="vehicle", t="time")
    with pytest.raises(dpgp.InvalidInputError, match="goes backwards inside track.*sort=True"):
        shards.frame_to_shards(shuffled / "tracks.csv", tmp_path / "out", id="vehicle", t="time", window=4.0)
    assert os.listdir(tmp_path) == []  # a failure leaves nothing behind


def test_repeated_times_are_refused(tmp_path):
    path = tmp_path / "rep.csv"
    pd.DataFrame({"id": [1, 1, 2, 1], "t": [0.0, 0.1, 0.0, 0.1], "x": [0.0, 1, 2, 3], "y": 0.0}).to_csv(path)
    with pytest.raises(dpgp.InvalidInputError, match="time repeats inside track 1"):
        shards.frame_to_shards(path, tmp_path / "out", sort=True, dt=0.1)
    assert os.listdir(tmp_path) == ["rep.csv"]


@pytest.mark.parametrize(
    ("kw", "error", "match"),
    [
        ({"window": 0}, dpgp.InvalidInputError, "window must be a positive number"),
        ({"window": "1h"}, dpgp.InvalidInputError, "window must be a positive number"),
        ({"chunk_rows": 0}, dpgp.InvalidInputError, "chunk_rows must be a whole number"),
        ({"chunk_rows": 1.5}, dpgp.InvalidInputError, "chunk_rows must be a whole number"),
        ({"dt": -1}, dpgp.InvalidInputError, "dt must be a positive number"),
        ({"velocity": "fast"}, dpgp.InvalidInputError, "velocity must be"),
        ({"smoothing": (4, 2)}, dpgp.InvalidInputError, "odd window"),
        ({"units": "furlongs"}, dpgp.InvalidInputError, "units must be"),
        ({"shards": 0}, dpgp.InvalidInputError, "shards must be 1 or more"),
        ({"preset": "nope"}, dpgp.InvalidInputError, "unknown preset"),
        ({"preset": "ngsim", "id": "Vehicle_ID"}, dpgp.InvalidInputError, "preset='ngsim' reads NGSIM's own"),
        ({"sort": "yes"}, dpgp.InvalidInputError, "sort must be True or False"),
        ({"velocity": "columns"}, dpgp.DataFormatError, "velocity='columns' needs vx and vy"),
        ({"t": "when"}, dpgp.DataFormatError, "column 'when'"),
        ({"shards": 10_000}, dpgp.InvalidInputError, "more than the .* frames"),
        ({"roi": (1e6, 2e6, 0, 1)}, dpgp.InvalidInputError, "no vehicle enters the ROI"),
        ({"dt": 1e4}, dpgp.InvalidInputError, "no track reaches a grid time"),
    ],
)
def test_bad_arguments(tmp_path, shuffled, kw, error, match):
    kw = {"id": "vehicle", "t": "time", "sort": True, "window": 10.0, **kw}
    with pytest.raises(error, match=match):
        shards.frame_to_shards(shuffled / "tracks.csv", tmp_path / "out", **kw)
    assert os.listdir(tmp_path) == []


def test_what_is_not_a_track_file(tmp_path, shuffled):
    with pytest.raises(dpgp.InvalidInputError, match="use dpgp.make_frames"):
        shards.frame_to_shards(pd.read_csv(shuffled / "tracks.csv"), tmp_path / "out")
    with pytest.raises(FileNotFoundError):
        shards.frame_to_shards(tmp_path / "missing.csv", tmp_path / "out")
    with pytest.raises(dpgp.DataFormatError, match="not an NGSIM trajectory file"):
        shards.frame_to_shards(shuffled / "tracks.csv", tmp_path / "out", preset="ngsim")
    assert os.listdir(tmp_path) == []


def test_the_target_is_checked_before_any_work(tmp_path, shuffled):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError):
        shards.frame_to_shards(shuffled / "tracks.csv", tmp_path / "out", id="vehicle", t="time", sort=True)
    assert os.listdir(tmp_path / "out") == ["notes.txt"]


def test_overwrite_replaces_sharded_frames(tmp_path, shuffled):
    kw = {"id": "vehicle", "t": "time", "sort": True, "window": 10.0}
    shards.frame_to_shards(shuffled / "tracks.csv", tmp_path / "out", 2, **kw)
    with pytest.raises(FileExistsError):
        shards.frame_to_shards(shuffled / "tracks.csv", tmp_path / "out", 3, **kw)
    m = shards.frame_to_shards(shuffled / "tracks.csv", tmp_path / "out", 3, overwrite=True, **kw)
    assert shards.read_manifest(tmp_path / "out").n_shards == m.n_shards == 3


def test_an_interrupted_write_leaves_nothing(tmp_path, shuffled, monkeypatch):
    from dpgp.data import _shardfile

    def fail(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(_shardfile, "_write_shard", fail)
    with pytest.raises(OSError, match="disk full"):
        shards.frame_to_shards(shuffled / "tracks.csv", tmp_path / "out", id="vehicle", t="time", sort=True)
    assert os.listdir(tmp_path) == []


# --- memory --------------------------------------------------------------------------------


def test_memory_follows_the_window_not_the_file(tmp_path):
    """A 400,000-row file: the streaming path's peak of memory allocated through Python (numpy,
    pandas; not pyarrow's own pool), in windows of 2 s of a 100 s recording and chunks of 20,000
    rows, stays well under the in-memory path's."""
    script = textwrap.dedent(
        """
        import sys, tracemalloc
        import numpy as np, pandas as pd
        import dpgp
        from dpgp.data import shards
        path, out, how = sys.argv[1:4]
        if how == "write":
            rng = np.random.default_rng(0)
            n_tracks, n = 2000, 200
            t0 = rng.uniform(0, 90, n_tracks)[:, None] + 0.05 * np.arange(n)[None, :]
            pd.DataFrame({"id": np.repeat(np.arange(n_tracks), n), "t": t0.ravel(),
                          "x": rng.normal(size=n_tracks * n).cumsum(), "y": t0.ravel() * 10}).to_csv(path, index=False)
            sys.exit()
        tracemalloc.start()
        if how == "stream":
            shards.frame_to_shards(path, out, 4, window=2.0, chunk_rows=20_000)
        else:
            dpgp.make_frames(dpgp.read_tracks(path), out=out, shards=4)
        print(tracemalloc.get_traced_memory()[1])
        """
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    path = str(tmp_path / "big.csv")
    subprocess.run([sys.executable, "-c", script, path, "", "write"], check=True, env=env)
    peak = {}
    for how in ("stream", "whole"):
        run = subprocess.run(
            [sys.executable, "-c", script, path, str(tmp_path / how), how],
            check=True, env=env, capture_output=True, text=True,
        )  # fmt: skip
        peak[how] = int(run.stdout.split()[-1])
    assert_same_frames(dpgp.read_frames(tmp_path / "stream"), dpgp.read_frames(tmp_path / "whole"))
    assert peak["stream"] < 0.5 * peak["whole"], peak
