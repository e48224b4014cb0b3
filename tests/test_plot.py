"""dpgp.plot: every function returns a non-empty figure with the expected artists, draws on the
axes it is given, and needs no GUI (figures belong to no pyplot manager)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from matplotlib.axes import Axes
from matplotlib.collections import PathCollection
from matplotlib.figure import Figure
from matplotlib.image import AxesImage
from matplotlib.patches import Rectangle
from matplotlib.quiver import Quiver

import dpgp
from dpgp import plot


@pytest.fixture(scope="module")
def model() -> dpgp.DPGP:
    frames = dpgp.datasets.synthetic("intersection", n_frames=40, seed=2)
    return dpgp.DPGP(iterations=4, seed=1, progress=False).fit(frames)


def _quivers(ax: Axes) -> list[Quiver]:
    return [c for c in ax.collections if isinstance(c, Quiver)]


def _drawn(fig: Figure, dpi: int = 50) -> np.ndarray:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGBA"))


def _not_blank(fig: Figure) -> None:
    assert fig.canvas.manager is None, "no pyplot/GUI figure manager"
    img = _drawn(fig)
    assert img.shape[0] > 100 and img.shape[1] > 100  # (pixels at 50 dpi)
    assert len(np.unique(img.reshape(-1, 4), axis=0)) > 10, "the figure is (almost) one colour"


def test_weights_are_decreasing_bars(model):
    ax = plot.weights(model)
    bars = [p for p in ax.patches if isinstance(p, Rectangle)]
    assert len(bars) == model.n_patterns_
    heights = np.array([b.get_height() for b in bars])
    np.testing.assert_allclose(heights, np.sort(model.weights_)[::-1])
    assert np.all(np.diff(heights) <= 0)
    _not_blank(ax.figure)


def test_velocity_field_has_one_arrow_per_grid_point_and_variance_shading(model):
    ax = plot.velocity_field(model, 1, grid=(9, 7))
    (q,) = _quivers(ax)
    assert q.N == 9 * 7
    pts, _, _ = plot.field_grid(model, (9, 7))
    mean, var = model.velocity_field(1, pts)
    np.testing.assert_allclose(q.U, mean[:, 0])
    np.testing.assert_allclose(q.V, mean[:, 1])
    (img,) = [a for a in ax.images if isinstance(a, AxesImage)]
    rel = (var / np.asarray(model.params_.signal_var)).max(axis=1)
    np.testing.assert_allclose(np.asarray(img.get_array()), rel.reshape(7, 9))
    # arrows in low-data regions are pale: as many pale arrows as grid points above the threshold
    colours = q.get_facecolors()
    pale = np.all(np.isclose(colours[:, :3], [176 / 255] * 3, atol=1e-3), axis=1)
    assert pale.sum() == (rel > 0.5).sum()
    assert 0 < pale.sum() < q.N, "this grid spans both data and empty regions"
    _not_blank(ax.figure)


def test_velocity_field_shows_data_on_request(model):
    ax = plot.velocity_field(model, 0, grid=5, show_data=True)
    (pts,) = [c for c in ax.collections if isinstance(c, PathCollection)]
    assert len(pts.get_offsets()) == model.frames_.sizes[model.labels_ == 0].sum()


def test_frames_draws_every_vehicle_of_the_patterns_frames(model):
    ax = plot.frames(model, 0, max_frames=None)
    (q,) = _quivers(ax)
    members = model.labels_ == 0
    assert q.N == model.frames_.sizes[members].sum()
    np.testing.assert_array_equal(q.U, model.frames_[np.flatnonzero(members)].v[:, 0])
    ax = plot.frames(model, 0, max_frames=2)
    assert _quivers(ax)[0].N == model.frames_.sizes[np.flatnonzero(members)[:2]].sum()
    _not_blank(ax.figure)


def test_simulation_draws_one_trajectory_per_vehicle(model):
    frame = 3
    ax = plot.simulation(model, frame, steps=12)
    n = len(model.frames_[frame])
    lines = [l for l in ax.lines if l.get_linestyle() == "-"]
    assert len(lines) == n
    sim = model.simulate(frame, steps=12)
    np.testing.assert_array_equal(lines[0].get_xydata()[0], sim.positions[0, 0])
    assert len(_quivers(ax)) == 1, "the pattern's field in the background"
    _not_blank(ax.figure)
    # a given result is drawn as is, and on the axes passed in
    fig = Figure()
    mine = fig.add_subplot()
    assert plot.simulation(model, frame, ax=mine, result=sim) is mine


def test_trace_has_k_alpha_and_log_joint(model):
    fig = plot.trace(model)
    assert isinstance(fig, Figure) and len(fig.axes) == 3
    for ax, key in zip(fig.axes, ("n_patterns", "alpha", "log_joint")):
        (line,) = ax.lines
        np.testing.assert_allclose(line.get_ydata(), model.history_[key])
        assert len(line.get_xdata()) == model.n_iter_ == 4
    _not_blank(fig)


def test_animate_writes_a_gif_with_one_frame_per_step(model, tmp_path):
    from PIL import Image

    sim = model.simulate(0, steps=9)
    path = tmp_path / "sim.gif"
    fig = plot.animate(sim, path, model=model, dpi=40)
    assert isinstance(fig, Figure)
    with Image.open(path) as im:
        assert im.format == "GIF" and im.n_frames == 10
    scen = model.sample_scenarios(2, steps=4, seed=0)
    plot.animate(scen, tmp_path / "scen.gif", scenario=1, dpi=40)
    with Image.open(tmp_path / "scen.gif") as im:
        assert im.n_frames == 5


def test_passed_axes_are_used_and_bad_patterns_rejected(model):
    fig = Figure()
    ax = fig.add_subplot()
    assert plot.weights(model, ax=ax) is ax
    assert plot.velocity_field(model, 0, grid=4, ax=ax) is ax
    for bad in (-1, model.n_patterns_, 1.5):
        with pytest.raises(dpgp.InvalidInputError):
            plot.velocity_field(model, bad)
    with pytest.raises(dpgp.InvalidInputError, match="grid"):
        plot.velocity_field(model, 0, grid=1)
    with pytest.raises(dpgp.NotFittedError):
        plot.weights(dpgp.DPGP())
