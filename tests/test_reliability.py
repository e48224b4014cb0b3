"""Reliability, second round (issue 17): each class of defect a hostile user found, as a test
that failed before the fix. The checkpoint identity is in tests/test_checkpoint.py
(``test_a_fit_gives_the_same_result_with_or_without_checkpoints``), the GEMM arena in
tests/test_memory.py, the fuzz generators of every class in tests/fuzz_cases.py."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import dpgp
from dpgp.gp import GPParams, log_marginal_likelihood, log_predictive, posterior

import fuzz_cases as fc
from test_fuzz import tiny  # noqa: F401 - the fuzz suite's tiny fitted model and its file


def _members(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _with_metadata(path: Path, out: Path, edit) -> Path:
    arrays = _members(path)
    meta = json.loads(str(arrays["metadata"]))
    edit(meta)
    arrays["metadata"] = np.array(json.dumps(meta))
    np.savez(out, **arrays)
    return out


# --- 2. extreme magnitudes: finite or refused up front, naming the limit -----------------------------
@pytest.mark.parametrize("alpha", [1e308, 5e-324, 1e101, 1e-101])
def test_an_alpha_past_its_range_is_refused_with_the_limit(alpha):
    frames = dpgp.datasets.synthetic("intersection", n_frames=8, seed=0, vehicles=(2, 4))
    with pytest.raises(dpgp.InvalidInputError, match=r"\[1e-100, 1e\+100\]"):  # was a NaN or inf log_joint_
        dpgp.DPGP(alpha=alpha, iterations=1, progress=False, noise_var=1.0).fit(frames)


@pytest.mark.parametrize("alpha", [1e100, 1e-100])
def test_an_alpha_at_its_limits_fits_finitely(alpha):
    frames = dpgp.datasets.synthetic("intersection", n_frames=8, seed=0, vehicles=(2, 4))
    model = dpgp.DPGP(alpha=alpha, iterations=2, progress=False, noise_var=1.0).fit(frames)
    assert np.isfinite(model.log_joint_) and np.all(np.isfinite(model.history_["log_joint"]))
    assert np.all(np.isfinite(model.predict_proba(frames)))


@pytest.mark.parametrize("scale", [1e154, 1e170, 1e200])
def test_gp_densities_of_huge_velocities_are_refused_not_minus_inf(scale):
    rng = np.random.default_rng(0)
    xy, v = rng.normal(size=(4, 2)), rng.normal(size=(4, 2)) * scale
    p = GPParams((5.0, 5.0), (1.0, 1.0), (0.5, 0.5), (0.0, 0.0))
    for call in (lambda: log_marginal_likelihood(xy, v, p), lambda: log_predictive(xy[:2], v[:2], xy[2:], v[2:], p),
                 lambda: posterior(xy, v, xy, p)):  # fmt: skip
        with pytest.raises(dpgp.InvalidInputError, match="1e\\+100"):  # was -inf
            call()


@pytest.mark.parametrize("scale", [1e154, 1e200, 1e300])
def test_gp_densities_at_huge_positions_stay_finite(scale):
    """The kernel only sees differences over length scales: huge coordinates are finite."""
    rng = np.random.default_rng(1)
    xy, v = rng.normal(size=(4, 2)) * scale, rng.normal(size=(4, 2))
    p = GPParams((5.0, 5.0), (1.0, 1.0), (0.5, 0.5), (0.0, 0.0))
    assert np.isfinite(log_marginal_likelihood(xy, v, p)) and np.isfinite(
        log_predictive(xy[:2], v[:2], xy[2:], v[2:], p)
    )
    assert np.isfinite(log_marginal_likelihood(xy + 1e300, v, p))


@pytest.mark.parametrize(
    "edit",
    [
        pytest.param(lambda m: m.__setitem__("alpha", 1e308), id="alpha-1e308"),
        pytest.param(lambda m: m.__setitem__("alpha", 5e-324), id="alpha-5e-324"),
        pytest.param(lambda m: m["params"].__setitem__("noise_var", [1e-300, 1e-300]), id="noise_var-1e-300"),
        pytest.param(lambda m: m["params"].__setitem__("signal_var", [1e300, 1e300]), id="signal_var-1e300"),
        pytest.param(lambda m: m["params"].__setitem__("mean", [1e200, 1e200]), id="mean-1e200"),
    ],
)
def test_a_model_file_with_extreme_finite_numbers_is_refused(tiny, tmp_path, edit):
    """Each loaded before and then gave NaN or -inf from predict_proba, score_samples or
    conditional_log_probs."""
    path = _with_metadata(tiny[1], tmp_path / "extreme.npz", edit)
    with pytest.raises(dpgp.ModelFileError, match="corrupted"):
        dpgp.DPGP.load(path)


@pytest.mark.parametrize("prior", [(1.7e308, 1.0), (1.0, 1e300), (1e-200, 1.0), (1e99, 1e99)])
def test_a_length_scale_prior_past_its_limits_is_refused(prior):  # (1.7e308, 1): a NaN log joint (fuzz)
    frames = dpgp.datasets.synthetic("intersection", n_frames=8, seed=0, vehicles=(2, 4))
    with pytest.raises(dpgp.InvalidInputError, match="1e\\+100"):
        dpgp.DPGP(length_scale_prior=prior, iterations=1, progress=False, noise_var=1.0).fit(frames)


def test_a_budget_past_what_the_core_counts_limits_nothing():  # 2**70 was OverflowError (fuzz)
    frames = dpgp.datasets.synthetic("intersection", n_frames=8, seed=0, vehicles=(2, 4))
    model = dpgp.DPGP(memory_budget=2**70, iterations=1, progress=False, noise_var=1.0).fit(frames)
    assert model.memory_budget_ == 2**63 - 1


def test_a_time_axis_too_long_to_hold_is_refused_even_without_vehicles(tiny):  # was numpy's MemoryError (fuzz)
    with pytest.raises(dpgp.InvalidInputError, match="fewer steps"):
        tiny[0].sample_scenarios(0, steps=2 * 10**8, dt=1e-300)


def test_a_model_file_with_an_extreme_length_scale_prior_is_refused(tiny, tmp_path):  # a NaN log joint (fuzz)
    path = _with_metadata(
        tiny[1], tmp_path / "prior.npz", lambda m: m["resolved"].__setitem__("length_scale_prior", [1e308, 1e308])
    )
    with pytest.raises(dpgp.ModelFileError, match="length_scale_prior"):
        dpgp.DPGP.load(path)


def test_an_roi_wider_than_the_float_range_is_refused():  # was an IndexError from an overflowing bin (fuzz)
    frames = dpgp.datasets.synthetic("intersection", n_frames=4, seed=0, vehicles=(2, 3))
    with pytest.raises(dpgp.InvalidInputError, match="wider than the floating-point range"):
        dpgp.EmpiricalDistributions.from_frames(frames, roi=(0, 1e308, -1e308, 1e308))


# --- 3. temporary files ---------------------------------------------------------------------------------
def _chattr(flag: str, path: Path) -> bool:
    if shutil.which("chattr") is None:
        return False
    return subprocess.run(["chattr", flag, str(path)], capture_output=True).returncode == 0


def test_a_save_into_an_append_only_directory_leaves_no_temporary_file(tiny, tmp_path):
    """In an append-only directory (``chattr +a``) a file can be created but neither renamed
    nor removed: the temporary file of a save stayed behind for good, with a PermissionError."""
    d = tmp_path / "append-only"
    d.mkdir()
    (d / "model.npz").write_bytes(b"old")
    if not _chattr("+a", d):
        pytest.skip("chattr +a is not available here (needs root and a file system with inode flags)")
    try:
        for target in (d / "model.npz", d / "new.npz"):
            with pytest.raises(PermissionError, match="append-only"):
                tiny[0].save(target)
        assert sorted(p.name for p in d.iterdir()) == ["model.npz"] and (d / "model.npz").read_bytes() == b"old"
    finally:
        _chattr("-a", d)


def test_a_refused_rename_removes_the_temporary_file(tiny, tmp_path, monkeypatch):
    def refuse(src, dst):  # noqa: ANN001
        raise PermissionError(13, "Permission denied", dst)

    monkeypatch.setattr(os, "replace", refuse)
    with pytest.raises(PermissionError):
        tiny[0].save(tmp_path / "model.npz")
    assert list(tmp_path.iterdir()) == []


# --- 4. huge declared shapes -------------------------------------------------------------------------
@pytest.mark.parametrize("member", ["labels", "frame_offsets", "frame_xy", "length_scales", "frame_ids"])
@pytest.mark.parametrize("descr", ["|V0", "<U0"])
def test_a_member_declaring_1e11_empty_items_is_refused_before_allocating(tiny, tmp_path, member, descr):
    """1e11 items of zero bytes read as nothing; converting them (labels to int64) asked numpy
    for 745 GiB and raised its MemoryError subclass."""
    shape = (10**11, 2) if member in ("frame_xy", "length_scales") else (10**11,)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for k, v in _members(tiny[1]).items():
            raw = io.BytesIO()
            np.save(raw, v, allow_pickle=False)
            z.writestr(k + ".npy", fc._npy_header(descr, shape) if k == member else raw.getvalue())
    path = tmp_path / "huge.npz"
    path.write_bytes(buf.getvalue())
    with pytest.raises(dpgp.ModelFileError):
        dpgp.DPGP.load(path)


def test_frames_check_sizes_before_converting():
    huge = np.empty(10**11, dtype="V0")  # no memory: zero-byte items
    xy = np.zeros((3, 2))
    with pytest.raises(dpgp.ShapeError):
        dpgp.Frames(np.arange(2), huge, xy, xy)
    with pytest.raises(dpgp.ShapeError):
        dpgp.Frames(huge, np.array([0, 3]), xy, xy)
    with pytest.raises(dpgp.ShapeError):
        dpgp.Frames(np.arange(1), np.array([0, 3]), np.empty((10**11, 2), dtype="V0"), xy)


# --- 5. legal input: bytes paths, numbers past the float range, duplicated columns -----------------------
def test_bytes_paths_work_wherever_a_path_is_taken(tiny, tmp_path):
    model, _ = tiny
    name = os.fsencode(str(tmp_path)) + b"/mod\xe9l.npz"  # a non-UTF-8 byte name round-trips
    model.save(name)  # was TypeError
    assert dpgp.DPGP.load(name).n_patterns_ == model.n_patterns_
    assert dpgp.io.read_metadata(name)["format"] == "dpgp-model"
    ckpt = os.fsencode(str(tmp_path / "fit.ckpt"))
    frames = model.frames_
    fitted = dpgp.DPGP(iterations=2, seed=0, progress=False, noise_var=1.0, checkpoint=ckpt, checkpoint_every=1).fit(
        frames
    )
    assert dpgp.DPGP.resume(ckpt).n_iter_ == fitted.n_iter_
    table = tmp_path / "frames.csv"
    frames.to_pandas().to_csv(table, index=False)
    assert len(dpgp.read_frames(os.fsencode(str(table)))) == len(frames)
    tracks = tmp_path / "tracks.csv"
    pd.DataFrame({"track": [0, 0, 1], "t": [0.0, 0.5, 0.0], "x": [0.0, 1, 2], "y": [0.0, 0, 1]}).to_csv(
        tracks, index=False
    )
    assert len(dpgp.read_tracks(os.fsencode(str(tracks)))) == 3
    ngsim = tmp_path / "ngsim.csv"
    ngsim.write_text("Vehicle_ID,Frame_ID,Total_Frames,Local_X,Local_Y\n1,1,2,0.0,0.0\n1,2,2,1.0,0.0\n")
    assert len(dpgp.read_ngsim(os.fsencode(str(ngsim)))) == 2  # was TypeError
    scenarios = model.sample_scenarios(2, steps=2, seed=0)
    scenarios.save(os.fsencode(str(tmp_path / "s.csv")))
    scenarios.to_sumo(os.fsencode(str(tmp_path / "s.xml")))
    assert (tmp_path / "s.csv").exists() and (tmp_path / "s.xml").exists()
    with pytest.raises(TypeError):  # not a path at all: Python's convention stays
        model.save(3)


def test_an_integer_past_the_float_range_is_a_data_format_error(tmp_path):
    path = tmp_path / "big.csv"
    path.write_text("frame,x,y,vx,vy\n0,1,2,3,4\n1," + "9" * 400 + ",2,3,4\n")
    with pytest.raises(dpgp.DataFormatError, match="too large for a double"):  # was OverflowError
        dpgp.read_frames(path)
    df = pd.DataFrame({"frame": [0, 1], "x": [1, 10**400], "y": [1, 2], "vx": [1, 2], "vy": [1, 2]})
    with pytest.raises(dpgp.DataFormatError, match="too large for a double"):
        dpgp.read_frames(df)


def test_an_ngsim_column_named_like_an_output_column_is_a_data_format_error(tmp_path):  # was ValueError (fuzz)
    path = tmp_path / "ngsim.csv"
    path.write_text("Vehicle_ID,Frame_ID,x,Local_X,Local_Y\n1,1,2,0.0,0.0\n1,2,2,1.0,0.0\n")
    with pytest.raises(dpgp.DataFormatError, match="clash"):
        dpgp.read_ngsim(path)


def test_saving_over_a_directory_names_the_target(tiny, tmp_path):
    with pytest.raises(IsADirectoryError, match="directory") as e:
        tiny[0].save(tmp_path)
    assert ".tmp" not in str(e.value) and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "preset, columns",
    [
        (None, ["track", "t", "x", "x", "y"]),
        ("highd", ["id", "frame", "x", "y", "x"]),
        ("ind", ["trackId", "frame", "xCenter", "yCenter", "xCenter"]),
    ],
)
def test_duplicated_column_names_are_a_data_format_error(preset, columns):
    df = pd.DataFrame([[0, 1, 1.0, 2.0, 3.0], [0, 2, 1.0, 2.0, 3.0]], columns=columns)
    with pytest.raises(dpgp.DataFormatError, match="more than one column named"):  # was AttributeError
        dpgp.read_tracks(df, preset=preset)


# --- 6. tests that can fail ---------------------------------------------------------------------------
def test_the_fuzz_slice_tolerates_no_class_of_outcome():
    import test_fuzz

    assert test_fuzz.KNOWN_OPEN == []
    assert not test_fuzz.known_open("fit", fc.Outcome("nonfinite", "the number nan"))
