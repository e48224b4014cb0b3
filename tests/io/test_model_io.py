"""Model files: a saved and loaded model predicts, simulates, generates and plots exactly as the
original; truncated, corrupted, foreign and newer-version files are refused with ModelFileError;
a failed save leaves the previous file intact."""

from __future__ import annotations

import io as _io
import json
import os
import zipfile

import numpy as np
import pytest

import dpgp
from dpgp.data.framing import FramingSummary
from dpgp.io import modelfile as mio

from distributions_oracle import smoothed_oracle
from model_files import _rewrite, _rewrite_metadata


def _summary(frames: dpgp.Frames) -> FramingSummary:
    zero = {f: 0 for f in FramingSummary.__dataclass_fields__ if f.startswith("n_")}
    return FramingSummary(**{**zero, "dt": 0.25, "max_gap": 1.0, "roi": (-55.0, 55.0, -55.0, 55.0), "units": "m",
                             "velocity": "columns", "smoothing": (5, 2), "n_frames": len(frames)})  # fmt: skip


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    frames = dpgp.datasets.synthetic("intersection", n_frames=40, seed=11)
    frames.summary = _summary(frames)
    model = dpgp.DPGP(
        iterations=3, seed=4, progress=False, store_labels=True, length_scale_prior=(8.0, 1.5), noise_var="global"
    ).fit(frames)
    path = tmp_path_factory.mktemp("io") / "model.npz"
    model.save(path)
    return model, path


def test_round_trip_is_exact(fitted):
    model, path = fitted
    back = dpgp.DPGP.load(path)
    for name in ("labels_", "weights_", "length_scales_", "pattern_ids_", "label_trace_"):
        np.testing.assert_array_equal(getattr(back, name), getattr(model, name), err_msg=name)
    assert back.alpha_ == model.alpha_ and back.log_joint_ == model.log_joint_
    assert back.history_ == model.history_ and back.n_iter_ == model.n_iter_ and back.converged_ == model.converged_
    assert back.get_params() == model.get_params() and back.params_ == model.params_
    assert back.frames_.summary == model.frames_.summary
    np.testing.assert_array_equal(back.frames_.xy, model.frames_.xy)
    np.testing.assert_array_equal(back.frames_.labels, model.frames_.labels)
    frames = dpgp.datasets.synthetic("intersection", n_frames=10, seed=99)
    np.testing.assert_array_equal(back.predict_proba(frames), model.predict_proba(frames))
    np.testing.assert_array_equal(back.score_samples(frames), model.score_samples(frames))
    q = np.random.default_rng(0).uniform(-50, 50, (30, 2))
    for k in range(model.n_patterns_):
        for a, b in zip(back.velocity_field(k, q), model.velocity_field(k, q)):
            np.testing.assert_array_equal(a, b)


def test_loaded_model_simulates_and_generates_exactly(fitted):
    model, path = fitted
    back = dpgp.DPGP.load(path)
    for kwargs in (dict(method="euler"), dict(method="rk4"), dict(stochastic=True, seed=3)):
        a, b = model.simulate(2, steps=15, **kwargs), back.simulate(2, steps=15, **kwargs)
        assert a.dt == 0.25, "dt comes from the framing summary"
        for name in ("positions", "velocities", "in_roi", "low_data", "t"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    sa, sb = model.sample_scenarios(5, steps=10, seed=8), back.sample_scenarios(5, steps=10, seed=8)
    assert sa.to_pandas().equals(sb.to_pandas())


def _pixels(fig) -> bytes:
    buf = _io.BytesIO()
    fig.savefig(buf, format="rgba", dpi=50)
    return buf.getvalue()


def test_loaded_model_plots_exactly(fitted):
    model, path = fitted
    back = dpgp.DPGP.load(path)
    assert _pixels(dpgp.plot.velocity_field(model, 1, grid=12).figure) == _pixels(
        dpgp.plot.velocity_field(back, 1, grid=12).figure
    )
    assert _pixels(dpgp.plot.simulation(model, 3).figure) == _pixels(dpgp.plot.simulation(back, 3).figure)
    assert _pixels(dpgp.plot.trace(model)) == _pixels(dpgp.plot.trace(back))


def test_file_is_plain_npz_with_versioned_json(fitted):
    _, path = fitted
    with np.load(path, allow_pickle=False) as npz:  # loads without pickle
        meta = json.loads(str(npz["metadata"]))
        assert all(npz[k].dtype != object for k in npz.files)
    # A file with its frames needs version 2 (readers of 2 read it); only frames left in shards need 3.
    assert meta["format"] == "dpgp-model" and meta["format_version"] == 2 < mio.FORMAT_VERSION
    assert meta["dpgp_version"] == dpgp.__version__
    assert meta["settings"]["length_scale_prior"] == [8.0, 1.5]
    phi_psi = dpgp.EmpiricalDistributions.from_dict(meta["distributions"])
    assert phi_psi.count_hist.sum() == 40
    assert mio.read_metadata(path) == meta


def test_newer_version_is_refused(fitted, tmp_path):
    _, path = fitted

    def bump(meta):
        meta["format_version"] = mio.FORMAT_VERSION + 1
        meta["dpgp_version"] = "9.0.0"

    _rewrite_metadata(path, tmp_path / "new.npz", bump)
    with pytest.raises(dpgp.ModelFileError, match="newer|upgrade") as e:
        dpgp.DPGP.load(tmp_path / "new.npz")
    assert "9.0.0" in str(e.value)


def test_files_with_one_noise_variance_load_as_a_pair(fitted, tmp_path):
    """Files written before the noise variance was per component hold one number."""
    model, path = fitted

    def one_noise(meta):
        meta["resolved"]["noise_var"] = 0.7
        meta["params"]["noise_var"] = 0.7

    _rewrite_metadata(path, tmp_path / "old.npz", one_noise)
    old = dpgp.DPGP.load(tmp_path / "old.npz")
    assert old.noise_var_ == (0.7, 0.7) and old.params_.noise_var == (0.7, 0.7)
    assert np.all(np.isfinite(old.score_samples(model.frames_[:5])))


def test_smoothing_is_stored_and_files_before_it_load_flagged(fitted, tmp_path):
    """The pseudo-counts set from the training frames are in the file and come back; a file
    written before them (no pseudo-counts: the paper's unsmoothed φ, ψ) loads with that form
    flagged, says so in its summary, and scores held-out frames smoothed by ½ as it did then."""
    model, path = fitted
    mine = dpgp.generate.scenarios.distributions(model)
    stored = mio.read_metadata(path)["distributions"]
    assert (stored["count_pseudocount"], stored["position_pseudocount"]) == mine.pseudocount
    assert (
        not mine.is_paper_form
        and dpgp.generate.scenarios.distributions(dpgp.DPGP.load(path)).pseudocount == mine.pseudocount
    )

    def before_issue_36(meta):
        d = meta["distributions"]
        d.pop("count_pseudocount"), d.pop("position_pseudocount")
        d["pseudocount"] = 0.0

    _rewrite_metadata(path, tmp_path / "old.npz", before_issue_36)
    old = dpgp.DPGP.load(tmp_path / "old.npz")
    d = dpgp.generate.scenarios.distributions(old)
    assert d.is_paper_form and "the paper's unsmoothed form" in old.summary()
    frames = dpgp.datasets.synthetic("intersection", n_frames=10, seed=99)
    frames = dpgp.Frames(frames.ids, frames.offsets, frames.xy * 1.2, frames.v)  # some beyond the ROI
    log_phi, log_psi = smoothed_oracle(model.frames_.sizes, model.frames_.xy, d.roi, d.bins, 0.5, 0.5)
    want = [log_phi(len(f)) + sum(log_psi(x, y) for x, y in f.xy) for f in frames]
    got = old.score_samples(frames) - old.score_samples(frames, positions=False)
    np.testing.assert_allclose(got, want, rtol=1e-9)
    assert np.isfinite(got).all()


def test_truncated_files_are_refused(fitted, tmp_path):
    _, path = fitted
    data = path.read_bytes()
    for cut in (0, 10, len(data) // 3, len(data) // 2, len(data) - 30):
        bad = tmp_path / f"cut{cut}.npz"
        bad.write_bytes(data[:cut])
        with pytest.raises(dpgp.ModelFileError):
            dpgp.DPGP.load(bad)


def test_corrupted_files_are_refused(fitted, tmp_path):
    _, path = fitted
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        infos = z.infolist()
    # flip bytes inside the compressed data of every member: zlib or the CRC catches it
    for info in infos:
        start = info.header_offset + 30 + len(info.filename) + len(info.extra)
        bad = bytearray(data)
        mid = start + info.compress_size // 2
        bad[mid : mid + 4] = bytes(b ^ 0xFF for b in bad[mid : mid + 4])
        (tmp_path / "bad.npz").write_bytes(bytes(bad))
        with pytest.raises(dpgp.ModelFileError):
            dpgp.DPGP.load(tmp_path / "bad.npz")


def test_a_member_flagged_as_encrypted_is_refused(fitted, tmp_path):
    """One flipped bit in a central-directory entry marks the member encrypted; zipfile then
    raises RuntimeError, which must reach the user as a ModelFileError (fuzz model_files:177)."""
    _, path = fitted
    data = bytearray(path.read_bytes())
    central = data.find(b"PK\x01\x02")  # the first central-directory entry
    data[central + 8] |= 0x01  # general-purpose flag bit 0: encrypted
    (tmp_path / "bad.npz").write_bytes(bytes(data))
    with pytest.raises(dpgp.ModelFileError, match="corrupted"):
        dpgp.DPGP.load(tmp_path / "bad.npz")


def test_foreign_files_are_refused(fitted, tmp_path):
    _, path = fitted
    csv = tmp_path / "frames.csv"
    csv.write_text("frame,x,y,vx,vy\n0,1,2,3,4\n")
    np.save(tmp_path / "array.npy", np.zeros(3))
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    np.savez(
        tmp_path / "objects.npz", **{k: np.zeros(1) for k in mio._REQUIRED}, frame_ids_=np.array([{}], dtype=object)
    )
    for bad, match in [
        (csv, "not|corrupt"),
        (tmp_path / "array.npy", "single numpy array"),
        (tmp_path / "other.npz", "lacks"),
    ]:
        with pytest.raises(dpgp.ModelFileError, match=match):
            dpgp.DPGP.load(bad)
    with pytest.raises(dpgp.ModelFileError):
        dpgp.DPGP.load(tmp_path / "objects.npz")
    # a well-formed archive with the wrong format name, or labels that do not fit the frames
    _rewrite(
        path,
        tmp_path / "fmt.npz",
        lambda k, v: np.array(json.dumps({**json.loads(str(v)), "format": "x"})) if k == "metadata" else v,
    )
    with pytest.raises(dpgp.ModelFileError, match="not a dpgp model"):
        dpgp.DPGP.load(tmp_path / "fmt.npz")
    _rewrite(path, tmp_path / "lab.npz", lambda k, v: v[:-1] if k == "labels" else v)
    with pytest.raises(dpgp.ModelFileError, match="labels"):
        dpgp.DPGP.load(tmp_path / "lab.npz")
    _rewrite(path, tmp_path / "json.npz", lambda k, v: np.array("{not json") if k == "metadata" else v)
    with pytest.raises(dpgp.ModelFileError, match="JSON"):
        dpgp.DPGP.load(tmp_path / "json.npz")
    with pytest.raises(FileNotFoundError):
        dpgp.DPGP.load(tmp_path / "missing.npz")
    assert issubclass(dpgp.ModelFileError, (OSError, dpgp.DpgpError))


def test_failed_save_keeps_the_previous_file(fitted, tmp_path, monkeypatch):
    model, _ = fitted
    target = tmp_path / "m.npz"
    model.save(target)
    before = target.read_bytes()

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", boom)
    with pytest.raises(OSError, match="disk full"):
        model.save(target)
    assert target.read_bytes() == before
    assert os.listdir(tmp_path) == ["m.npz"], "the temporary file is removed"


def test_unfitted_model_cannot_be_saved(tmp_path):
    with pytest.raises(dpgp.NotFittedError):
        dpgp.DPGP().save(tmp_path / "m.npz")
