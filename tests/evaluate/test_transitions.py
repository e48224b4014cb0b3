"""Time order of frames and pattern transitions (issue 20), against a plain-Python oracle."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

import dpgp
from dpgp.data.timeorder import time_order
from dpgp.evaluate.transitions import Transitions, count_transitions
from dpgp.exceptions import ModelFileError, UnorderedFramesError


def _oracle(scenes, times, labels, dt):
    """Counts, entries, exits and runs by walking each scene's frames in time order."""
    k = max(labels) + 1
    counts = np.zeros((k, k), int)
    entry, exit_ = np.zeros(k, int), np.zeros(k, int)
    runs = []
    for s in sorted(set(scenes)):
        idx = sorted((i for i in range(len(times)) if scenes[i] == s), key=lambda i: times[i])
        seqs = [[idx[0]]]
        for a, b in zip(idx, idx[1:]):
            if abs(times[b] - times[a] - dt) < 1e-9:
                counts[labels[a], labels[b]] += 1
                seqs[-1].append(b)
            else:
                seqs.append([b])
        for seq in seqs:
            entry[labels[seq[0]]] += 1
            exit_[labels[seq[-1]]] += 1
            start = 0
            for j in range(1, len(seq) + 1):
                if j == len(seq) or labels[seq[j]] != labels[seq[start]]:
                    runs.append((labels[seq[start]], seq[start], j - start, int(start == 0 or j == len(seq))))
                    start = j
    return counts, entry, exit_, sorted(runs)


@pytest.mark.parametrize("seed", range(5))
def test_counts_entries_exits_and_runs_match_the_oracle(seed):
    rng = np.random.default_rng(seed)
    n = 60
    scenes = rng.integers(0, 3, n).tolist()
    times = np.zeros(n)
    for s in set(scenes):  # each scene on a 0.5 s grid with gaps
        idx = [i for i in range(n) if scenes[i] == s]
        times[idx] = 0.5 * np.sort(rng.choice(3 * len(idx), len(idx), replace=False))
    labels = rng.integers(0, 4, n)
    ids = np.empty(n, dtype=object)
    ids[:] = list(zip([f"s{s}" for s in scenes], times.tolist()))
    perm = rng.permutation(n)  # frames need not come in time order
    tr = count_transitions(labels[perm], ids[perm])
    counts, entry, exit_, runs = _oracle([scenes[i] for i in perm], times[perm], labels[perm].tolist(), 0.5)
    k = len(entry)
    assert np.array_equal(tr.counts[:k, :k], counts)
    assert np.array_equal(tr.entry[:k], entry) and np.array_equal(tr.exit[:k], exit_)
    assert sorted(map(tuple, tr.runs.tolist())) == runs
    assert tr.dt == 0.5
    # every frame starts a pair or ends a recording: rows of probs and exits sum to one
    seen = tr.counts.sum(1) + tr.exit > 0
    assert np.allclose((tr.probs.sum(1) + tr.exit_probs)[seen], 1.0)
    assert tr.dwell().sum() == pytest.approx(0.5 * n)


def test_ids_as_a_model_file_stores_them_keep_their_order():
    ids = np.array(["(0, 0.0)", "(0, 0.5)", "('b', 0.0)", "('b', 0.5)", "(0, 1.0)"])
    o = time_order(ids)
    assert o.next.tolist() == [1, 4, 3, -1, -1]


@pytest.mark.parametrize(
    "ids",
    [np.array(["a", "b"]), np.array([0.0, 0.0]), np.array([0.0, np.nan]), np.array(["(0, 'x')", "(0, 1)"])],
)
def test_frames_without_times_are_a_typed_error(ids):
    with pytest.raises(UnorderedFramesError):
        count_transitions([0, 0], ids)


def test_bad_labels_are_an_error():
    with pytest.raises(ValueError, match="non-negative integers"):
        count_transitions([0, -1], np.array([0.0, 1.0]))


@pytest.fixture(scope="module")
def fitted():
    frames = dpgp.datasets.synthetic("intersection", n_frames=30, seed=5)
    return dpgp.DPGP(iterations=3, seed=1, progress=False).fit(frames)


def test_model_transitions_round_trip_through_the_model_file(fitted, tmp_path):
    tr = fitted.transitions_
    assert tr.counts.shape == (fitted.n_patterns_, fitted.n_patterns_)
    assert tr.counts.sum() == len(fitted.labels_) - 1  # ids 0..29: one unbroken recording
    path = tmp_path / "m.npz"
    fitted.save(path)
    loaded = dpgp.DPGP.load(path)
    back = loaded.transitions_
    assert np.array_equal(back.counts, tr.counts) and np.array_equal(back.runs, tr.runs)
    # a file from before issue 20 (no "transitions" in its metadata) loads and recomputes them
    old = tmp_path / "old.npz"
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(old, "w") as dst:
        for item in src.infolist():
            data = src.read(item.filename)
            if item.filename == "metadata.npy":
                arr = np.lib.format.read_array(__import__("io").BytesIO(data))
                meta = json.loads(str(arr))
                assert "transitions" in meta
                del meta["transitions"]
                buf = __import__("io").BytesIO()
                np.lib.format.write_array(buf, np.array(json.dumps(meta)))
                data = buf.getvalue()
            dst.writestr(item, data)
    again = dpgp.DPGP.load(old).transitions_
    assert np.array_equal(again.counts, tr.counts)


def test_stored_transitions_that_do_not_fit_are_a_model_file_error():
    good = Transitions(np.zeros((2, 2), int), np.array([1, 0]), np.array([0, 1]), np.zeros((0, 4), int), 0.5)
    assert Transitions.from_dict(good.to_dict(), 2).n_patterns == 2
    with pytest.raises(ModelFileError):
        Transitions.from_dict(good.to_dict(), 3)
    with pytest.raises(ModelFileError):
        Transitions.from_dict({**good.to_dict(), "dt": -1}, 2)


def test_plot_and_info_show_the_transitions(fitted, tmp_path, capsys):
    fig = dpgp.plot.transitions(fitted)
    assert len(fig.axes) >= 2
    path = tmp_path / "m.npz"
    fitted.save(path)
    from dpgp.cli import main

    main(["info", str(path)])
    assert "consecutive frames share a pattern" in capsys.readouterr().out


def test_unordered_frames_fit_and_save_but_have_no_transitions(tmp_path):
    f = dpgp.datasets.synthetic("intersection", n_frames=12, seed=2)
    f = dpgp.Frames(np.array([f"f{i}" for i in range(len(f))]), f.offsets, f.xy, f.v)
    m = dpgp.DPGP(iterations=1, seed=0, progress=False).fit(f)
    with pytest.raises(UnorderedFramesError, match="no time order"):
        _ = m.transitions_
    m.save(tmp_path / "u.npz")
    with pytest.raises(UnorderedFramesError):
        _ = dpgp.DPGP.load(tmp_path / "u.npz").transitions_
