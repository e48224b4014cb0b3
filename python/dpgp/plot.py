"""Figures of a fitted model (the paper's Figs. 3 and 4), a convergence trace, and animations.

Every function draws with matplotlib's object API on ``ax`` when given, else on a new
:class:`matplotlib.figure.Figure` that belongs to no GUI (so it works headless and in scripts
without leaking pyplot state); it returns that Axes (or Figure), which notebooks display and
``.figure.savefig(path)`` writes. Nothing here calls ``plt.show``.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import numpy as np

from ._arrays import as_path
from .exceptions import InvalidInputError
from .generate.simulation import LOW_DATA_THRESHOLD, Simulation, default_roi

if TYPE_CHECKING:
    from pathlib import Path

    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .generate.scenarios import Scenarios
    from .model.estimator import DPGP

_FIELD = "#1f4e99"  # arrows where the pattern has data
_SPARSE = "#b0b0b0"  # arrows in low-data regions


def _axes(ax: Axes | None, figsize: tuple[float, float] = (6.0, 5.0)) -> Axes:
    if ax is not None:
        return ax
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, layout="constrained").add_subplot()


def _equal(roi: tuple[float, float, float, float]) -> bool:
    """Equal axes unless the ROI is a long strip (a highway seen whole)."""
    return 0.25 <= (roi[3] - roi[2]) / (roi[1] - roi[0]) <= 4


def _spatial_axes(ax: Axes | None, roi: tuple[float, float, float, float]) -> Axes:
    """Axes for a plot of the ROI; a new figure is shaped like the ROI."""
    ratio = (roi[3] - roi[2]) / (roi[1] - roi[0])
    size = (float(np.clip(5.0 / ratio + 1.3, 3.5, 9.0)), 5.0) if _equal(roi) else (6.0, 5.0)
    return _axes(ax, size)


def _frame_roi(ax: Axes, roi: tuple[float, float, float, float]) -> None:
    x0, x1, y0, y1 = roi
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    if _equal(roi):
        ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")


def _arrows(ax: Axes, xy: np.ndarray, v: np.ndarray, cell: tuple[float, float], key: bool, **style: Any) -> Any:
    """A quiver in data units, scaled so that typical arrows (95th percentile) span at most 90%
    of a ``cell = (dx, dy)`` in each direction; with ``key``, a labelled reference arrow."""
    reach = np.maximum(np.abs(v[:, 0]) / cell[0], np.abs(v[:, 1]) / cell[1])
    scale = float(np.quantile(reach, 0.95)) / 0.9 if len(reach) else 1.0
    scale = scale if scale > 0 else 1.0
    arrows = ax.quiver(xy[:, 0], xy[:, 1], v[:, 0], v[:, 1], angles="xy", scale_units="xy", scale=scale, **style)
    speed = np.hypot(v[:, 0], v[:, 1])
    if key and len(speed) and speed.max() > 0:
        u = float(f"{np.quantile(speed, 0.95):.1g}")
        k = ax.quiverkey(arrows, 0.97, 0.97, u, f"speed {u:g}", labelpos="W", color="k", coordinates="axes",
                         fontproperties={"size": "small"})  # fmt: skip
        k.text.set_bbox({"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 1.0})
    return arrows


def _cell(roi: tuple[float, float, float, float], nx: int, ny: int) -> tuple[float, float]:
    return ((roi[1] - roi[0]) / max(nx - 1, 1), (roi[3] - roi[2]) / max(ny - 1, 1))


def _pattern(model: DPGP, k: Any) -> int:
    model._check_fitted()
    if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)) or not 0 <= k < model.n_patterns_:
        raise InvalidInputError(f"pattern must be an index 0..{model.n_patterns_ - 1}, got {k!r}")
    return int(k)


def _grid(grid: Any) -> tuple[int, int]:
    g = np.atleast_1d(np.asarray(grid))
    if g.shape == (1,):
        g = np.r_[g, g]
    if g.shape != (2,) or g.dtype.kind not in "iu" or np.any(g < 2):
        raise InvalidInputError(f"grid must be a whole number >= 2 or a pair (nx, ny), got {grid!r}")
    return int(g[0]), int(g[1])


def _colours(groups: np.ndarray) -> np.ndarray:
    """One viridis colour per group (frame), as RGBA rows."""
    from matplotlib import colormaps

    g = np.unique(groups, return_inverse=True)[1]
    return colormaps["viridis"](g / max(int(g.max()), 1))


def weights(model: DPGP, ax: Axes | None = None) -> Axes:
    """Mixture weights of the patterns in decreasing order, as bars (the paper's Fig. 3)."""
    model._check_fitted()
    ax = _axes(ax, (7.0, 3.5))
    w = np.sort(model.weights_)[::-1]
    ax.bar(np.arange(len(w)), w, color=_FIELD)
    ax.set_xlabel("motion pattern (by size)")
    ax.set_ylabel("weight")
    ax.set_title(f"{len(w)} motion patterns, α = {model.alpha_:.3g}")
    ax.set_xlim(-0.6, len(w) - 0.4)
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    return ax


def field_grid(
    model: DPGP, grid: Any = 20, roi: tuple[float, float, float, float] | None = None
) -> tuple[np.ndarray, int, int]:
    """The ``nx x ny`` grid points (row-major in y, then x) over ``roi`` (default: the model's)."""
    nx, ny = _grid(grid)
    x0, x1, y0, y1 = default_roi(model) if roi is None else roi
    gx, gy = np.meshgrid(np.linspace(x0, x1, nx), np.linspace(y0, y1, ny))
    return np.column_stack([gx.ravel(), gy.ravel()]), nx, ny


def _relative_variance(model: DPGP, var: np.ndarray) -> np.ndarray:
    """Posterior over prior variance, the larger of the two outputs: 0 at data, 1 far away."""
    return (var / np.asarray(model.params_.signal_var)).max(axis=1)


def velocity_field(
    model: DPGP,
    k: int,
    grid: Any = 20,
    ax: Axes | None = None,
    roi: tuple[float, float, float, float] | None = None,
    low_data_threshold: float = LOW_DATA_THRESHOLD,
    show_data: bool = False,
) -> Axes:
    """Pattern ``k``'s posterior mean velocity as one arrow per grid point (``grid`` = n or
    ``(nx, ny)``), over grey shading of the posterior variance relative to the prior's (dark:
    no data); arrows where it exceeds ``low_data_threshold`` are drawn pale (the paper's Fig. 4a).
    ``show_data`` adds the pattern's observed positions."""
    k = _pattern(model, k)
    roi = default_roi(model) if roi is None else roi
    q, nx, ny = field_grid(model, grid, roi)
    mean, var = model.velocity_field(k, q)
    rel = _relative_variance(model, var)
    ax = _spatial_axes(ax, roi)
    ax.imshow(
        rel.reshape(ny, nx), origin="lower", extent=roi, cmap="Greys", vmin=0.0, vmax=1.5,
        interpolation="bilinear", aspect="auto", alpha=0.6,
    )  # fmt: skip
    colors = np.where(rel > low_data_threshold, _SPARSE, _FIELD)
    _arrows(ax, q, mean, _cell(roi, nx, ny), True, color=colors, pivot="mid")
    if show_data:
        xy = model.frames_.xy[np.repeat(model.labels_ == k, model.frames_.sizes)]
        ax.scatter(xy[:, 0], xy[:, 1], s=2, c="tab:orange", alpha=0.5, label="observations")
    _frame_roi(ax, roi)
    ax.set_title(f"pattern {k} (weight {model.weights_[k]:.2f}): mean velocity", fontsize="medium")
    return ax


def frames(model: DPGP, k: int, ax: Axes | None = None, max_frames: int | None = 30) -> Axes:
    """The observed frames assigned to pattern ``k`` (the paper's Fig. 4c-d): each vehicle's
    velocity as an arrow, coloured by frame; at most ``max_frames`` frames (None: all)."""
    k = _pattern(model, k)
    members = np.flatnonzero(model.labels_ == k)
    if max_frames is not None:
        members = members[:max_frames]
    sub = model.frames_[members]
    roi = default_roi(model)
    ax = _spatial_axes(ax, roi)
    _arrows(ax, sub.xy, sub.v, _cell(roi, 20, 20), True, color=_colours(sub.frame_of_row), pivot="tail")
    _frame_roi(ax, roi)
    ax.set_title(f"pattern {k}: {len(members)} of its {int((model.labels_ == k).sum())} frames", fontsize="medium")
    return ax


def simulation(
    model: DPGP,
    frame: Any,
    k: int | None = None,
    ax: Axes | None = None,
    result: Simulation | None = None,
    steps: int = 40,
    grid: Any = 15,
    **simulate_options: Any,
) -> Axes:
    """A simulated frame (the paper's Fig. 4b): the pattern's field in the background, each
    vehicle's start (circle) and its trajectory while in the ROI, low-data steps marked ``x``.
    ``result`` draws an existing :class:`~dpgp.simulation.Simulation` instead of running one."""
    sim = result if result is not None else model.simulate(frame, pattern=k, steps=steps, **simulate_options)
    roi = default_roi(model)
    ax = _spatial_axes(ax, roi)
    q, nx, ny = field_grid(model, grid, roi)
    mean, _ = model.velocity_field(sim.pattern, q)
    _arrows(ax, q, mean, _cell(roi, nx, ny), False, color="0.75", pivot="mid")
    for j in range(sim.n_vehicles):
        inside = sim.in_roi[:, j]
        last = min(int(inside.sum()), sim.steps)  # include the first position outside
        path = sim.positions[: last + 1, j]
        ax.plot(path[:, 0], path[:, 1], "-", color="tab:blue", lw=1.2)
    ax.plot(sim.positions[0, :, 0], sim.positions[0, :, 1], "o", color="tab:red", ms=4, label="start")
    low = sim.low_data & sim.in_roi
    if low.any():
        ax.plot(sim.positions[..., 0][low], sim.positions[..., 1][low], "x", color="k", ms=4, label="low data")
    _frame_roi(ax, roi)
    ax.set_title(f"simulation through pattern {sim.pattern}: {sim.steps} {sim.method} steps of {sim.dt:g} s")
    ax.legend(loc="upper right", fontsize="small")
    return ax


def trace(model: DPGP) -> Figure:
    """Number of patterns, α and the log joint density over the sweeps (convergence check)."""
    model._check_fitted()
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 6.0), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    h = model.history_
    sweeps = np.arange(1, len(h.get("n_patterns", [])) + 1)
    for ax, key, label in zip(axes, ("n_patterns", "alpha", "log_joint"), ("K", "α", "log joint")):
        ax.plot(sweeps, h.get(key, []), "-", marker="." if len(sweeps) < 60 else None)
        ax.set_ylabel(label)
    from matplotlib.ticker import MaxNLocator

    axes[0].yaxis.set_major_locator(MaxNLocator(integer=True))
    axes[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    axes[-1].set_xlabel("sweep")
    axes[0].set_title("Gibbs trace")
    return fig


def animate(
    result: Simulation | Scenarios,
    path: str | os.PathLike,
    model: DPGP | None = None,
    scenario: int = 0,
    fps: float = 8.0,
    dpi: int = 80,
    tail: int = 6,
) -> Figure:
    """Write a simulation (or scenario ``scenario`` of generated scenarios) as a GIF at ``path``:
    vehicles as dots with a short ``tail``, over the pattern's field when ``model`` is given."""
    from matplotlib.animation import PillowWriter

    sim = result if isinstance(result, Simulation) else result[scenario]
    roi = tuple(sim.roi)
    if not np.all(np.isfinite(roi)):
        lo, hi = sim.positions.reshape(-1, 2).min(axis=0), sim.positions.reshape(-1, 2).max(axis=0)
        roi = (lo[0] - 1, hi[0] + 1, lo[1] - 1, hi[1] + 1)
    ax = _spatial_axes(None, roi)  # type: ignore[arg-type]
    fig: Figure = ax.figure  # type: ignore[assignment]
    if model is not None:
        q, nx, ny = field_grid(model, 15, roi)  # type: ignore[arg-type]
        mean, _ = model.velocity_field(sim.pattern, q)
        _arrows(ax, q, mean, _cell(roi, nx, ny), False, color="0.8", pivot="mid")  # type: ignore[arg-type]
    _frame_roi(ax, roi)  # type: ignore[arg-type]
    tails = [ax.plot([], [], "-", color="tab:blue", lw=1, alpha=0.6)[0] for _ in range(sim.n_vehicles)]
    (dots,) = ax.plot([], [], "o", color="tab:red", ms=5)
    label = ax.set_title("")
    writer = PillowWriter(fps=fps)  # type: ignore[arg-type]
    with writer.saving(fig, as_path(path), dpi):
        for t in range(sim.steps + 1):
            inside = sim.in_roi[t]
            dots.set_data(sim.positions[t, inside, 0], sim.positions[t, inside, 1])
            for j, line in enumerate(tails):
                seg = slice(max(0, t - tail), t + 1)
                keep = sim.in_roi[seg, j]
                line.set_data(sim.positions[seg, j, 0][keep], sim.positions[seg, j, 1][keep])
            label.set_text(f"t = {sim.t[t]:.1f} s, {int(inside.sum())} vehicles")
            writer.grab_frame()
    return fig


# --- many chains (dpgp.fit_chains) --------------------------------------------------------------
#: The figures :func:`write_figures` writes (``dpgp plot --kind``).
FIGURES = ("weights", "trace", "field", "frames", "simulation", "animation")


def write_figures(
    model: DPGP,
    directory: str | os.PathLike,
    kinds: Any = FIGURES,
    n_patterns: int = 3,
    frame: int | None = None,
    steps: int = 40,
    dpi: int = 100,
) -> list[Path]:
    """Write figures of a fitted ``model`` into ``directory`` (created if needed) as PNG, the
    animation as GIF; returns the paths written. ``kinds``: some of :data:`FIGURES`
    (``weights.png``, ``trace.png``, ``field_<k>.png`` and ``frames_<k>.png`` for the
    ``n_patterns`` largest patterns, ``simulation.png`` and ``simulation.gif`` of training frame
    ``frame`` — default one of the largest pattern — rolled ``steps`` steps)."""
    from pathlib import Path

    unknown = sorted(set(kinds) - set(FIGURES))
    if unknown:
        raise InvalidInputError(f"unknown figure kinds {unknown}; choose among {FIGURES}")
    out = Path(as_path(directory))
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []

    def save(fig: Any, name: str) -> None:
        path = out / name
        fig.savefig(path, dpi=dpi)
        written.append(path)

    if frame is None:
        frame = int(np.flatnonzero(model.labels_ == 0)[0])  # a frame of the largest pattern
    if "weights" in kinds:
        save(weights(model).figure, "weights.png")
    if "trace" in kinds:
        save(trace(model), "trace.png")
    for k in range(min(n_patterns, model.n_patterns_)):
        if "field" in kinds:
            save(velocity_field(model, k).figure, f"field_{k}.png")
        if "frames" in kinds:
            save(frames(model, k).figure, f"frames_{k}.png")
    if "simulation" in kinds or "animation" in kinds:
        sim = model.simulate(frame, steps=steps)
        if "simulation" in kinds:
            save(simulation(model, frame, result=sim).figure, "simulation.png")
        if "animation" in kinds:
            path = out / "simulation.gif"
            animate(sim, path, model=model)
            written.append(path)
    return written


def _stop_note(chains: Any) -> str:
    if chains.stop_reason_.startswith(("converged", "not converged")):
        return chains.stop_reason_
    return f"no stopping rule: {chains.stop_reason_}"


def transitions(model: DPGP, top: int = 12, bins: int = 30) -> Figure:
    """Pattern dynamics of a fit (issue 20): a heatmap of the transition probabilities between
    consecutive frames' patterns (the ``top`` largest patterns, with the chance of a recording's
    exit as a last column) beside histograms of their dwell times (censored runs included)."""
    tr = model.transitions_
    from matplotlib.figure import Figure

    k = min(top, tr.n_patterns)
    order = np.argsort(-np.bincount(model.labels_, minlength=tr.n_patterns), kind="stable")[:k]
    fig = Figure(figsize=(11.0, 4.8), layout="constrained")
    heat, hist = fig.subplots(1, 2, width_ratios=(1.1, 1.0))
    probs = np.c_[tr.probs[np.ix_(order, order)], tr.exit_probs[order]]
    im = heat.imshow(probs, vmin=0, vmax=1, cmap="viridis")
    fig.colorbar(im, ax=heat, label="P(next frame's pattern)")
    heat.set_xticks(range(k + 1), [str(j) for j in order] + ["exit"])
    heat.set_yticks(range(k), [str(j) for j in order])
    heat.set_xlabel("next pattern")
    heat.set_ylabel("pattern")
    heat.set_title(f"transitions (consecutive frames keep their pattern {100 * tr.share_same:.0f}%)", fontsize="small")
    all_dwell = tr.dwell()
    edges = np.linspace(0, all_dwell.max() if len(all_dwell) else 1.0, bins + 1)
    for j in order[: min(k, 6)]:
        d = tr.dwell(int(j))
        hist.hist(d, bins=edges, histtype="step", label=f"{j} (mean {d.mean():.1f} s)" if len(d) else str(j))
    hist.set_yscale("log")
    hist.set_xlabel("dwell time (s)")
    hist.set_ylabel("runs")
    hist.set_title("dwell times of the largest patterns", fontsize="small")
    hist.legend(fontsize="small")
    return fig


def phases(model: DPGP, n_phases: Any = 2, bins: int = 30) -> Figure:
    """Phases of a fit (issue 20, :meth:`dpgp.DPGP.phases`): each frame's pattern over time (the
    largest patterns on the lowest rows) on bands coloured by its phase, each phase's share of the
    patterns, and the phases' dwell-time histograms. ``n_phases``: a number of phases,
    ``"auto"``, or phases already fitted (``model.phases(4, cycle=True)``)."""
    from matplotlib.figure import Figure

    from .data.timeorder import time_order
    from .evaluate.phases import Phases

    ph = n_phases if isinstance(n_phases, Phases) else model.phases(n_phases)
    order = time_order(model.frames_)
    t = order.time - order.time.min()
    rank = np.empty(model.n_patterns_, dtype=np.int64)
    rank[np.argsort(-np.bincount(model.labels_, minlength=model.n_patterns_), kind="stable")] = np.arange(
        model.n_patterns_
    )
    fig = Figure(figsize=(11.0, 6.4), layout="constrained")
    grid = fig.add_gridspec(2, 2, height_ratios=(1.2, 1.0))
    top = fig.add_subplot(grid[0, :])
    share, hist = fig.add_subplot(grid[1, 0]), fig.add_subplot(grid[1, 1])
    colors = [f"C{p % 10}" for p in range(ph.n_phases)]
    for p, first, n, _censored in ph.transitions.runs:
        top.axvspan(t[first], t[first] + n * order.dt, color=colors[p], alpha=0.18, lw=0)
    top.scatter(t, rank[model.labels_], s=2, c="k")
    top.set_xlabel("time (s)")
    top.set_ylabel("pattern (by size)")
    top.set_title(
        f"{ph.n_phases} phases: consecutive frames keep their phase {100 * ph.transitions.share_same:.0f}%, "
        f"their pattern {100 * model.transitions_.share_same:.0f}%",
        fontsize="small",
    )
    k = min(12, model.n_patterns_)
    big = np.argsort(rank)[:k]
    left = np.zeros(k)
    for p in range(ph.n_phases):
        share.bar(range(k), ph.emission[p, big], bottom=left, color=colors[p], label=f"phase {p}")
        left += ph.emission[p, big]
    share.set_xticks(range(k), [str(j) for j in big])
    share.set_xlabel("pattern")
    share.set_ylabel("P(pattern | phase), stacked")
    share.legend(fontsize="small")
    d_all = ph.transitions.dwell()
    edges = np.linspace(0, d_all.max() if len(d_all) else 1.0, bins + 1)
    for p in range(ph.n_phases):
        d = ph.transitions.dwell(p)
        hist.hist(
            d,
            bins=edges.tolist(),
            histtype="step",
            color=colors[p],
            label=f"phase {p} (mean {d.mean():.1f} s)" if len(d) else f"phase {p}",
        )
    hist.set_xlabel("dwell time (s)")
    hist.set_ylabel("runs")
    hist.legend(fontsize="small")
    return fig


def stop_lines(model: DPGP, phases: Any = 2, ax: Axes | None = None, max_points: int = 20000) -> Axes:
    """The red signals' stop lines that long scenarios by ``phases`` stop vehicles at
    (:meth:`dpgp.DPGP.stop_lines`; a number of phases, ``"auto"``, or phases already fitted) over
    the recorded positions (grey; standing vehicles darker): each line a bar across its lane with a
    tick in its traffic's direction, coloured by the signal phase in which it is red (the stages
    with the same red lines, :meth:`dpgp.DPGP.signal_phases`); never red: dashed grey."""
    from .generate.motion import motion_model
    from .generate.stop_lines import STAND_SHARE

    lines = model.stop_lines(phases)
    roi = default_roi(model)
    ax = _spatial_axes(ax, roi)
    xy, v = np.asarray(model.frames_.xy), np.asarray(model.frames_.v)
    keep = np.random.default_rng(0).permutation(len(xy))[:max_points]
    standing = np.hypot(*v[keep].T) < STAND_SHARE * np.quantile(np.hypot(*v.T), 0.9) if len(v) else np.zeros(0, bool)
    for mask, grey in ((~standing, "#d0d0d0"), (standing, "#808080")):
        pts = xy[keep][mask]
        ax.scatter(pts[:, 0], pts[:, 1], s=1, c=grey, lw=0)
    groups = lines.signal_groups()

    lateral = float(motion_model(model._fitted()).lateral)
    half = lateral if np.isfinite(lateral) and lateral > 0 else 0.02 * (roi[1] - roi[0])
    seen: set[str] = set()
    for i in range(len(lines)):
        e = lines.heading[i]
        n = np.array([-e[1], e[0]])
        red = np.flatnonzero(lines.red[:, i])
        colour, style = (f"C{int(groups[red[0]]) % 10}", "-") if len(red) else ("#808080", "--")
        label = f"red in phases {red.tolist()}" if len(red) else "never red"
        bar = np.array([lines.at[i] - half * n, lines.at[i] + half * n])
        ax.plot(*bar.T, style, color=colour, lw=2.5, gid="stop line", label=None if label in seen else label)
        ax.plot(*np.array([lines.at[i], lines.at[i] + half * e]).T, "-", color=colour, lw=1.2)
        seen.add(label)
    _frame_roi(ax, roi)
    ax.set_title(f"{len(lines)} stop lines; signal phases by their red lines: {groups.tolist()}", fontsize="small")
    if len(lines):
        ax.legend(fontsize="small", loc="upper right")
    return ax


def chain_trace(chains: Any) -> Figure:
    """Log joint, K and α per sweep, one line per chain, the burn-in shaded; the title says
    why the run stopped."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    fig = Figure(figsize=(8.0, 6.5), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    sweeps = np.arange(1, chains.n_sweeps + 1)
    for ax, key, label in zip(axes, ("log_joint", "n_patterns", "alpha"), ("log joint", "K", "α")):
        for name, y in zip(chains.names, chains.traces[key]):
            ax.plot(sweeps, y, "-", lw=1, label=name)
        if chains.burn_in:
            ax.axvspan(0.5, chains.burn_in + 0.5, color="0.9", zorder=0)
        ax.set_ylabel(label)
    axes[0].legend(loc="lower right", fontsize="small", ncols=min(chains.n_chains, 4))
    axes[1].yaxis.set_major_locator(MaxNLocator(integer=True))
    axes[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    axes[-1].set_xlabel(f"sweep (burn-in of {chains.burn_in} shaded)")
    note = _stop_note(chains)
    head, _, detail = note.partition(" (")  # the verdict; the failing diagnostics on a second line
    fig.suptitle(f"{chains.n_chains} chains: {head}" + (f"\n({detail}" if detail else ""), fontsize="small")
    return fig


def similarity(chains: Any, loss: str = "vi", max_items: int = 1500, ax: Axes | None = None) -> Axes:
    """The posterior similarity matrix, frames ordered by the point estimate's patterns (each
    pattern's most typical frames first), pattern borders drawn; above ``max_items`` frames an
    evenly spaced subset of that order is shown."""
    est = chains.point_estimate(loss)
    labels = est.labels
    n = len(labels)
    # Within a pattern, frames by their mean similarity to the pattern, from a few sample rows.
    rng = np.random.default_rng(0)
    typical = np.zeros(n)
    for k in range(est.n_clusters):
        members = np.flatnonzero(labels == k)
        probe = rng.choice(members, size=min(len(members), 50), replace=False)
        typical[members] = chains.similarity(rows=probe)[:, members].mean(axis=0)
    order = np.lexsort((-typical, labels))
    if n > max_items:
        order = order[np.linspace(0, n - 1, max_items).astype(int)]
    sim = chains.similarity(rows=order)[:, order]
    ax = _axes(ax, (6.0, 5.2))
    image = ax.imshow(sim, vmin=0.0, vmax=1.0, cmap="viridis", interpolation="nearest")
    ax.figure.colorbar(image, ax=ax, label="P(same pattern)")
    edges = np.flatnonzero(np.diff(labels[order])) + 0.5
    for e in edges:
        ax.axhline(e, color="w", lw=0.5)
        ax.axvline(e, color="w", lw=0.5)
    shown = "" if n <= max_items else f" ({max_items} of {n} shown)"
    ax.set_title(f"posterior similarity, by the {loss.upper()} point estimate ({est.n_clusters} patterns){shown}",
                 fontsize="medium")  # fmt: skip
    ax.set_xlabel("frame")
    ax.set_ylabel("frame")
    return ax


def rhat(chains: Any, ax: Axes | None = None, points: int = 30) -> Axes:
    """Rank-normalised split-R̂ of the log joint, K and α had the run stopped after each number
    of sweeps (the second half kept), with the stopping threshold."""
    ns, values = chains.rhat_by_sweeps(points)
    ax = _axes(ax, (7.0, 4.0))
    for key, label in (("log_joint", "log joint"), ("n_patterns", "K"), ("alpha", "α")):
        flat = len(ns) and np.all(np.isnan(values[key]))  # never varies: R̂ is undefined
        ax.plot(ns, values[key], ".-", label=label + (" (constant, no R̂)" if flat else ""))
    threshold = chains.thresholds.get("rhat", 1.01)
    ax.axhline(threshold, color="k", ls="--", lw=1, label=f"threshold {threshold:g}")
    ax.set_xlabel("sweeps per chain")
    ax.set_ylabel("split-R̂ (rank-normalised)")
    ax.set_title(_stop_note(chains), fontsize="small", wrap=True)
    ax.legend(fontsize="small")
    return ax


__all__ = [
    "weights", "velocity_field", "frames", "simulation", "trace", "animate", "field_grid",
    "chain_trace", "similarity", "rhat", "write_figures", "FIGURES", "transitions", "phases", "stop_lines",
]  # fmt: skip
