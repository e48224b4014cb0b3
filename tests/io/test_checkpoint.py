"""Checkpoint and resume (issue 11, item 1): a fit killed at any point and resumed from its
checkpoint is bitwise the fit run without interruption; a checkpoint is a model file with the
same guarantees (no pickle, ModelFileError on damage)."""

from __future__ import annotations

import io
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

import dpgp
import dpgp.io
from dpgp.exceptions import InvalidInputError, ModelFileError

# Synthetic highway frames with a small noise variance: frames keep moving between patterns and
# patterns are born and die, so a resumed chain that computed with other factors or pattern ids
# than the uninterrupted one would part from it (test_the_data_would_catch_a_chain_that_parts).
SETTINGS = dict(iterations=7, checkpoint_every=2, noise_var=0.2, seed=1, progress=False, store_labels=True)


@pytest.fixture(scope="module")
def frames() -> dpgp.Frames:
    return dpgp.datasets.synthetic("highway", 80, seed=3)


class Recording(dpgp.DPGP):
    """A fit that keeps a copy of every checkpoint it writes."""

    def _write_checkpoint(self, traces):  # noqa: ANN001
        super()._write_checkpoint(traces)
        copies = self.__dict__.setdefault("copies", [])
        copy = Path(f"{self.checkpoint}.{len(copies)}")
        shutil.copy(self.checkpoint, copy)
        copies.append(copy)


def differences(a: dpgp.DPGP, b: dpgp.DPGP) -> list[str]:
    """What differs between two fits, bit for bit (wall-clock seconds aside)."""
    out = [n for n in ("labels_", "length_scales_", "label_trace_") if not np.array_equal(getattr(a, n), getattr(b, n))]
    out += [n for n in ("alpha_", "n_iter_", "converged_", "log_joint_") if getattr(a, n) != getattr(b, n)]
    strip = lambda h: {k: v for k, v in h.items() if k != "seconds"}  # noqa: E731
    return out + (["history_"] if strip(a.history_) != strip(b.history_) else [])


def no_temps(directory: Path) -> list[str]:
    return [p.name for p in directory.glob(".dpgp-*")]


@pytest.mark.parametrize(
    "variant",
    [
        dict(likelihood="exact", proposal="full"),
        dict(likelihood="exact", proposal="informed", n_threads=2),
        dict(likelihood="hsgp", proposal="full", assignment="map", n_iter_no_change=2),
        dict(likelihood="hsgp", proposal="informed", seed=4),
    ],
    ids=["exact-full", "exact-informed-2threads", "hsgp-full-map-stopping", "hsgp-informed"],
)
def test_resuming_from_every_checkpoint_gives_the_uninterrupted_fit(frames, tmp_path, variant):
    fit = Recording(**{**SETTINGS, **variant}, checkpoint=str(tmp_path / "fit.ckpt")).fit(frames)
    assert len(fit.copies) >= 3  # after the initialisation, every 2 sweeps, and the end
    sweeps = []
    for copy in fit.copies:
        sweeps.append(dpgp.io.read_metadata(copy)["resume"]["sweeps_done"])
        resumed = dpgp.DPGP.resume(copy)
        assert differences(fit, resumed) == [], copy.name
    assert sweeps[0] == 0
    assert no_temps(tmp_path) == []


class NoRebuild(dpgp.DPGP):
    """A fit that keeps its incremental state instead of rebuilding at the cadence (as fits
    without checkpoints did before issue 17)."""

    def _save_checkpoint(self, stable, traces):  # noqa: ANN001
        return np.asarray(self._sampler.labels())


@pytest.mark.parametrize(
    "variant", [dict(likelihood="exact", proposal="full"), dict(likelihood="hsgp", proposal="informed", n_threads=2)]
)
def test_a_fit_gives_the_same_result_with_or_without_checkpoints(frames, tmp_path, variant):
    """Whether a fit writes checkpoints is an operational choice: same data, settings and seed
    give bitwise the same labels, length scales, alpha and history either way (issue 17)."""
    settings = {**SETTINGS, **variant}
    plain = dpgp.DPGP(**settings).fit(frames)
    checkpointed = dpgp.DPGP(**settings, checkpoint=str(tmp_path / "c")).fit(frames)
    assert differences(plain, checkpointed) == []
    assert len(plain.checkpoint_seconds_["reset"]) == len(checkpointed.checkpoint_seconds_["reset"]) == 1 + 7 // 2
    assert plain.checkpoint_seconds_["write"] == [] and len(checkpointed.checkpoint_seconds_["write"]) == 1 + 7 // 2


def test_the_data_would_catch_a_chain_that_parts(frames):
    """The test data are sensitive: a fit that does not rebuild its sampler at the cadence
    differs from one that does, so the identity above and the resume tests can fail."""
    settings = {**SETTINGS, "likelihood": "exact", "proposal": "full"}
    assert "history_" in differences(NoRebuild(**settings).fit(frames), dpgp.DPGP(**settings).fit(frames))


def test_extending_a_chain_equals_the_longer_fit(frames, tmp_path):
    s = {**SETTINGS, "likelihood": "exact", "proposal": "informed"}
    short = dpgp.DPGP(**s, checkpoint=str(tmp_path / "short.ckpt")).fit(
        frames
    )  # 7 sweeps: ends past its last checkpoint
    longer = dpgp.DPGP(**{**s, "iterations": 11}, checkpoint=str(tmp_path / "long.ckpt")).fit(frames)
    again = dpgp.DPGP.resume(tmp_path / "short.ckpt")
    assert again.resumed_from_ == 7 and differences(short, again) == []
    extended = dpgp.DPGP.resume(tmp_path / "short.ckpt", iterations=11)
    assert extended.resumed_from_ == 6 and extended.iterations == 11
    assert differences(longer, extended) == []
    with pytest.raises(InvalidInputError, match="total length"):
        dpgp.DPGP.resume(tmp_path / "short.ckpt", iterations=5)  # the file now holds 11 sweeps
    with pytest.raises(InvalidInputError, match="total length"):
        dpgp.DPGP.resume(tmp_path / "short.ckpt", iterations="20")


CHILD = """
import sys, dpgp
frames = dpgp.datasets.synthetic("highway", 80, seed=3)
settings = dict(iterations={iterations}, checkpoint_every=2, noise_var=0.2, seed=1, progress=False, store_labels=True)
dpgp.DPGP(**settings, checkpoint=sys.argv[1]).fit(frames)
print("finished", flush=True)
"""


def test_a_fit_killed_at_random_points_resumes_to_its_twin(frames, tmp_path):
    iterations = 24
    t = time.perf_counter()
    twin = dpgp.DPGP(**{**SETTINGS, "iterations": iterations}, checkpoint=str(tmp_path / "twin.ckpt")).fit(frames)
    seconds = time.perf_counter() - t
    rng = random.Random(11)
    killed_at = []
    for kill in range(3):
        path = tmp_path / f"killed{kill}.ckpt"
        proc = subprocess.Popen([sys.executable, "-c", CHILD.format(iterations=iterations), str(path)],
                                stdout=subprocess.PIPE, text=True)  # fmt: skip
        try:
            deadline = time.monotonic() + 120
            while not path.exists() and proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.005)  # the first checkpoint: the initialisation is done
            time.sleep(rng.uniform(0.0, 0.7) * seconds)
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=60)
        finally:
            proc.kill()
            proc.stdout.close()
        assert path.exists(), "the child wrote no checkpoint"
        killed_at.append(dpgp.io.read_metadata(path)["resume"]["sweeps_done"])
        resumed = dpgp.DPGP.resume(path)
        assert resumed.resumed_from_ == killed_at[-1]
        assert differences(twin, resumed) == [], f"kill {kill} at sweep {killed_at[-1]}"
        assert no_temps(tmp_path) == []  # resuming removes what a write cut short left
    # The kills landed mid-chain (a child that finished first proves nothing); the resumed
    # sweeps: {killed_at} of {iterations}.
    assert min(killed_at) < iterations - 2, killed_at


def test_load_reads_a_checkpoint_as_a_model(frames, tmp_path):
    fit = Recording(**SETTINGS, checkpoint=str(tmp_path / "fit.ckpt")).fit(frames)
    middle = dpgp.DPGP.load(fit.copies[1])  # after 2 sweeps
    assert middle.n_iter_ == 2 and len(middle.history_["log_joint"]) == 2
    assert middle.label_trace_.shape == (2, len(frames))
    assert middle.predict(frames[:5]).shape == (5,)
    final = dpgp.DPGP.load(tmp_path / "fit.ckpt")
    assert np.array_equal(final.labels_, fit.labels_) and final.alpha_ == fit.alpha_
    assert np.array_equal(final.predict_proba(frames), fit.predict_proba(frames))
    assert final.checkpoint == str(tmp_path / "fit.ckpt")
    with zipfile.ZipFile(tmp_path / "fit.ckpt") as z:  # no pickle: every member is a plain .npy
        assert all(name.endswith(".npy") for name in z.namelist())
        assert {"resume_labels.npy", "resume_length_scales.npy"} <= set(z.namelist())


@pytest.fixture(scope="module")
def checkpoint_bytes(frames, tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("ckpt") / "fit.ckpt"
    dpgp.DPGP(**{**SETTINGS, "iterations": 3}, checkpoint=str(path)).fit(frames)
    return path.read_bytes()


def _members(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _rewrite(path: Path, arrays: dict[str, np.ndarray]) -> Path:
    """A valid archive (fresh CRCs) of edited members; ``path`` ends in .npz (numpy adds it otherwise)."""
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize("at", [0.1, 0.5, 0.9, 0.999])
def test_a_truncated_checkpoint_is_a_model_file_error(checkpoint_bytes, tmp_path, at):
    path = tmp_path / "cut.ckpt"
    path.write_bytes(checkpoint_bytes[: int(at * len(checkpoint_bytes))])
    for read in (dpgp.DPGP.load, dpgp.DPGP.resume):
        with pytest.raises(ModelFileError):
            read(path)


def test_flipped_bits_are_a_model_file_error(checkpoint_bytes, tmp_path):
    """Each flipped bit is detected (ModelFileError) or harmless: the resumed chain is then
    bitwise the clean one's (a flip in a zip header's timestamp changes nothing read)."""
    clean_path = tmp_path / "clean.ckpt"
    clean_path.write_bytes(checkpoint_bytes)
    clean = dpgp.DPGP.resume(clean_path, iterations=3)
    rng = np.random.default_rng(0)
    path = tmp_path / "flipped.ckpt"
    detected, harmless = 0, 0
    for _ in range(20):
        data = bytearray(checkpoint_bytes)
        i = int(rng.integers(len(data)))
        data[i] ^= 1 << int(rng.integers(8))
        path.write_bytes(bytes(data))
        try:
            resumed = dpgp.DPGP.resume(path, iterations=3)
        except ModelFileError:
            detected += 1
        else:
            assert differences(resumed, clean) == [], f"a flip of byte {i} went undetected and changed the chain"
            harmless += 1
    assert detected + harmless == 20 and detected >= 15, (detected, harmless)


@pytest.mark.parametrize(
    "edit",
    [
        {"sweeps_done": 99},
        {"sweeps_done": -1},
        {"sweeps_done": 1.5},
        {"stable": -2},
        {"stable": 99},
        {"alpha": 0.0},
        {"alpha": "x"},
        {"data_sha256": "0" * 64},
        "not an object",
    ],
    ids=lambda e: str(e)[:30],
)
def test_edited_resume_metadata_is_a_model_file_error(checkpoint_bytes, tmp_path, edit):
    arrays = _members(checkpoint_bytes)
    meta = json.loads(str(arrays["metadata"]))
    meta["resume"] = {**meta["resume"], **edit} if isinstance(edit, dict) else edit
    arrays["metadata"] = np.array(json.dumps(meta))
    path = _rewrite(tmp_path / "edited.npz", arrays)
    for read in (dpgp.DPGP.load, dpgp.DPGP.resume):
        with pytest.raises(ModelFileError):
            read(path)


@pytest.mark.parametrize("member", ["resume_labels", "resume_length_scales", "label_trace"])
def test_a_missing_resume_member_is_a_model_file_error(checkpoint_bytes, tmp_path, member):
    arrays = _members(checkpoint_bytes)
    del arrays[member]
    with pytest.raises(ModelFileError, match=member.split("_")[-1]):
        dpgp.DPGP.resume(_rewrite(tmp_path / "less.npz", arrays))


@pytest.mark.parametrize("member", ["frame_v", "frame_xy"])
def test_data_that_do_not_match_the_fingerprint_are_refused(checkpoint_bytes, tmp_path, member):
    arrays = _members(checkpoint_bytes)
    arrays[member] = arrays[member].copy()
    arrays[member][3, 1] += 0.25  # a plausible edit: the CRCs of the rewritten file are fine
    path = _rewrite(tmp_path / "edited.npz", arrays)
    for read in (dpgp.DPGP.resume, dpgp.DPGP.load):
        with pytest.raises(ModelFileError, match="fingerprint"):
            read(path)


def test_a_plain_model_file_is_not_a_checkpoint(frames, tmp_path):
    model = dpgp.DPGP(**{**SETTINGS, "iterations": 1}).fit(frames)
    model.save(tmp_path / "model.npz")
    with pytest.raises(ModelFileError, match="not a checkpoint"):
        dpgp.DPGP.resume(tmp_path / "model.npz")
    with pytest.raises(FileNotFoundError):
        dpgp.DPGP.resume(tmp_path / "missing.ckpt")


def test_a_failed_write_leaves_no_temporary_file(frames, tmp_path, monkeypatch):
    def fail(src, dst):  # noqa: ANN001
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="No space"):
        dpgp.DPGP(**SETTINGS, checkpoint=str(tmp_path / "fit.ckpt")).fit(frames)
    assert no_temps(tmp_path) == [] and not (tmp_path / "fit.ckpt").exists()


def test_a_fit_removes_what_a_killed_writer_left(frames, tmp_path):
    stale = tmp_path / ".dpgp-fit.ckpt-abc123.tmp"
    other = tmp_path / ".dpgp-other.npz-abc123.tmp"  # another file's: not ours to remove
    stale.write_bytes(b"half a checkpoint")
    other.write_bytes(b"x")
    dpgp.DPGP(**{**SETTINGS, "iterations": 1}, checkpoint=str(tmp_path / "fit.ckpt")).fit(frames)
    assert not stale.exists() and other.exists()


@pytest.mark.parametrize(
    ("settings", "error"),
    [
        ({"checkpoint_every": 0}, InvalidInputError),
        ({"checkpoint_every": 2.5}, InvalidInputError),
        ({"checkpoint_every": True}, InvalidInputError),
        ({"checkpoint": 3}, InvalidInputError),
        ({"checkpoint": ""}, InvalidInputError),
        ({"checkpoint": "/no/such/directory/fit.ckpt"}, FileNotFoundError),
        ({"checkpoint": "."}, IsADirectoryError),
    ],
)
def test_checkpoint_settings_are_checked_before_the_fit(frames, settings, error):
    with pytest.raises(error, match="checkpoint"):
        dpgp.DPGP(**{**SETTINGS, **settings}).fit(frames)


def test_fit_chains_refuses_a_checkpoint(frames, tmp_path):
    with pytest.raises(InvalidInputError, match="checkpoint"):
        dpgp.fit_chains(frames, 2, iterations=2, checkpoint=str(tmp_path / "c.ckpt"))


def test_the_cli_fits_with_a_checkpoint_and_resumes(frames, tmp_path, capsys):
    from dpgp.cli import main

    data = tmp_path / "frames.csv"
    frames.to_pandas().to_csv(data, index=False)
    ckpt, out = tmp_path / "fit.ckpt", tmp_path / "model.npz"
    argv = ["fit", str(data), "-o", str(tmp_path / "first.npz"), "--iterations", "5", "--checkpoint", str(ckpt),
            "--checkpoint-every", "2", "--no-progress", "--seed", "4"]  # fmt: skip
    assert main(argv) == 0
    assert main(["resume", str(ckpt), "--iterations", "8", "-o", str(out), "--no-progress"]) == 0
    assert "resumed" in capsys.readouterr().out
    longer = dpgp.DPGP.load(out)
    assert longer.n_iter_ == 8 and longer.iterations == 8
    assert main(["resume", str(tmp_path / "first.npz")]) == 1
    assert main(["fit", str(data), "-o", str(out), "--checkpoint", str(ckpt), "--chains", "2"]) == 1
    assert main(["resume", str(ckpt), "--iterations", "3"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("dpgp: error: ") for line in err), err
    assert "Traceback" not in "".join(err)
