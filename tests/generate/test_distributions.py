"""φ (vehicle count per frame) and ψ (positions over a grid of bins): densities, sampling,
storage without pickle, and bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import dpgp

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def toy_frames() -> dpgp.Frames:
    # 4 frames with 1, 2, 2, 3 vehicles; positions chosen to fill known bins of (0,4)x(0,2)
    frame = [0, 1, 1, 2, 2, 3, 3, 3]
    x = [0.5, 0.5, 1.5, 3.5, 3.5, 0.2, 3.9, 4.0]
    y = [0.5, 0.5, 1.5, 1.5, 0.5, 0.1, 1.9, 2.0]
    return dpgp.Frames.from_arrays(frame, x, y, np.zeros(8), np.zeros(8))


def test_count_pmf_is_the_empirical_distribution():
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2))
    assert np.allclose(d.count_pmf(), [0, 0.25, 0.5, 0.25])
    assert d.max_count == 3
    assert d.log_count_pmf(2) == pytest.approx(np.log(0.5))
    assert np.array_equal(d.log_count_pmf([0, 4, 17]), [-np.inf] * 3)
    with pytest.raises(dpgp.InvalidInputError, match="whole numbers"):
        d.log_count_pmf(1.5)


def test_position_density_is_a_histogram_uniform_in_each_bin():
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2))
    # bins are 1 x 1; 8 positions: bin (0,0) holds 3 (0.5,0.5 twice and 0.2,0.1), bin (3,1) holds 3
    # (3.5,1.5; 3.9,1.9; and 4.0,2.0 on the upper edge), (1,1) and (3,0) one each
    expect = np.zeros((4, 2))
    expect[0, 0], expect[3, 1], expect[1, 1], expect[3, 0] = 3, 3, 1, 1
    assert np.array_equal(d.position_hist, expect)
    got = np.exp(d.log_position_density([[0.01, 0.01], [0.99, 0.99], [1.5, 1.2], [2.5, 0.5], [-0.1, 0.5], [2, 2.01]]))
    assert np.allclose(got, [3 / 8, 3 / 8, 1 / 8, 0, 0, 0])
    # a density: integrates to 1 over the ROI (sum of bin density times bin area)
    centres = np.array([[i + 0.5, j + 0.5] for i in range(4) for j in range(2)])
    assert np.exp(d.log_position_density(centres)).sum() * 1.0 == pytest.approx(1.0)
    assert d.log_frame_density([[0.5, 0.5], [3.5, 1.5]]) == pytest.approx(np.log(0.5) + 2 * np.log(3 / 8))


def test_sampling_follows_the_distributions():
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2))
    counts = d.sample_counts(40_000, rng=1)
    assert counts.dtype == np.int64
    freq = np.bincount(counts, minlength=4) / len(counts)
    assert np.allclose(freq, [0, 0.25, 0.5, 0.25], atol=0.01)
    xy = d.sample_positions(40_000, rng=np.random.default_rng(2))
    assert xy.shape == (40_000, 2)
    assert xy[:, 0].min() >= 0 and xy[:, 0].max() <= 4 and xy[:, 1].min() >= 0 and xy[:, 1].max() <= 2
    hist, _, _ = np.histogram2d(xy[:, 0], xy[:, 1], bins=(4, 2), range=((0, 4), (0, 2)))
    assert np.allclose(hist / len(xy), d.position_hist / 8, atol=0.01)
    assert hist[2].sum() == 0  # an empty bin is never sampled
    # uniform inside a bin: inside bin (0, 0) the mean is its centre
    inside = xy[(xy[:, 0] < 1) & (xy[:, 1] < 1)]
    assert np.allclose(inside.mean(axis=0), [0.5, 0.5], atol=0.02)
    # reproducible from a seed
    assert np.array_equal(d.sample_positions(5, rng=7), d.sample_positions(5, rng=7))


def test_pseudocount_fills_unseen_counts_and_bins():
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2), pseudocount=1.0)
    assert np.allclose(d.count_pmf(), [0, 2 / 7, 3 / 7, 2 / 7])
    assert np.isfinite(d.log_position_density([[2.5, 0.5]])).all()
    assert d.log_count_pmf(0) == -np.inf  # frames are never empty


def test_held_out_density_is_smoothed_and_normalised():
    """Counts 1, 2, 2, 3 (4 frames) and 8 positions in 8 bins of 1 x 1, smoothed by ½: the
    formula written out by hand, finite for an unseen count and an empty bin."""
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2))
    c = 0.5
    total = 4 + 3 * c + c  # the tail beyond 3 vehicles holds c in all
    phi = {1: (1 + c) / total, 2: (2 + c) / total, 3: (1 + c) / total, 4: c / 2 / total, 6: c / 8 / total}
    psi_full, psi_empty = (3 + c) / (8 + 8 * c), (0 + c) / (8 + 8 * c)  # bins (0, 0) and (2, 0)
    assert d.held_out_log_density([[0.5, 0.5], [2.5, 0.5]]) == pytest.approx(np.log(phi[2] * psi_full * psi_empty))
    assert d.held_out_log_density([[0.5, 0.5]] * 4) == pytest.approx(np.log(phi[4] * psi_full**4))
    assert d.held_out_log_density([[2.5, 0.5]] * 6) == pytest.approx(np.log(phi[6] * psi_empty**6))
    assert d.held_out_log_density([[0.5, 0.5], [4.5, 0.5]]) == -np.inf  # outside the ROI
    # φ̃ sums to 1 over every count; ψ̃ integrates to 1 over the ROI
    logs = [d.held_out_log_density([[0.5, 0.5]] * l) - l * np.log(psi_full) for l in range(1, 80)]
    assert np.exp(logs).sum() == pytest.approx(1.0)
    centres = [[i + 0.5, j + 0.5] for i in range(4) for j in range(2)]
    assert sum(np.exp(d.held_out_log_density([p]) - np.log(phi[1])) for p in centres) == pytest.approx(1.0)


def test_storage_as_plain_arrays(tmp_path):
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2), pseudocount=0.5)
    stored = d.to_dict()
    assert all(isinstance(v, np.ndarray) and v.dtype != object for v in stored.values())
    np.savez(tmp_path / "m.npz", **stored)
    with np.load(tmp_path / "m.npz", allow_pickle=False) as z:
        back = dpgp.EmpiricalDistributions.from_dict(dict(z))
    pts = np.random.default_rng(0).uniform([0, 0], [4, 2], (50, 2))
    assert np.array_equal(back.log_position_density(pts), d.log_position_density(pts))
    assert np.array_equal(back.count_pmf(), d.count_pmf()) and back.roi == d.roi and back.bins == d.bins
    as_lists = {k: v.tolist() for k, v in stored.items()}  # e.g. from JSON
    assert dpgp.EmpiricalDistributions.from_dict(as_lists).roi == d.roi
    with pytest.raises(dpgp.DataFormatError, match="newer"):
        dpgp.EmpiricalDistributions.from_dict({**stored, "version": np.array(99)})
    with pytest.raises(dpgp.DataFormatError, match="missing"):
        dpgp.EmpiricalDistributions.from_dict({"roi": stored["roi"]})


def test_roi_defaults_to_make_frames_crop():
    import pandas as pd

    t = np.arange(0, 5.01, 0.5)
    tracks = pd.DataFrame(
        {"track": np.repeat([0, 1], len(t)), "t": np.r_[t, t], "x": np.r_[t * 2, 10 - t], "y": np.r_[t, t * 0 + 1]}
    )
    frames = dpgp.make_frames(tracks, roi=(0, 8, 0, 4), dt=0.5, units="ft->m")
    d = dpgp.EmpiricalDistributions.from_frames(frames, bins=3)
    assert d.roi == pytest.approx((0, 8 * 0.3048, 0, 4 * 0.3048)) and d.bins == (3, 3)
    plain = dpgp.EmpiricalDistributions.from_frames(frames[:])  # a slice has no summary: bounding box
    assert plain.roi == pytest.approx(frames.bounds())


def test_real_us101_counts():
    path = DATA / "ngsim_us101_frames.tsv"
    if not path.exists():
        pytest.skip(f"real data file {path} is absent (it lives in ../shared/data beside the repo)")
    frames = dpgp.read_frames(path)
    d = dpgp.EmpiricalDistributions.from_frames(frames, bins=(6, 20))
    pmf = d.count_pmf()
    # 7-30 vehicles per frame in this file (its README says 8-19)
    assert np.flatnonzero(pmf)[0] == 7 and d.max_count == 30
    assert np.allclose(pmf, np.bincount(frames.sizes) / len(frames)) and pmf.sum() == pytest.approx(1.0)
    assert np.all(np.isfinite(d.log_position_density(frames.xy)))


def test_bad_input():
    f = toy_frames()
    with pytest.raises(dpgp.InvalidInputError, match="outside the roi"):
        dpgp.EmpiricalDistributions.from_frames(f, roi=(0, 1, 0, 1))
    for roi in ((1, 0, 0, 1), (0, 1, 0), "everywhere"):
        with pytest.raises(dpgp.InvalidInputError, match="roi must be"):
            dpgp.EmpiricalDistributions.from_frames(f, roi=roi)
    for bins in (0, (3, 0), (2.5, 2), (1, 2, 3)):
        with pytest.raises(dpgp.InvalidInputError, match="bins"):
            dpgp.EmpiricalDistributions.from_frames(f, bins=bins)
    d = dpgp.EmpiricalDistributions.from_frames(f)
    with pytest.raises(dpgp.ShapeError):
        d.log_position_density([1.0, 2.0, 3.0])
    with pytest.raises(dpgp.InvalidInputError, match="non-finite"):
        d.log_position_density([[np.nan, 1.0]])
    with pytest.raises(dpgp.InvalidInputError, match="whole number"):
        d.sample_counts(-1)
    with pytest.raises(dpgp.InvalidInputError, match="pseudocount"):
        dpgp.EmpiricalDistributions.from_frames(f, pseudocount=-1)


def test_stored_histograms_that_overflow_or_hold_no_vehicles_are_refused():
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames()).to_dict()
    with pytest.raises(dpgp.InvalidInputError, match="overflow"):
        dpgp.EmpiricalDistributions.from_dict({**d, "count_hist": [1e308, 1e308]})
    with pytest.raises(dpgp.InvalidInputError, match="empty"):
        dpgp.EmpiricalDistributions.from_dict({**d, "count_hist": [5.0, 0.0, 0.0]})
