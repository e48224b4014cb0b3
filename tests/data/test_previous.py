"""Each vehicle's previous step (issue 34): ``Frames.prev_v`` and the heading carried through
stops, ``Frames.prev_heading`` / ``Frames.headings()``.

Oracles: hand-computed values on a small track set (a vehicle that stops and starts, one that
appears mid-sequence, a gap, one that never moves); a plain per-track loop over
``resample_tracks`` on real files; equality across batch boundaries, selections, shards and
model files; old shard directories and model files read without the columns; bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

import dpgp
from dpgp.data import framing
from dpgp.data import shards as shards_mod

from conftest import data_file as real

NAN = float("nan")


def _hand_tracks() -> pd.DataFrame:
    """On-grid samples (dt = 1 s) with the tracks' own velocities: the frames hold them exactly.

    A (1): moves east, slows, stops, leaves north (its t = 4 sample lies outside the ROI used
    below), crawls, turns west. B (2): appears at t = 3, heading south. C (3): a gap from t = 1
    to t = 5 (longer than max_gap), then a crawl and a start. D (4): present, never moving."""
    rows = []
    a_v = [(2, 0), (2, 0), (0.125, 0.25), (0, 0), (0, 1), (0, 0.25), (-1, 0), (-1, 0)]
    for t, (vx, vy) in enumerate(a_v):
        rows.append((1, t, float(t), 100.0 if t == 4 else 0.0, vx, vy))
    for t in (3, 4, 5):
        rows.append((2, t, 5.0, -float(t), 0, -3))
    for t, (vx, vy) in zip((0, 1, 5, 6), [(1, 1), (1, 1), (0.25, 0), (1, 0)]):
        rows.append((3, t, 10.0, 1.0, vx, vy))
    for t in range(4):
        rows.append((4, t, 20.0, 2.0, 0, 0))
    return pd.DataFrame(rows, columns=["track", "t", "x", "y", "vx", "vy"]).astype({"vx": float, "vy": float})


# (track, t) -> (prev_vx, prev_vy, heading), worked out by hand from the definition
_EXPECTED = {
    (1, 0): (NAN, NAN, NAN),  # first appearance
    (1, 1): (2, 0, 0.0),
    (1, 2): (2, 0, 0.0),
    (1, 3): (0.125, 0.25, 0.0),  # 0.28 m/s < 0.5: keeps east
    (1, 4): (0, 0, 0.0),  # stopped: still east
    (1, 5): (0, 1, math.pi / 2),  # moved north at t = 4
    (1, 6): (0, 0.25, math.pi / 2),  # crawling: keeps north
    (1, 7): (-1, 0, math.pi),
    (2, 3): (NAN, NAN, NAN),  # appears mid-sequence
    (2, 4): (0, -3, -math.pi / 2),
    (2, 5): (0, -3, -math.pi / 2),
    (3, 0): (NAN, NAN, NAN),
    (3, 1): (1, 1, math.pi / 4),
    (3, 5): (NAN, NAN, NAN),  # after the gap: no previous step, nothing carried across it
    (3, 6): (0.25, 0, NAN),  # crawled since it reappeared: no heading yet
    (4, 0): (NAN, NAN, NAN),
    (4, 1): (0, 0, NAN),  # never moved
    (4, 2): (0, 0, NAN),
    (4, 3): (0, 0, NAN),
}


def _by_track_time(frames: dpgp.Frames) -> dict:
    df = frames.to_pandas()
    return {(int(r.track), round(float(r.frame))): (r.prev_vx, r.prev_vy, r.prev_heading) for r in df.itertuples()}


def _same(got, want) -> bool:
    return all((np.isnan(g) and np.isnan(w)) or g == pytest.approx(w, abs=1e-12) for g, w in zip(got, want))


def test_hand_built_tracks_give_the_hand_computed_previous_steps():
    frames = dpgp.make_frames(_hand_tracks(), dt=1.0, max_gap=1.5)
    got = _by_track_time(frames)
    assert got.keys() == _EXPECTED.keys()
    for key, want in _EXPECTED.items():
        assert _same(got[key], want), (key, got[key], want)
    assert frames.prev_v.shape == (frames.n_points, 2) and frames.prev_v.dtype == np.float64
    np.testing.assert_array_equal(frames.headings(), frames.prev_heading)
    assert frames.headings() is not frames.prev_heading  # a copy
    assert frames.heading_min_speed == 0.5
    assert frames.headings(min_speed=0.5) is not None


def test_the_roi_crops_frames_not_the_vehicles_past():
    """A leaves the ROI at t = 4 only: its row at t = 5 still has the t = 4 velocity (north)."""
    frames = dpgp.make_frames(_hand_tracks(), roi=(-1, 30, -50, 50), dt=1.0, max_gap=1.5)
    got = _by_track_time(frames)
    assert (1, 4) not in got
    assert _same(got[(1, 5)], (0, 1, math.pi / 2))
    assert _same(got[(1, 6)], (0, 0.25, math.pi / 2))


def test_a_higher_min_speed_carries_further_back():
    frames = dpgp.make_frames(_hand_tracks(), dt=1.0, max_gap=1.5, heading_min_speed=1.5)
    got = _by_track_time(frames)
    # A: the north step (1 m/s) and the west steps are below 1.5 now: east (2 m/s) is carried
    assert _same(got[(1, 5)], (0, 1, 0.0)) and _same(got[(1, 7)], (-1, 0, 0.0))
    assert _same(got[(3, 1)], (1, 1, NAN))  # sqrt(2) < 1.5
    assert _same(got[(2, 4)], (0, -3, -math.pi / 2))
    with pytest.raises(dpgp.InvalidInputError, match="heading_min_speed=0.5"):
        frames.headings(min_speed=0.5)
    with pytest.raises(dpgp.InvalidInputError, match="heading_min_speed"):
        dpgp.make_frames(_hand_tracks(), dt=1.0, heading_min_speed=-1)


# --- an independent per-track loop on real data ------------------------------------------------


def _loop_oracle(tracks: pd.DataFrame, floor: float, **kw) -> dict:
    """(track, grid time) -> (prev_vx, prev_vy, heading): a plain loop over each track's
    resampled grid points (before any ROI), in time order."""
    table = dpgp.resample_tracks(tracks, **{k: v for k, v in kw.items() if k != "roi"})
    dt = kw["dt"]
    out = {}
    for _, g in table.groupby("track", sort=False):
        t, vx, vy = g["t"].to_numpy(), g["vx"].to_numpy(), g["vy"].to_numpy()
        heading = NAN
        for i in range(len(t)):
            if i > 0 and abs(t[i] - t[i - 1] - dt) < 1e-6 * dt:
                pv = (vx[i - 1], vy[i - 1])
                if math.hypot(*pv) >= floor:
                    heading = math.atan2(pv[1], pv[0])
            else:
                pv, heading = (NAN, NAN), NAN
            out[(g["track"].iloc[i], round(t[i] / dt))] = (pv[0], pv[1], heading)
    return out


@pytest.mark.parametrize(
    "name, reader, kw, floor",
    [
        # SUMO: queues at a junction (stop and go), metres
        ("sumo_grid_intersection_fcd.xml.gz", "sumo", {"dt": 0.5, "roi": (200, 280, 200, 280)}, 0.5),
        # NGSIM Peachtree in feet: the floor of 0.5 m/s is 1.64 ft/s
        ("ngsim_peachtree_raw.csv", "ngsim", {"dt": 0.5, "velocity": "diff"}, 0.5 / 0.3048),
    ],
)
def test_real_files_match_a_per_track_loop(name, reader, kw, floor):
    path = real(name)
    tracks = dpgp.read_ngsim(path) if reader == "ngsim" else dpgp.read_tracks(path, preset=reader)
    frames = dpgp.make_frames(tracks, **kw)
    want = _loop_oracle(tracks, floor, **kw)
    df = frames.to_pandas()
    dt = kw["dt"]
    labels = np.unique(tracks["track"].to_numpy())  # make_frames' track codes: sorted ids, or the ids
    n_carried = 0
    for r in df.itertuples():
        label = labels[r.track] if labels.dtype.kind not in "iu" else r.track
        w = want[(label, round(r.frame / dt))]
        assert _same((r.prev_vx, r.prev_vy, r.prev_heading), w), (label, r.frame, w)
        n_carried += bool(np.isfinite(w[2]) and math.hypot(w[0], w[1]) < floor)
    assert n_carried > 0, "the file has stopped vehicles whose heading is carried"
    assert np.isnan(frames.prev_v[:, 0]).any() and np.isfinite(frames.prev_v[:, 0]).any()


def test_batch_boundaries_do_not_change_anything(monkeypatch):
    tracks = dpgp.read_tracks(real("sumo_grid_intersection_fcd.xml.gz"), preset="sumo")
    whole = dpgp.make_frames(tracks, dt=0.5, roi=(200, 280, 200, 280))
    monkeypatch.setattr(framing, "_BATCH", 97)  # batches cut between segments of one track
    cut = dpgp.make_frames(tracks, dt=0.5, roi=(200, 280, 200, 280))
    np.testing.assert_array_equal(cut.prev_v, whole.prev_v)
    np.testing.assert_array_equal(cut.prev_heading, whole.prev_heading)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_stop_and_go_with_gaps_in_small_batches_matches_the_loop(monkeypatch, seed):
    """Uneven sampling, gaps, stops and a ROI, framed in batches of 61 grid points and rows."""
    rng = np.random.default_rng(seed)
    parts = []
    for i in range(30):
        n = int(rng.integers(2, 60))
        steps = rng.uniform(0.05, 0.3, n)
        steps[rng.random(n) < 0.05] = 1.5  # gaps longer than max_gap
        t = rng.uniform(0, 20) + np.cumsum(steps)
        moving = rng.random(n) < 0.6  # stop and go
        vx = np.where(moving, rng.normal(0, 3, n), rng.normal(0, 0.1, n))
        vy = np.where(moving, rng.normal(0, 3, n), rng.normal(0, 0.1, n))
        x, y = np.cumsum(vx * steps), np.cumsum(vy * steps)
        parts.append(pd.DataFrame({"track": 7 * i + 3, "t": t, "x": x, "y": y, "vx": vx, "vy": vy}))
    tracks = pd.concat(parts, ignore_index=True)
    kw = {"dt": 0.2, "max_gap": 0.7, "roi": (-3, 3, -3, 3)}
    monkeypatch.setattr(framing, "_BATCH", 61)
    frames = dpgp.make_frames(tracks, **kw)
    want = _loop_oracle(tracks, 0.5, **kw)
    for r in frames.to_pandas().itertuples():
        w = want[(r.track, round(r.frame / kw["dt"]))]
        assert _same((r.prev_vx, r.prev_vy, r.prev_heading), w), (r.track, r.frame, w)


# --- selections, shards, model files -------------------------------------------------------------


@pytest.fixture(scope="module")
def hand() -> dpgp.Frames:
    return dpgp.make_frames(_hand_tracks(), dt=1.0, max_gap=1.5)


def test_selections_carry_each_rows_own_values(hand):
    for sel in (slice(3, 7), np.array([6, 2, 5]), np.arange(len(hand)) % 2 == 0):
        part = hand[sel]
        rows = np.concatenate([np.arange(hand.offsets[i], hand.offsets[i + 1]) for i in np.arange(len(hand))[sel]])
        np.testing.assert_array_equal(part.prev_v, hand.prev_v[rows])
        np.testing.assert_array_equal(part.headings(), hand.prev_heading[rows])
        assert part.heading_min_speed == hand.heading_min_speed
    f = hand[5]
    a, b = hand.offsets[5], hand.offsets[6]
    np.testing.assert_array_equal(f.prev_v, hand.prev_v[a:b])
    np.testing.assert_array_equal(f.prev_heading, hand.prev_heading[a:b])
    cropped = hand.crop((-1, 30, -50, 50))
    assert cropped.n_points == hand.n_points - 1
    keep = hand.xy[:, 1] <= 50
    np.testing.assert_array_equal(cropped.prev_heading, hand.prev_heading[keep])


def test_shards_store_and_read_the_columns(tmp_path, hand):
    m = hand.to_parquet(tmp_path / "f", shards=3)
    assert m.heading_min_speed == 0.5
    back = dpgp.read_frames(tmp_path / "f")
    np.testing.assert_array_equal(back.prev_v, hand.prev_v)
    np.testing.assert_array_equal(back.prev_heading, hand.prev_heading)
    for part, start in shards_mod.iter_shards(tmp_path / "f"):
        # a shard's first frame keeps the heading carried from frames in the shard before
        rows = slice(hand.offsets[start], hand.offsets[start + len(part)])
        np.testing.assert_array_equal(part.prev_v, hand.prev_v[rows])
        np.testing.assert_array_equal(part.headings(), hand.prev_heading[rows])


def test_old_shard_directories_read_without_the_columns(tmp_path, hand):
    hand.to_parquet(tmp_path / "f", shards=2)
    doc = json.loads((tmp_path / "f" / "manifest.json").read_text())
    del doc["previous"]  # as written before issue 34 (its shards have no prev_* columns either)
    (tmp_path / "f" / "manifest.json").write_text(json.dumps(doc))
    back = dpgp.read_frames(tmp_path / "f")
    assert back.prev_v is None and back.prev_heading is None and back.heading_min_speed is None
    assert back.tracks is not None
    with pytest.raises(dpgp.InvalidInputError, match="no previous velocities"):
        back.headings()
    part, _ = shards_mod.read_shard(tmp_path / "f", 1)
    assert part.prev_v is None


def test_a_damaged_previous_column_is_named(tmp_path, hand):
    import pyarrow.parquet as pq

    hand.to_parquet(tmp_path / "f", shards=1)
    file = tmp_path / "f" / "shard-00000.parquet"
    table = pq.read_table(file)
    col = table.column("prev_vx").to_numpy().copy()
    col[1] = np.inf
    table = table.set_column(table.column_names.index("prev_vx"), "prev_vx", [col])
    pq.write_table(table, file)
    with pytest.raises(dpgp.DataFormatError, match="previous velocities hold inf"):
        dpgp.read_frames(tmp_path / "f")
    doc = json.loads((tmp_path / "f" / "manifest.json").read_text())
    doc["previous"] = {"heading_min_speed": -1}
    (tmp_path / "f" / "manifest.json").write_text(json.dumps(doc))
    with pytest.raises(dpgp.DataFormatError, match="heading_min_speed"):
        shards_mod.read_manifest(tmp_path / "f")


def _stop_and_go() -> pd.DataFrame:
    """Forty vehicles on two opposite lanes that queue (stop for several seconds) and go."""
    rng = np.random.default_rng(2)
    parts = []
    for i in range(40):
        n = int(rng.integers(20, 120))
        t = rng.uniform(0, 30) + np.arange(n) * 0.1
        speed = np.where((np.arange(n) > n // 3) & (np.arange(n) < n // 3 + 40), 0.0, rng.uniform(3, 10))
        sign = 1 if i % 2 else -1
        x = sign * np.cumsum(speed) * 0.1
        parts.append(pd.DataFrame({"id": i, "time": t, "x": x, "y": sign * 2.0 + rng.normal(0, 0.01, n)}))
    return pd.concat(parts, ignore_index=True)


def test_streamed_framing_equals_in_memory_across_windows(tmp_path):
    """Queues longer than a window: the heading carried from window to window."""
    _stop_and_go().to_csv(tmp_path / "q.csv", index=False)
    read_kw = {"id": "id", "t": "time"}
    tracks = dpgp.read_tracks(tmp_path / "q.csv", **read_kw)
    kw = {"dt": 0.2, "velocity": "diff", "roi": (-60, 60, -5, 5)}
    want = dpgp.make_frames(tracks, **kw)
    shards_mod.frame_to_shards(tmp_path / "q.csv", tmp_path / "got", 3, window=0.9, chunk_rows=500, **read_kw, **kw)
    got = dpgp.read_frames(tmp_path / "got")
    np.testing.assert_array_equal(got.prev_v, want.prev_v)
    np.testing.assert_array_equal(got.prev_heading, want.prev_heading)
    slow = np.hypot(*want.prev_v.T) < 0.5
    assert (slow & np.isfinite(want.prev_heading)).sum() > 100  # headings carried through queues
    h = want.prev_heading[np.isfinite(want.prev_heading)]
    assert (np.cos(h) > 0.99).any() and (np.cos(h) < -0.99).any()  # both lanes' directions


def test_model_files_store_the_columns_and_read_old_ones_without(tmp_path):
    tracks = dpgp.read_tracks(_stop_and_go(), id="id", t="time")
    frames = dpgp.make_frames(tracks, dt=0.5, velocity="diff", roi=(-60, 60, -5, 5))[:40]
    bare = dpgp.Frames(frames.ids, frames.offsets, frames.xy, frames.v, tracks=frames.tracks)
    bare.summary = frames.summary
    kw = dict(iterations=2, seed=1, progress=False, noise_var="global", length_scale_prior=(8.0, 1.5))
    model = dpgp.DPGP(**kw).fit(frames)
    # the column is data only: the fit is the same without it
    np.testing.assert_array_equal(dpgp.DPGP(**kw).fit(bare).labels_, model.labels_)
    model.save(tmp_path / "m.npz")
    back = dpgp.DPGP.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(back.frames_.prev_v, frames.prev_v)
    np.testing.assert_array_equal(back.frames_.headings(), frames.prev_heading)
    assert back.frames_.heading_min_speed == 0.5
    with np.load(tmp_path / "m.npz", allow_pickle=False) as npz:  # no pickle anywhere
        assert {"frame_prev_v", "frame_prev_heading"} <= set(npz.files)
        arrays = {k: npz[k] for k in npz.files if not k.startswith("frame_prev")}
    np.savez(tmp_path / "old.npz", **arrays)  # as written before issue 34
    old = dpgp.DPGP.load(tmp_path / "old.npz")
    assert old.frames_.prev_v is None and old.frames_.prev_heading is None
    np.testing.assert_array_equal(old.labels_, model.labels_)
    damaged = dict(arrays, frame_prev_v=frames.prev_v.copy())
    damaged["frame_prev_v"][0] = [np.inf, 0.0]
    damaged["frame_prev_heading"] = frames.prev_heading
    np.savez(tmp_path / "bad.npz", **damaged)
    with pytest.raises(dpgp.ModelFileError, match="previous velocity"):
        dpgp.DPGP.load(tmp_path / "bad.npz")
    np.savez(tmp_path / "half.npz", **dict(arrays, frame_prev_v=frames.prev_v))  # no heading member
    with pytest.raises(dpgp.ModelFileError, match="come together"):
        dpgp.DPGP.load(tmp_path / "half.npz")


# --- bad input -----------------------------------------------------------------------------------


def _rows(**kw):
    base = dict(frame=[0, 0, 1], x=[0.0, 1, 2], y=[0.0, 0, 0], vx=[1.0, 1, 1], vy=[0.0, 0, 0])
    return dpgp.Frames.from_arrays(**{**base, **kw})


def test_from_arrays_takes_previous_velocities():
    f = _rows(prev_vx=[NAN, 0.1, 2.0], prev_vy=[NAN, 0.0, 2.0])
    np.testing.assert_array_equal(f.prev_v, [[NAN, NAN], [0.1, 0.0], [2.0, 2.0]])
    # rows alone hold no history: a slow previous velocity gives no heading
    np.testing.assert_allclose(f.headings(), [NAN, NAN, math.pi / 4])
    g = _rows(prev_vx=[NAN, 0.1, 2.0], prev_vy=[NAN, 0.0, 2.0], prev_heading=[NAN, 3.0, 0.7])
    np.testing.assert_array_equal(g.headings(), [NAN, 3.0, 0.7])
    assert _rows().prev_v is None
    with pytest.raises(dpgp.InvalidInputError, match="no previous velocities"):
        _rows().headings()
    assert dpgp.datasets.synthetic("intersection", n_frames=5, seed=1).prev_v is None  # no tracks


@pytest.mark.parametrize(
    "kw, error, match",
    [
        (
            dict(prev_vx=[NAN, 1.0, 2.0], prev_vy=[0.0, 1.0, 2.0]),
            dpgp.InvalidInputError,
            r"frame 0 \(id 0\), vehicle 0",
        ),
        (
            dict(prev_vx=[0.0, 1.0, 2.0], prev_vy=[0.0, 1.0, np.inf]),
            dpgp.InvalidInputError,
            r"frame 1 \(id 1\), vehicle 0",
        ),
        (
            dict(prev_vx=[0.0, 1.0, 2.0], prev_vy=[0.0, 1.0, 1.0], prev_heading=[0, 4, 0]),
            dpgp.InvalidInputError,
            "vehicle 1",
        ),
        (
            dict(prev_vx=[NAN, 1.0, 2.0], prev_vy=[NAN, 1.0, 1.0], prev_heading=[0, 0, 0]),
            dpgp.InvalidInputError,
            "always NaN",
        ),
        (dict(prev_vx=[0.0, 1.0, 2.0]), dpgp.InvalidInputError, "together"),
        (dict(prev_vx=[0.0, 1.0], prev_vy=[0.0, 1.0]), dpgp.ShapeError, "one value per row"),
        (dict(prev_vx=[0.0, 1, 2], prev_vy=[0.0, 1, 2], heading_min_speed="fast"), dpgp.InvalidInputError, "m/s"),
    ],
)
def test_bad_previous_columns_are_refused(kw, error, match):
    with pytest.raises(error, match=match):
        _rows(**kw)


def test_frames_refuses_a_heading_without_velocities():
    with pytest.raises(dpgp.InvalidInputError, match="needs prev_v"):
        dpgp.Frames(np.array([0]), np.array([0, 1]), np.zeros((1, 2)), np.zeros((1, 2)), prev_heading=np.zeros(1))
    with pytest.raises(dpgp.ShapeError, match=r"\(n, 2\)"):
        dpgp.Frames(np.array([0]), np.array([0, 1]), np.zeros((1, 2)), np.zeros((1, 2)), prev_v=np.zeros((2, 2)))


def test_generation_takes_headings_from_the_speed_the_frames_were_made_with_in_their_units():
    """Frames in feet: the framing's floor is 0.5 m/s = 1.64 ft/s, and generation (which keeps
    headings as rollouts run) must use the same floor in the same units, not 0.5 ft/s."""
    from types import SimpleNamespace

    from dpgp.generate.headings import heading_speed

    # one vehicle east at 1.0 ft/s (0.30 m/s: no heading), then north at 2.0 ft/s (0.61 m/s)
    v = [(1.0, 0.0)] * 3 + [(0.0, 2.0)] * 3
    rows = [(1, t, float(t), 0.0, vx, vy) for t, (vx, vy) in enumerate(v)]
    tracks = pd.DataFrame(rows, columns=["track", "t", "x", "y", "vx", "vy"])
    tracks.attrs["dpgp"] = {"units": "ft"}
    frames = dpgp.make_frames(tracks, dt=1.0)
    assert frames.summary.length_unit == "ft"
    speed = heading_speed(SimpleNamespace(frames=frames))
    assert speed == pytest.approx(0.5 / 0.3048)
    # the framing's own headings: none from the slow steps, north once the fast ones start
    got = _by_track_time(frames)
    assert all(math.isnan(got[(1, t)][2]) for t in (1, 2, 3))
    assert got[(1, 4)][2] == pytest.approx(math.pi / 2)
    # the floor generation uses gives the same verdict on each step's velocity
    fast = np.hypot(frames.v[:, 0], frames.v[:, 1]) >= speed
    np.testing.assert_array_equal(fast, [False] * 3 + [True] * 3)
    metres = tracks.copy()
    metres.attrs["dpgp"] = {"units": "m"}
    assert heading_speed(SimpleNamespace(frames=dpgp.make_frames(metres, dt=1.0))) == 0.5
