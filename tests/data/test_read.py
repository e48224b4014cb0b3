"""dpgp.read(path, format="auto"): every supported format recognised by its own columns, an
unrecognised file refused with the formats and the columns it has; Frames.crop against a plain
loop over the rows; the CLI reads through it."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import dpgp
from dpgp import cli
from dpgp.data.read import FORMATS, detect_format

from conftest import DATA

INTERACTION = ["track_id", "frame_id", "timestamp_ms", "agent_type", "x", "y", "vx", "vy", "psi_rad", "length", "width"]


def _interaction(path, n_tracks=8, steps=30):
    rng = np.random.default_rng(0)
    rows = []
    for tid in range(1, n_tracks + 1):
        t0 = int(rng.integers(0, 20)) * 100
        (x0, y0), (vx, vy) = rng.uniform(-20, 20, 2), rng.uniform(-3, 3, 2)
        for i in range(steps):
            t = t0 + 100 * i
            rows.append(
                (tid, t // 100 + 1, t, "car", x0 + vx * i / 10, y0 + vy * i / 10, vx, vy, np.arctan2(vy, vx), 4.5, 1.8)
            )
    pd.DataFrame(rows, columns=INTERACTION).to_csv(path, index=False)
    return path


def test_interaction_recorded_tracks_are_recognised_and_read(tmp_path):
    path = _interaction(tmp_path / "vehicle_tracks_000.csv")
    assert detect_format(path) == "interaction"
    frames = dpgp.read(path)
    direct = dpgp.make_frames(dpgp.read_tracks(path, preset="interaction"), dt=0.5)
    assert len(frames) > 0 and frames.n_points == direct.n_points
    np.testing.assert_array_equal(frames.xy, direct.xy)
    np.testing.assert_array_equal(frames.v, direct.v)
    assert dpgp.read(path, dt=0.2).n_points > frames.n_points  # the time step is the caller's


def test_the_cli_fits_an_interaction_file_without_format(tmp_path, capsys):
    path = _interaction(tmp_path / "tracks.csv")
    out = tmp_path / "m.npz"
    assert cli.main(["fit", str(path), "-o", str(out), "--iterations", "2", "--no-progress"]) == 0
    assert dpgp.DPGP.load(out).n_iter_ == 2


@pytest.mark.parametrize(
    "name, fmt",
    [
        ("eth_ucy_biwi_eth.txt", "eth_ucy"),
        ("ngsim_peachtree_raw.csv", "ngsim"),
        ("ngsim_us101_frames.tsv", "frames"),
        ("sumo_grid_intersection_fcd.xml.gz", "sumo"),
        ("sumo_left_turn_frames.csv", "frames"),
    ],
)
def test_the_shared_files_are_recognised(name, fmt):
    path = DATA / name
    if not path.exists():
        pytest.skip(f"{path} is absent")
    assert detect_format(path) == fmt


@pytest.mark.parametrize(
    "columns, fmt",
    [
        (["Vehicle_ID", "Frame_ID", "Local_X", "Local_Y", "v_Vel"], "ngsim"),
        (["timestep_time", "vehicle_id", "vehicle_x", "vehicle_y"], "sumo"),
        (["id", "frame", "x", "y", "xVelocity", "yVelocity", "width"], "highd"),
        (["recordingId", "trackId", "frame", "xCenter", "yCenter", "xVelocity", "yVelocity"], "ind"),
        (["frame", "x", "y", "vx", "vy"], "frames"),
        (["track_id", "t", "x", "y"], "tracks"),
        (["vehicle_id", "time", "x", "y", "vx", "vy"], "tracks"),
        (INTERACTION, "interaction"),
    ],
)
def test_each_format_by_its_own_columns(tmp_path, columns, fmt):
    path = tmp_path / "table.csv"
    path.write_text(",".join(columns) + "\n" + ",".join("1" for _ in columns) + "\n")
    assert detect_format(path) == fmt


def test_an_unrecognised_file_names_the_formats_and_its_columns(tmp_path):
    path = tmp_path / "odd.csv"
    path.write_text("car,when,east,north\n1,0,0,0\n")
    with pytest.raises(dpgp.DataFormatError) as e:
        dpgp.read(path)
    message = str(e.value)
    assert "['car', 'when', 'east', 'north']" in message
    for fmt in ("interaction", "ngsim", "highd", "ind", "sumo", "eth_ucy", "frames", "tracks"):
        assert fmt in message
    headerless = tmp_path / "three.txt"
    headerless.write_text("1 2 3\n4 5 6\n")
    with pytest.raises(dpgp.DataFormatError, match="eth_ucy"):
        detect_format(headerless)
    with pytest.raises(dpgp.InvalidInputError, match="unknown format"):
        dpgp.read(path, format="csv")
    with pytest.raises(FileNotFoundError):
        dpgp.read(tmp_path / "missing.csv")
    assert set(FORMATS) >= {"interaction", "ngsim", "frames", "tracks", "sumo", "highd", "ind", "eth_ucy"}


def _crop_by_loop(frames, roi):
    """The oracle: row by row, frame by frame."""
    x0, x1, y0, y1 = roi
    ids, rows = [], []
    for i, f in enumerate(frames):
        keep = [r for r in range(len(f)) if x0 <= f.xy[r, 0] <= x1 and y0 <= f.xy[r, 1] <= y1]
        if keep:
            ids.append(frames.ids[i])
            rows.extend(frames.offsets[i] + np.array(keep))
    return ids, np.array(rows)


def test_crop_keeps_exactly_the_vehicles_inside():
    frames = dpgp.datasets.synthetic("intersection", n_frames=30, seed=1)
    frames.tracks = np.arange(frames.n_points)
    roi = (-12.0, 8.0, -15.0, 5.0)
    ids, rows = _crop_by_loop(frames, roi)
    cropped = frames.crop(roi)
    assert list(cropped.ids) == ids and 0 < len(cropped) < len(frames)
    np.testing.assert_array_equal(cropped.xy, frames.xy[rows])
    np.testing.assert_array_equal(cropped.v, frames.v[rows])
    np.testing.assert_array_equal(cropped.tracks, rows)
    keep = np.isin(frames.ids, ids)
    np.testing.assert_array_equal(cropped.labels, frames.labels[keep])
    with pytest.raises(dpgp.InvalidInputError, match="no vehicle lies inside"):
        frames.crop((1e6, 1e6 + 1, 0, 1))


def test_a_file_of_frames_is_cropped_and_stamped(tmp_path):
    frames = dpgp.datasets.synthetic("intersection", n_frames=20, seed=2)
    path = tmp_path / "frames.csv"
    frames.to_pandas().to_csv(path, index=False)
    roi = (-10.0, 10.0, -10.0, 10.0)
    read = dpgp.read(path, roi=roi, dt=0.25)
    assert read.n_points == frames.crop(roi).n_points
    assert read.summary.roi == roi and read.summary.dt == 0.25
    assert read.summary.n_empty_frames == len(frames) - len(read)
    assert getattr(dpgp.read(path), "summary", None) is None  # nothing asked, nothing stamped
    with pytest.raises(dpgp.InvalidInputError, match="units"):
        dpgp.read(path, units="ft->m")
