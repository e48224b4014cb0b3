"""Held-out evaluation of a fitted model against baselines: is the model worth fitting?

Protocol: a split in time (:func:`split_in_time`, first 70% of the frames to train, the last
30% to test), so that frames that are neighbours in time do not leak between the sets.

**Log density** of the test velocities given their positions, in nats per vehicle (the sum over
test frames divided by the number of test vehicles; higher is better):

- ``dpgp``: ``DPGP.score_samples(test, positions=False, average=True)``, the mixture's
  posterior predictive density of each frame's velocities, jointly over its vehicles, averaged
  over the fit's kept posterior draws after burn-in (:mod:`dpgp.posterior`);
- ``single_gp``: one GP for all training frames (K = 1, the same kernel family and the data's
  signal variances and means), on up to :data:`SINGLE_GP_POINTS` training observations (whole
  frames spread evenly in time); σ_n² and a common length scale chosen by held-out score inside
  those frames, the rule of ``noise_var="auto"`` (:mod:`dpgp.defaults`); each test frame scored
  jointly given them. (Maximising its marginal likelihood instead was tried and rejected: pooled
  over patterns, it prefers white noise with tiny length scales and then scores below the
  position-blind baseline on every real data set);
- ``position_blind``: an independent Gaussian per velocity component, fitted to the training
  velocities (maximum likelihood);
- ``constant_velocity``: each vehicle's velocity a Gaussian around its previous velocity
  (``Frames.prev_v``) with a full 2×2 spread fitted by maximum likelihood on the training frames'
  steps, and the position-blind Gaussian for vehicles without a previous velocity
  (:mod:`.baselines`, which says why). It needs training and test frames made by
  :func:`dpgp.make_frames` from tracks; without them (frames read from a framed table, older
  shards) its ``log_density`` is NaN and ``Evaluation.notes`` says why.

The table's ``dpgp_margin`` is the model's score minus each baseline's, nats per vehicle
(``Evaluation.margins``: over ``position_blind`` and ``constant_velocity``). A model that
conditions on the previous step (``inputs="position+heading"``) should beat both.

**Rollouts**, given the raw tracks: from each test frame, the model moves the vehicles with its
mean field (:meth:`DPGP.simulate`, forward Euler at the frames' time step, through the frame's
MAP pattern); ``constant_velocity`` moves each vehicle with its velocity in that frame. Both stop
where they leave the ROI, as the core's rollouts do (:func:`constant_velocity_rollout`: compared
with a baseline that drove on, the stop alone was 0.78x constant velocity at 4 s on Peachtree's
small ROI, a lead that owes nothing to the field). Against
where the vehicles really went (the tracks resampled to the same grid), at each horizon ``h``
(seconds): FDE is the distance at ``h``, ADE the mean distance over the steps up to ``h``,
averaged over the vehicles still in the ROI at ``h``. In the data's length units.

**Realism**, given the raw tracks: the WOSAC-style score of :mod:`dpgp.realism` for as many
generated scenarios of :data:`dpgp.realism.SCENARIO_SECONDS` (4 s) as test frames, against the
test period's recorded windows, with the training period's windows and the position-blind
generator as references (:func:`dpgp.realism.model_realism`); :func:`realism` is
:func:`dpgp.realism.realism`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .._constants import TRAIN_FRACTION
from .._validate import inside_roi
from ..data.frames import Frames
from ..exceptions import InvalidInputError, ShapeError
from ..gp.defaults import NOISE_GRID, refine_grid, vehicle_spacing
from ..gp.exact import GPParams, log_predictive_frames
from .baselines import ConstantVelocity, constant_velocity_scores, position_blind_scores
from .realism_checks import Realism, model_realism, realism

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure

SINGLE_GP_POINTS = 600  # training observations the single GP is fitted to and conditions on
LENGTH_GRID = (1.0, 2.0, 4.0)  # single GP: length scales tried, times the vehicle spacing
METHODS = ("dpgp", "single_gp", "position_blind", "constant_velocity")


def split_in_time(frames: Frames, train_fraction: float = TRAIN_FRACTION) -> tuple[Frames, Frames]:
    """The first ``train_fraction`` of the frames (in their order, which is time for
    :func:`dpgp.make_frames` and :func:`dpgp.read_frames`) and the rest."""
    if not (isinstance(train_fraction, (int, float)) and 0 < train_fraction < 1):
        raise InvalidInputError(f"train_fraction must be between 0 and 1, got {train_fraction!r}")
    n = len(frames)
    cut = int(round(n * train_fraction))
    if cut < 1 or cut >= n:
        raise ShapeError(
            f"{n} frames cannot be split {train_fraction:g} / {1 - train_fraction:g}: each side needs a frame"
        )
    return frames[:cut], frames[cut:]


@dataclass(frozen=True, eq=False)
class Evaluation:
    """``table``: one row per method (``dpgp``, ``single_gp``, ``position_blind``,
    ``constant_velocity``), columns ``log_density`` (nats per vehicle), ``log_density_per_frame``
    (nats per test frame, the mean of ``frame_scores``), ``dpgp_margin`` (the ``dpgp``
    log density minus this method's, nats per vehicle; NaN on the ``dpgp`` row) and
    ``ade_{h}s`` / ``fde_{h}s`` per horizon (NaN where a method does not apply or there are no
    tracks). ``frame_scores``: per test frame, the log density of each method scored and the
    vehicle count (no ``constant_velocity`` column when it was not scored). ``rollouts``: per
    horizon, ADE/FDE of each method and the vehicles counted. ``realism``: the
    :class:`dpgp.realism.Realism` of generated scenarios (when tracks were given; its
    meta-scores are also the table's ``realism`` column). ``states_averaged``: the posterior
    states the ``dpgp`` density is averaged over. ``notes``: why a baseline was not scored."""

    table: pd.DataFrame
    frame_scores: pd.DataFrame
    rollouts: pd.DataFrame | None
    units: dict[str, Any] = field(default_factory=dict)
    realism: Realism | None = None
    states_averaged: int = 1  # posterior states the dpgp density averages over
    notes: tuple[str, ...] = ()

    @property
    def margins(self) -> dict[str, float | None]:
        """The model's held-out margin over ``position_blind`` and over ``constant_velocity``, nats
        per test vehicle (``dpgp`` minus the baseline); ``None`` for a baseline not scored."""
        out: dict[str, float | None] = {}
        for m in ("position_blind", "constant_velocity"):
            x = float(self.table.loc[m, "dpgp_margin"])
            out[m] = None if np.isnan(x) else x
        return out

    def plot(self) -> Figure:
        """Log density per vehicle by method, and ADE/FDE against horizon (when tracks were given)."""
        from matplotlib.figure import Figure

        panels = 2 if self.rollouts is not None and len(self.rollouts) else 1
        fig = Figure(figsize=(5.0 * panels, 4.0), layout="constrained")
        axes = fig.subplots(1, panels, squeeze=False)[0]
        scores = self.table["log_density"].dropna()
        colours = dict(zip(METHODS, ("#1f4e99", "#7a9cc6", "#b0b0b0", "#d9a441")))
        bars = axes[0].bar(scores.index, scores.to_numpy(), color=[colours[m] for m in scores.index])
        axes[0].bar_label(bars, fmt="%.2f")
        axes[0].set_ylabel("held-out log density (nats per vehicle)")
        margins = ", ".join(f"{m}: {x:+.2f}" for m, x in self.margins.items() if x is not None)
        axes[0].set_title(f"velocities given positions\ndpgp's margin over {margins}", fontsize="medium")
        axes[0].tick_params(axis="x", labelrotation=20)
        if panels == 2:
            ax, r = axes[1], self.rollouts
            for method, colour in (("dpgp", "#1f4e99"), ("constant_velocity", "#b0b0b0")):
                ax.plot(r["horizon"], r[f"{method}_ade"], "o-", color=colour, label=f"{method} ADE")  # type: ignore[index]
                ax.plot(r["horizon"], r[f"{method}_fde"], "s--", color=colour, label=f"{method} FDE")  # type: ignore[index]
            ax.set_xlabel("horizon (s)")
            ax.set_ylabel(f"displacement error ({self.units.get('length', 'data units')})")
            ax.set_title("rollouts against the tracks")
            ax.legend()
        return fig

    def summary(self) -> str:
        """The table, the model's two margins and the notes, as text (the repr, and what
        ``dpgp evaluate`` prints)."""
        lines = [self.table.to_string(float_format=lambda x: f"{x:.3f}")]
        margins = "; ".join(f"over {m} {'not scored' if x is None else f'{x:+.3f}'}" for m, x in self.margins.items())
        lines.append(f"dpgp's margin per test vehicle (nats): {margins}")
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"Evaluation(\n{self.summary()}\n)"


def evaluate(
    model: Any,
    test_frames: Frames,
    tracks: Any = None,
    horizons: Any = (1, 2, 4),
    average: bool = True,
    *,
    agent: str | None = None,
    seed: int | None = 0,
) -> Evaluation:
    """Score ``model`` (a fitted :class:`~dpgp.DPGP`) and the baselines on ``test_frames``; see
    the module docstring. ``tracks``: the raw tracks table the frames were made from (for
    rollouts and realism); the frames must then carry ``summary`` (``make_frames`` sets it).
    ``average``: score the model by its posterior predictive over the kept draws
    (:mod:`dpgp.posterior`; ``states_averaged`` says over how many states), else by its final
    state. ``agent`` (``"vehicle"``/``"pedestrian"``, default: from the tracks' format) and
    ``seed``: the realism score's collision rule and generated scenarios."""
    import pandas as pd

    model._check_fitted()
    if not isinstance(test_frames, Frames):
        raise ShapeError(f"test_frames must be dpgp.Frames, got {type(test_frames).__name__}")
    horizons = _horizons(horizons)
    if tracks is not None and getattr(test_frames, "summary", None) is None:
        raise InvalidInputError(
            "rollouts need test frames made by dpgp.make_frames from these tracks (their time step and units); "
            "these frames carry no framing summary"
        )
    train = model.frames_
    sizes = test_frames.sizes
    scores = {
        "dpgp": np.asarray(model.score_samples(test_frames, positions=False, average=average), dtype=np.float64),
        "single_gp": SingleGP.fit(train).score_frames(test_frames),
        "position_blind": position_blind_scores(train, test_frames),
    }
    cv, note = _constant_velocity(train, test_frames)
    if cv is not None:
        scores["constant_velocity"] = cv
    frame_scores = pd.DataFrame({"frame": test_frames.ids, "n_vehicles": sizes, **scores})
    table = pd.DataFrame(index=pd.Index(METHODS, name="method"))
    table["log_density"] = [scores[m].sum() / sizes.sum() if m in scores else np.nan for m in METHODS]
    table["log_density_per_frame"] = [scores[m].mean() if m in scores else np.nan for m in METHODS]
    table["dpgp_margin"] = table.loc["dpgp", "log_density"] - table["log_density"]
    table.loc["dpgp", "dpgp_margin"] = np.nan
    rollouts = real = None
    if tracks is not None:
        real = model_realism(model, test_frames, tracks, agent=agent, seed=seed)
        table.loc["dpgp", "realism"] = real.scores.loc["meta", "generated"]
        table.loc["position_blind", "realism"] = real.scores.loc["meta", "blind"]
        rollouts = rollout_errors(model, test_frames, tracks, horizons)
        for _, row in rollouts.iterrows():
            h = f"{row['horizon']:g}s"
            for m in ("dpgp", "constant_velocity"):
                table.loc[m, f"ade_{h}"] = row[f"{m}_ade"]
                table.loc[m, f"fde_{h}"] = row[f"{m}_fde"]
    table["n_test_frames"] = len(test_frames)
    table["n_test_vehicles"] = int(sizes.sum())
    from ..gp.draws import used

    states = 1 + (len(used(getattr(model, "draws_", None), getattr(model, "n_iter_", 0) or 0)) if average else 0)
    return Evaluation(
        table, frame_scores, rollouts, _units(test_frames), realism=real, states_averaged=states,
        notes=() if note is None else (note,),
    )  # fmt: skip


def _constant_velocity(train: Frames, test: Frames) -> tuple[np.ndarray | None, str | None]:
    """The ``constant_velocity`` frame scores, or None and why they are missing (frames without
    previous velocities, or a baseline that cannot be fitted on these training frames)."""
    if getattr(test, "prev_v", None) is None:
        return None, (
            "constant_velocity not scored: the test frames carry no previous velocities (prev_v); "
            "frame them with dpgp.make_frames from tracks"
        )
    if getattr(train, "prev_v", None) is None:
        return None, (
            "constant_velocity not scored: the model's training frames carry no previous velocities (prev_v); "
            "fit it on frames made by dpgp.make_frames from tracks"
        )
    try:
        return ConstantVelocity.fit(train).score_frames(test), None
    except InvalidInputError as e:
        return None, f"constant_velocity not scored: {e}"


# --- the single GP baseline (the closed-form ones: .baselines) -------------------------------
def _spread_frames(frames: Frames, max_points: int) -> Frames:
    """Whole frames spread evenly over the sequence, up to ``max_points`` observations."""
    if frames.n_points <= max_points:
        return frames
    n = max(1, int(len(frames) * max_points / frames.n_points))
    idx = np.unique(np.linspace(0, len(frames) - 1, n).round().astype(int))
    return frames[idx]


@dataclass(frozen=True)
class SingleGP:
    """One GP for all frames (K = 1): the ``single_gp`` baseline."""

    params: GPParams
    train_xy: np.ndarray
    train_v: np.ndarray

    @classmethod
    def fit(cls, train: Frames) -> SingleGP:
        """Signal variances and means of the training velocities; noise variances (the same
        fraction ρ of each component's variance) and a common length scale chosen as dpgp's
        ``noise_var="auto"`` is, by held-out score inside the training frames (their first 70%
        scoring the rest) over ρ in :data:`~dpgp.defaults.NOISE_GRID` and :data:`LENGTH_GRID`
        times the vehicle spacing."""
        var, mu = tuple(train.v.var(axis=0)), tuple(train.v.mean(axis=0))
        sub = _spread_frames(train, SINGLE_GP_POINTS)
        spacing = vehicle_spacing(train)
        grid = np.asarray(NOISE_GRID)
        if len(sub) >= 4:
            cut = int(round(TRAIN_FRACTION * len(sub)))
            fit_part, check = sub[:cut], sub[cut:]
            scores = np.array([[
                cls(GPParams((w * spacing, w * spacing), var, _times(rho, var), mu), fit_part.xy, fit_part.v).score_frames(check).sum()
                for rho in grid] for w in LENGTH_GRID])  # fmt: skip
            i, j = np.unravel_index(np.argmax(scores), scores.shape)
            w, rho = LENGTH_GRID[i] * spacing, refine_grid(grid, scores[i])
        else:
            w, rho = spacing, float(grid[len(grid) // 2])
        return cls(GPParams((w, w), var, _times(rho, var), mu), sub.xy, sub.v)

    def score_frames(self, test: Frames) -> np.ndarray:
        """log N(V_f ; posterior mean, posterior covariance + σ_n² I) per test frame, jointly over
        its vehicles and summed over the two components (the core's exact GP, one factorisation)."""
        return log_predictive_frames(self.train_xy, self.train_v, test.xy, test.v, test.offsets, self.params)


def _times(rho: float, var: tuple[float, float]) -> tuple[float, float]:
    return (float(rho * var[0]), float(rho * var[1]))


# --- rollouts ----------------------------------------------------------------------------------
def rollout_errors(model: Any, test: Frames, tracks: Any, horizons: tuple[float, ...]) -> pd.DataFrame:
    """ADE/FDE per horizon for the model's mean rollouts and for constant velocity; see the
    module docstring. One row per horizon: ``horizon, steps, n_vehicles, dpgp_ade, dpgp_fde,
    constant_velocity_ade, constant_velocity_fde``."""
    import pandas as pd

    from ..data.framing import resample_tracks
    from ..generate.simulation import default_dt, default_roi

    summary = getattr(test, "summary", None)
    if summary is None:
        raise InvalidInputError(
            "rollouts need test frames made by dpgp.make_frames from these tracks (their time step and units); "
            "these frames carry no framing summary"
        )
    dt = float(summary.dt)
    roi = default_roi(model)
    if abs(default_dt(model) - dt) > 1e-9:
        raise InvalidInputError(
            f"the model was fitted at dt = {default_dt(model):g} s, the test frames are at {dt:g} s"
        )
    steps = [int(round(h / dt)) for h in horizons]
    if min(steps) < 1:
        raise InvalidInputError(f"every horizon must be at least one time step ({dt:g} s), got {horizons}")
    truth = _truth_lookup(resample_tracks(tracks, dt=dt, units=summary.units), dt)
    patterns = model.predict(test)
    n_max = max(steps)
    errors: dict[str, list[np.ndarray]] = {
        m: [] for m in ("dpgp", "constant_velocity")
    }  # (l, n_max) distance per frame
    alive_at = []  # (l, n_max) true position known and inside the ROI
    for i, f in enumerate(test):
        times = float(test.ids[i]) if np.ndim(test.ids[i]) == 0 else float(test.ids[i][-1])
        true = _true_positions(truth, f.xy, times, n_max, dt)
        sim = model.simulate(f, pattern=int(patterns[i]), steps=n_max, dt=dt, roi=roi, low_data_threshold=None)
        cv = constant_velocity_rollout(f.xy, f.v, n_max, dt, roi)
        for m, pred in (("dpgp", sim.positions), ("constant_velocity", cv)):
            errors[m].append(np.linalg.norm(pred[1:] - true[1:], axis=-1).T)
        inside = np.isfinite(true[1:, :, 0]) & inside_roi(true[1:], roi)
        alive_at.append(inside.T)
    alive = np.concatenate(alive_at) if alive_at else np.zeros((0, n_max), bool)
    rows = []
    for h, s in zip(horizons, steps):
        counted = alive[:, s - 1]
        row = {"horizon": h, "steps": s, "n_vehicles": int(counted.sum())}
        for m, errs in errors.items():
            e = np.concatenate(errs)[counted, :s] if counted.any() else np.zeros((0, s))
            known = np.isfinite(e)
            row[f"{m}_ade"] = float(np.mean(np.where(known, e, 0).sum(1) / known.sum(1))) if len(e) else np.nan
            row[f"{m}_fde"] = float(np.mean(e[:, -1])) if len(e) else np.nan
        rows.append(row)
    return pd.DataFrame(rows)


def constant_velocity_rollout(xy: np.ndarray, v: np.ndarray, steps: int, dt: float, roi: Any) -> np.ndarray:
    """(steps + 1, l, 2): each vehicle moving with its own velocity by forward Euler, and, like the
    core's rollouts, standing from the first position outside ``roi`` on (a vehicle that starts
    outside never moves)."""
    out = np.empty((steps + 1, len(xy), 2))
    out[0] = xy
    moving = inside_roi(xy, roi)
    for t in range(1, steps + 1):
        out[t] = np.where(moving[:, None], out[t - 1] + dt * v, out[t - 1])
        moving &= inside_roi(out[t], roi)
    return out


def _truth_lookup(resampled: Any, dt: float) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Grid step -> (track, x, y) of every resampled vehicle-time at that step."""
    k = np.rint(resampled["t"].to_numpy() / dt).astype(np.int64)
    order = np.argsort(k, kind="stable")
    k = k[order]
    tr = resampled["track"].to_numpy()[order]
    xy = np.column_stack([resampled["x"].to_numpy()[order], resampled["y"].to_numpy()[order]])
    starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
    ends = np.r_[starts[1:], len(k)]
    return {int(k[a]): (tr[a:b], xy[a:b]) for a, b in zip(starts, ends)}  # type: ignore[misc]


def _true_positions(truth: dict, xy0: np.ndarray, t0: float, n_steps: int, dt: float) -> np.ndarray:
    """(n_steps + 1, l, 2) true positions of the frame's vehicles (NaN where the track has
    ended), each vehicle identified by its position at ``t0``."""
    k0 = int(round(t0 / dt))
    out = np.full((n_steps + 1, len(xy0), 2), np.nan)
    tr0, p0 = truth.get(k0, (np.zeros(0, np.int64), np.zeros((0, 2))))
    if len(p0) == 0:
        return out
    d = np.linalg.norm(p0[None, :, :] - xy0[:, None, :], axis=-1)
    j = d.argmin(axis=1)
    matched = d[np.arange(len(xy0)), j] <= 1e-6 * max(1.0, float(np.abs(xy0).max()))
    ids = np.where(matched, tr0[j], -1)
    for s in range(n_steps + 1):
        tr, p = truth.get(k0 + s, (None, None))
        if tr is None:
            continue
        where = {int(t): r for r, t in enumerate(tr)}
        for v, track in enumerate(ids):
            r = where.get(int(track)) if track >= 0 else None
            if r is not None:
                out[s, v] = p[r]
    return out


def _horizons(horizons: Any) -> tuple[float, ...]:
    try:
        h = tuple(float(x) for x in np.atleast_1d(np.asarray(horizons, dtype=np.float64)))
    except (TypeError, ValueError):
        raise InvalidInputError(f"horizons must be numbers of seconds, got {horizons!r}") from None
    if not h or not all(np.isfinite(x) and x > 0 for x in h):
        raise InvalidInputError(f"horizons must be positive numbers of seconds, got {horizons!r}")
    return h


def _units(frames: Frames) -> dict[str, Any]:
    summary = getattr(frames, "summary", None)
    units = getattr(summary, "units", None)
    return {"length": units or "data units", "dt": getattr(summary, "dt", None)}


__all__ = [
    "Evaluation",
    "evaluate",
    "realism",
    "split_in_time",
    "SingleGP",
    "position_blind_scores",
    "constant_velocity_scores",
    "ConstantVelocity",
    "rollout_errors",
    "TRAIN_FRACTION",
]
