"""Generating new multi-vehicle scenarios from a fitted model (docs/guide/generating.md; the
rules: docs/generation.md).

By default (``dynamics="interactive"``, issue 15) a scenario is: a pattern drawn by its weight;
one of that pattern's own frames, drawn uniformly, whose positions are the scene's (a recorded
configuration: its count, spacing and groups), less any vehicle closer than the pattern's
recorded spacing (:mod:`dpgp.motion`) to one kept before it, so ``counts`` may fall short of the
frame's size; velocities drawn jointly from the pattern's GP at those positions; then a
rollout by the residual model and interaction rules of :mod:`dpgp.motion` (see
``docs/generation.md``). ``dynamics="field"`` is the earlier generator, bit for bit:

A scenario is: a pattern drawn by its weight, a vehicle count drawn from φ (the training frames'
vehicle-count distribution), positions drawn from the pattern's own position distribution (a ψ
histogram of its frames' positions; the global ψ when it holds fewer than
:data:`MIN_OWN_POSITIONS`), velocities drawn jointly from the pattern's GP at those positions,
then a rollout (:mod:`dpgp.simulation`) that keeps drawing velocities from the pattern's
posterior at every step (``stochastic=True``, the default) or follows its mean.

Export: a CSV table ``scenario, vehicle, t, x, y, vx, vy`` and SUMO floating-car data (FCD) XML,
the trajectory format of the SUMO simulator and its tools (see :meth:`Scenarios.to_sumo`).

Limits: one call generates at most :data:`MAX_SCENARIOS` (10⁵) scenarios, and at most
:data:`dpgp.simulation.MAX_ROWS` rows counted with φ's largest vehicle count, ``n ×
max_count × (steps + 1)`` (so whether a call is refused does not depend on the seed). Larger
requests are an ``InvalidInputError`` before anything is drawn; generate in batches instead.
"""

from __future__ import annotations

import dataclasses
import gzip
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import _core
from .._arrays import as_path
from .._validate import check_roi
from ..exceptions import InvalidInputError
from ..gp.fitted import FittedPatterns, as_fitted
from .distributions import EmpiricalDistributions
from .headings import check_max_curvature, heading_speed, start_headings
from .motion import motion_model
from .rollout import motion_records, split
from .simulation import (
    LOW_DATA_THRESHOLD,
    Simulation,
    _check,
    _check_pattern,
    _check_rows,
    check_dynamics,
    rollouts,
)  # fmt: skip

if TYPE_CHECKING:
    import pandas as pd

MIN_OWN_POSITIONS = 20  # fewer positions than this in a pattern: draw from the global ψ
DEFAULT_BINS = (20, 20)  # ψ grid over the ROI
#: Most scenarios one call may generate. Each costs tens of microseconds and a few kB of Python
#: objects whatever its size, so 10**8 would run for an hour; generate more in batches (seeds).
MAX_SCENARIOS = 100_000

_COLUMNS = ["scenario", "vehicle", "t", "x", "y", "vx", "vy"]


@dataclass(frozen=True, eq=False)
class Scenarios:
    """Generated scenarios: ``scenarios[i]`` is the :class:`~dpgp.simulation.Simulation` of
    scenario ``i``; ``patterns`` and ``counts`` give each one's pattern and vehicle count;
    ``ego`` (when asked for, :func:`choose_ego`) each one's ego vehicle, ``-1`` where none
    qualified: the vehicle a system under test replaces, named ``Ego`` in OpenSCENARIO files and
    ``s{scenario}_ego`` in SUMO's."""

    simulations: list[Simulation]
    patterns: np.ndarray
    counts: np.ndarray
    ego: np.ndarray | None = None
    #: Drawn from a tilted generator (:mod:`.critical`): each scene's likelihood ratio against the
    #: natural one, and the training frame it started from.
    weights: np.ndarray | None = None
    sources: np.ndarray | None = None
    #: With a :class:`Tilt` of the innovations: each scene's shifted innovation (``(n, 2)``; NaN
    #: where its vehicle was gone by then), what :func:`~dpgp.generate.critical.learn_tilt` learns from.
    picks: np.ndarray | None = None

    def estimate(self, event: Any, size: Any = None, measures: Any = None) -> Any:
        """The natural rate of ``event`` (e.g. ``"ttc<1.0"``) estimated from these scenes with
        their :attr:`weights` (natural scenes: 1): a :class:`~dpgp.generate.criticality.Estimate`
        (``measures``: their per-scene measures when already computed)."""
        from .criticality import estimate

        return estimate(self, event, size=size, measures=measures)

    def _is_ego(self, scenario: np.ndarray, vehicle: np.ndarray) -> np.ndarray:
        """Whether each ``(scenario, vehicle)`` row is its scenario's ego."""
        if self.ego is None:
            return np.zeros(len(vehicle), dtype=bool)
        return np.asarray(self.ego)[scenario.astype(np.int64)] == vehicle

    def __len__(self) -> int:
        return len(self.simulations)

    def __getitem__(self, i: int) -> Simulation:
        return self.simulations[i]

    def __iter__(self):
        return iter(self.simulations)

    @property
    def dt(self) -> float:
        return self.simulations[0].dt if self.simulations else float("nan")

    def to_pandas(self) -> pd.DataFrame:
        """``scenario, vehicle, t, x, y, vx, vy``: one row per vehicle and time while the vehicle
        is inside the ROI (a vehicle that has left is gone, as in recorded data)."""
        import pandas as pd

        parts = []
        for s, sim in enumerate(self.simulations):
            T, l = sim.in_roi.shape
            keep = sim.in_roi.ravel()
            parts.append(
                {
                    "scenario": np.full(int(keep.sum()), s, dtype=np.int64),
                    "vehicle": np.tile(np.arange(l, dtype=np.int64), T)[keep],
                    "t": np.repeat(sim.t, l)[keep],
                    "x": sim.positions[..., 0].ravel()[keep],
                    "y": sim.positions[..., 1].ravel()[keep],
                    "vx": sim.velocities[..., 0].ravel()[keep],
                    "vy": sim.velocities[..., 1].ravel()[keep],
                }
            )
        if not parts:
            return pd.DataFrame({c: np.array([], dtype=np.float64) for c in _COLUMNS})
        return pd.DataFrame({c: np.concatenate([p[c] for p in parts]) for c in _COLUMNS})

    def to_csv(self, path: str | os.PathLike) -> None:
        """Write :meth:`to_pandas` as CSV (full float precision)."""
        self.to_pandas().to_csv(as_path(path), index=False, float_format="%.17g")

    def to_sumo(self, path: str | os.PathLike, vtype: str = "DEFAULT_VEHTYPE") -> None:
        """Write SUMO floating-car data (``<fcd-export>``; gzip if ``path`` ends in ``.gz``).

        Vehicle ids are ``s{scenario}_v{vehicle}``, a scenario's ego's ``s{scenario}_ego``. Scenario ``s`` is shifted in time by
        ``s * (steps + 1) * dt`` so that scenarios follow one another on one regular time grid
        (framing the file again gives frames that each hold one scenario). ``speed`` and
        ``angle`` (degrees clockwise from north, +y) carry the velocity, as SUMO writes them.
        ``dpgp.read_tracks(path)`` reads the file back.
        """
        df = self.to_pandas()
        steps = self.simulations[0].steps if self.simulations else 0
        dt = self.dt if steps else 1.0
        step = np.rint(df["t"].to_numpy() / dt).astype(np.int64) if steps else np.zeros(len(df), np.int64)
        tick = df["scenario"].to_numpy() * (steps + 1) + step
        order = np.lexsort((df["vehicle"].to_numpy(), tick))
        vx, vy = df["vx"].to_numpy()[order], df["vy"].to_numpy()[order]
        speed = np.hypot(vx, vy)
        angle = np.degrees(np.arctan2(vx, vy)) % 360.0
        sc, veh = df["scenario"].to_numpy()[order], df["vehicle"].to_numpy()[order]
        ego = self._is_ego(sc, veh)
        ids = [f"s{s}_ego" if e else f"s{s}_v{v}" for s, v, e in zip(sc, veh, ego)]
        x, y, tick = df["x"].to_numpy()[order], df["y"].to_numpy()[order], tick[order]
        lines = [
            '<?xml version="1.0" encoding="UTF-8"?>',
            "<!-- generated by dpgp: scenarios sampled from a DP-GP motion-pattern model -->",
            '<fcd-export xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
            'xsi:noNamespaceSchemaLocation="http://sumo.dlr.de/xsd/fcd_file.xsd">',
        ]
        starts = np.flatnonzero(np.r_[True, tick[1:] != tick[:-1]]) if len(tick) else np.array([], int)
        bounds = np.r_[starts, len(tick)]
        for a, b in zip(bounds[:-1], bounds[1:]):
            lines.append(f'    <timestep time="{tick[a] * dt:.6f}">')
            lines.extend(
                f'        <vehicle id="{ids[i]}" x="{x[i]:.6f}" y="{y[i]:.6f}" angle="{angle[i]:.6f}" '
                f'type="{vtype}" speed="{speed[i]:.6f}"/>'
                for i in range(a, b)
            )
            lines.append("    </timestep>")
        lines.append("</fcd-export>\n")
        text = "\n".join(lines).encode("utf-8")
        path = as_path(path)
        opener = gzip.open if path.endswith(".gz") else open
        with opener(path, "wb") as fh:
            fh.write(text)

    def to_openscenario(self, path: str | os.PathLike, model: Any = None, **options: Any) -> list:
        """Write ASAM OpenSCENARIO 1.2 files, one per scenario (``path``: a directory, or a
        ``.xosc`` file for one scenario); needs ``pip install dpgp[openscenario]``. ``options``:
        ``units``, ``origin``, ``road_network``, ``object_type``, ``size``, ``seed``,
        ``description``, ``date``, ``progress``; see :func:`dpgp.openscenario.write_openscenario`."""
        from .openscenario import write_openscenario

        return write_openscenario(self, path, model, **options)

    def save(self, path: str | os.PathLike, format: str | None = None) -> None:
        """Write ``"csv"`` or ``"sumo"`` (default: SUMO for ``.xml``/``.xml.gz``, else CSV)."""
        fmt = format or ("sumo" if as_path(path).lower().endswith((".xml", ".xml.gz")) else "csv")
        if fmt == "csv":
            self.to_csv(path)
        elif fmt == "sumo":
            self.to_sumo(path)
        else:
            raise InvalidInputError(f"format must be 'csv' or 'sumo', got {format!r}")

    def __repr__(self) -> str:
        steps = self.simulations[0].steps if self.simulations else 0
        return (
            f"Scenarios({len(self)} scenarios of {steps} steps of {self.dt:g} s, {int(self.counts.sum())} vehicles, "
            f"from {len(np.unique(self.patterns))} pattern(s))"
        )


def distributions(model: Any, bins: Any = DEFAULT_BINS) -> EmpiricalDistributions:
    """φ and ψ of the training frames over the training ROI, with the smoothing pseudo-counts
    set from them (``model`` a :class:`~dpgp.fitted.FittedPatterns` or a fitted estimator; kept
    in its cache, and in the model file, so that neither is recomputed)."""
    fit = as_fitted(model)
    cached = fit.cache.get("distributions")
    if cached is not None and cached[0] is fit.frames and (bins is None or cached[1].bins == _pair(bins)):
        return cached[1]
    d = EmpiricalDistributions.from_frames(fit.frames, roi=_padded(fit), bins=bins or DEFAULT_BINS)
    fit.cache["distributions"] = (fit.frames, d)
    return d


def _pair(bins: Any) -> tuple[int, int]:
    b = np.atleast_1d(bins)
    return (int(b[0]), int(b[-1]))


def _padded(fit: FittedPatterns) -> tuple[float, float, float, float]:
    """The training ROI, widened to hold every training position (ψ must cover them all)."""
    roi = fit.roi
    x0, x1, y0, y1 = fit.frames.bounds()
    r = (min(roi[0], x0), max(roi[1], x1), min(roi[2], y0), max(roi[3], y1))
    if r[0] == r[1] or r[2] == r[3]:
        r = (r[0] - 0.5, r[1] + 0.5, r[2] - 0.5, r[3] + 0.5)
    return r


def pattern_positions(model: Any, k: int, psi: EmpiricalDistributions) -> EmpiricalDistributions:
    """Pattern ``k``'s own position distribution (its frames' positions on ψ's grid), or ψ
    itself when the pattern holds fewer than :data:`MIN_OWN_POSITIONS` positions."""
    fit = as_fitted(model)
    rows = np.repeat(fit.labels == k, fit.frames.sizes)
    if rows.sum() < MIN_OWN_POSITIONS:
        return psi
    frames = fit.frames[np.flatnonzero(fit.labels == k)]
    # only drawn from: the recorded form, no smoothing to set
    return EmpiricalDistributions.from_frames(frames, roi=psi.roi, bins=psi.bins, pseudocount=0.0)


def sample_scenarios(
    model: Any,
    n: int,
    steps: int = 100,
    pattern: int | None = None,
    seed: int | None = None,
    *,
    dt: float | None = None,
    method: str = "euler",
    stochastic: bool = True,
    roi: tuple[float, float, float, float] | None = None,
    low_data_threshold: float | None = LOW_DATA_THRESHOLD,
    dynamics: str | None = None,
    max_curvature: float | str | None = None,
    ego: Any = None,
    tilt: Any = None,
) -> Scenarios:
    """Generate ``n`` scenarios; see :meth:`dpgp.DPGP.sample_scenarios`. ``model``: a
    :class:`~dpgp.fitted.FittedPatterns` (or a fitted estimator, which hands one down).
    ``max_curvature``: the pure field's turning limit over heading (:mod:`.headings`). ``ego``:
    ``(x, y)`` or ``(x, y, heading in degrees)``, each scenario's ego vehicle by
    :func:`choose_ego`. ``tilt``: draw each scene's training frame from these probabilities (one
    per training frame, :func:`tilted_frames`; :mod:`.critical`) instead of the natural ones
    (:func:`natural_frames`), or from a :class:`Tilt` that may also shift an innovation, and weigh
    each scene by its likelihood ratio."""
    rule = ego_rule(ego)
    placed = rule if isinstance(rule, Ego) and rule.placed else None
    scenes = _sample(model, n, steps, pattern, seed, dt=dt, method=method, stochastic=stochastic, roi=roi,
                     low_data_threshold=low_data_threshold, dynamics=dynamics, max_curvature=max_curvature,
                     tilt=tilt, place=placed)  # fmt: skip
    if rule is None:
        return scenes
    if placed is not None:  # the first vehicle of every scene
        egos = np.array([0 if s.in_roi.shape[1] and s.in_roi[0, 0] else -1 for s in scenes.simulations], np.int64)
        return dataclasses.replace(scenes, ego=egos)
    return dataclasses.replace(scenes, ego=choose_ego(scenes.simulations, rule.point, rule.heading))


@dataclass(frozen=True)
class Tilt:
    """An importance-sampling tilt of the default generator (:mod:`.critical`): ``frames``, the
    probability of starting from each training frame (``None``: the natural ones,
    :func:`natural_frames`); ``shift``, the mean ``(along, across)`` from which one uniformly
    chosen residual innovation of each scene is drawn (``None``: none; the core's ``Shift``,
    ``docs/criticality.md``). Each scene's weight is the product of both exact ratios."""

    frames: Any = None
    shift: tuple[float, float] | None = None

    @classmethod
    def of(cls, tilt: Any) -> Tilt:
        """A :class:`Tilt`, or frame probabilities alone."""
        return tilt if isinstance(tilt, Tilt) else cls(frames=tilt)


def natural_frames(model: Any) -> np.ndarray:
    """The natural probability of starting from each training frame: its pattern's weight over
    the pattern's number of frames."""
    fit = as_fitted(model)
    labels = np.asarray(fit.labels, dtype=np.int64)
    counts = np.bincount(labels, minlength=fit.n_patterns)
    return np.asarray(fit.weights, dtype=np.float64)[labels] / counts[labels]


def tilted_frames(model: Any, tilt: Any) -> np.ndarray:
    """``tilt`` checked: one probability per training frame, summing to 1 (normalised), positive
    wherever the natural generator is (else a scene could not be weighed)."""
    p = natural_frames(model)
    try:
        q = np.asarray(tilt, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        q = np.zeros(0)
    if q.shape != p.shape or not np.all(np.isfinite(q) & (q >= 0)) or q.sum() <= 0:
        raise InvalidInputError(
            f"tilt must give {len(p)} probabilities >= 0, one per training frame (see dpgp.generate.critical)"
        )
    q = q / q.sum()
    if np.any((q == 0) & (p > 0)):
        raise InvalidInputError("tilt gives probability 0 to training frames the natural generator starts from")
    return q


#: An ego's start heading lies within this many degrees of the rule's heading.
EGO_HEADING_TOLERANCE = 45.0


@dataclass(frozen=True)
class Ego:
    """A scenario's ego vehicle, the one a system under test replaces: by rule (``placed=False``,
    :func:`choose_ego`), the vehicle nearest ``(x, y)`` at the start (with ``heading``, in
    degrees, one moving within :data:`EGO_HEADING_TOLERANCE` of it: an approach); or
    ``placed`` there by the user, the first vehicle of every scene (the recorded ones closer than
    the pattern's spacing to it dropped), its velocity drawn from the field as the others' (over
    heading, at ``heading``; unknown without one). ``ego=(x, y)`` and ``(x, y, heading)`` are the rule."""

    x: float
    y: float
    heading: float | None = None
    placed: bool = False

    @property
    def point(self) -> tuple[float, float]:
        return (self.x, self.y)


def ego_rule(ego: Any) -> Ego | None:
    """``ego=`` checked: ``None``, or the :class:`Ego` it names."""
    if ego is None:
        return None
    if isinstance(ego, Ego):
        vals = [ego.x, ego.y] + ([] if ego.heading is None else [ego.heading])
        placed = bool(ego.placed)
    else:
        try:
            vals = [float(v) for v in ego]
        except (TypeError, ValueError):
            vals = []
        placed = False
    if len(vals) not in (2, 3) or not all(np.isfinite(vals)):
        raise InvalidInputError(
            f"ego must be (x, y) or (x, y, heading in degrees): the vehicle nearest that point at the start "
            f"(heading that way), or an Ego placed there; got {ego!r}"
        )
    return Ego(float(vals[0]), float(vals[1]), float(vals[2]) if len(vals) == 3 else None, placed)


def moving_along(v: np.ndarray, heading: float, min_speed: float) -> np.ndarray:
    """Which velocities ``v`` (n, 2) move at least ``min_speed`` within
    :data:`EGO_HEADING_TOLERANCE` degrees of ``heading`` (degrees): an approach."""
    turn = np.degrees(np.angle(np.exp(1j * (np.arctan2(v[:, 1], v[:, 0]) - np.radians(heading)))))
    return (np.hypot(v[:, 0], v[:, 1]) >= min_speed) & (np.abs(turn) <= EGO_HEADING_TOLERANCE)


def choose_ego(sims: list[Simulation], point: tuple[float, float], heading: float | None = None,
               min_speed: float = 0.5) -> np.ndarray:  # fmt: skip
    """Each scenario's ego: of its vehicles inside the ROI at the start (and, with ``heading``,
    moving at least ``min_speed`` within :data:`EGO_HEADING_TOLERANCE` degrees of it: an
    approach), the one nearest ``point``; ``-1`` where none qualifies."""
    out = np.full(len(sims), -1, dtype=np.int64)
    for i, sim in enumerate(sims):
        xy, v, inside = sim.positions[0], sim.velocities[0], sim.in_roi[0].copy()
        if heading is not None:
            inside &= moving_along(v, heading, min_speed)
        if inside.any():
            d = np.hypot(xy[:, 0] - point[0], xy[:, 1] - point[1])
            out[i] = int(np.argmin(np.where(inside, d, np.inf)))
    return out


def _sample(
    model: Any,
    n: int,
    steps: int,
    pattern: int | None,
    seed: int | None,
    *,
    dt: float | None,
    method: str,
    stochastic: bool,
    roi: tuple[float, float, float, float] | None,
    low_data_threshold: float | None,
    dynamics: str | None,
    max_curvature: float | str | None,
    tilt: Any = None,
    place: Ego | None = None,
) -> Scenarios:
    fit = as_fitted(model)
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 0:
        raise InvalidInputError(f"n must be a whole number >= 0, got {n!r}")
    if n > MAX_SCENARIOS:
        raise InvalidInputError(
            f"n={n} is more than the {MAX_SCENARIOS} scenarios one call may generate; generate them in batches with different seeds"
        )
    dt = fit.dt if dt is None else dt
    steps, method, thr = _check(steps, method, dt, low_data_threshold)
    _check_rows(
        int(steps) + 1, f"a time axis of {steps} steps", "ask for fewer steps"
    )  # allocated even for no scenario
    box = fit.roi if roi is None else check_roi(roi)
    psi = distributions(fit)
    # Bound the work by the largest count φ can draw, so that whether a call is refused does not
    # depend on the seed, and it is refused before anything is drawn or allocated.
    rows = int(n) * psi.max_count * (steps + 1)
    _check_rows(
        rows, f"{n} scenarios of up to {psi.max_count} vehicles and {steps} steps", "ask for fewer scenarios or steps"
    )
    if seed is not None and (isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0):
        raise InvalidInputError(f"seed must be a whole number >= 0 or None, got {seed!r}")
    rng = np.random.default_rng(seed)
    dynamics = check_dynamics(dynamics, method)
    kappa = check_max_curvature(max_curvature, fit, dynamics)
    if place is not None:
        if dynamics == "field":
            raise InvalidInputError("a placed ego joins the default generator's scenes: drop dynamics='field'")
        x0, x1, y0, y1 = box
        if not (x0 <= place.x <= x1 and y0 <= place.y <= y1):
            raise InvalidInputError(f"the placed ego ({place.x:g}, {place.y:g}) lies outside the ROI {tuple(box)}")
    if tilt is not None:
        if dynamics == "field" or pattern is not None:
            raise InvalidInputError(
                "tilt= draws the starting frames of the default generator: drop dynamics='field' and pattern="
            )
        tilt = Tilt.of(tilt)
        p = natural_frames(fit)
        q = p if tilt.frames is None else tilted_frames(fit, tilt.frames)
        shift = _check_shift(tilt.shift, stochastic)
        chosen = rng.choice(len(q), size=n, p=q).astype(np.int64)
        scenes = _interactive(fit, fit.labels[chosen].astype(np.int64), psi, rng, steps=steps, dt=float(dt),
                              stochastic=stochastic, roi=box, low_data_threshold=thr, dynamics=dynamics, chosen=chosen,
                              shift=shift, place=place)  # fmt: skip
        ratio = p[chosen] / q[chosen]
        if scenes.weights is not None:  # the shifted innovations' own ratios
            ratio = ratio * scenes.weights
        return dataclasses.replace(scenes, weights=ratio, sources=chosen)
    if pattern is None:
        patterns = rng.choice(fit.n_patterns, size=n, p=fit.weights).astype(np.int64)
    else:
        patterns = np.full(n, _check_pattern(fit, pattern), dtype=np.int64)
    if dynamics != "field":
        return _interactive(fit, patterns, psi, rng, steps=steps, dt=float(dt), stochastic=stochastic, roi=box,
                            low_data_threshold=thr, dynamics=dynamics, place=place)  # fmt: skip
    counts = psi.sample_counts(n, rng)
    own = {int(k): pattern_positions(fit, int(k), psi) for k in np.unique(patterns)}
    starts = [own[int(k)].sample_positions(int(c), rng) for k, c in zip(patterns, counts)]
    # The rollout's first recorded velocities are the GP draw at the sampled positions.
    seeds = [int(s) for s in rng.integers(0, 2**63, size=n, dtype=np.uint64)] if stochastic else None
    sims = rollouts(
        fit,
        patterns.tolist(),
        starts,
        steps=steps,
        dt=float(dt),
        method=method,
        seeds=seeds,
        roi=box,
        low_data_threshold=thr,
        # over heading: unknown at the start (the first draw is of the field averaged over
        # heading), then each vehicle's own, tracked from its velocities as simulate tracks them
        headings=[np.full(len(s), np.nan) for s in starts],
        max_curvature=kappa,
    )
    return Scenarios(sims, patterns, counts)


def _check_shift(shift: Any, stochastic: bool) -> tuple[float, float] | None:
    if shift is None:
        return None
    try:
        mean = tuple(float(v) for v in shift)
    except (TypeError, ValueError):
        mean = ()
    if len(mean) != 2 or not all(np.isfinite(mean)):
        raise InvalidInputError(f"a tilt's shift is two finite numbers (along, across), got {shift!r}")
    if not stochastic:
        raise InvalidInputError("a tilt's shift moves drawn innovations: drop stochastic=False")
    return (mean[0], mean[1])


def pattern_frames(fit: FittedPatterns, patterns: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A training frame per scenario, drawn uniformly from its pattern's own."""
    out = np.zeros(len(patterns), dtype=np.int64)
    for k in np.unique(patterns):
        mine = np.flatnonzero(patterns == k)
        own = np.flatnonzero(fit.labels == k)
        out[mine] = own[rng.integers(0, len(own), size=len(mine))]
    return out


def pattern_counts(fit: FittedPatterns, patterns: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A vehicle count per scenario: the size of a frame drawn uniformly from its pattern's own."""
    return fit.frames.sizes[pattern_frames(fit, patterns, rng)]


def _interactive(fit: FittedPatterns, patterns: np.ndarray, psi: EmpiricalDistributions, rng: np.random.Generator, *,
                 steps: int, dt: float, stochastic: bool, roi: Any, low_data_threshold: float | None, dynamics: str,
                 chosen: np.ndarray | None = None, shift: tuple[float, float] | None = None,
                 place: Ego | None = None) -> Scenarios:  # fmt: skip
    """Scenes from each pattern's own frames (``chosen``: these training frames, one a scene): the positions of one of them (a recorded
    configuration: its count, spacing and groups), less any vehicle closer than the pattern's
    recorded spacing to one kept before it; velocities jointly from its GP at those positions,
    rolled out by the residual model and interaction. Thinning, draws and rollouts run in
    parallel in the core, one seed per scenario."""
    if len(patterns) == 0:
        return Scenarios([], patterns, np.zeros(0, dtype=np.int64))
    if chosen is None:
        chosen = pattern_frames(fit, patterns, rng)
    requested = fit.frames.sizes[chosen]
    rows = np.concatenate([np.arange(fit.frames.offsets[f], fit.frames.offsets[f + 1]) for f in chosen])
    starts = np.ascontiguousarray(fit.frames.xy[rows], dtype=np.float64)
    # a field over heading: each recorded vehicle's heading goes with its position
    prev = None if fit.frames.prev_heading is None else fit.frames.prev_heading[rows]
    h = start_headings(fit.frames.v[rows], prev, heading_speed(fit), len(rows))
    if place is not None:
        # the placed ego first in each scene: thinning keeps it and drops recorded vehicles too close
        at = np.r_[0, np.cumsum(requested)][:-1]
        starts = np.ascontiguousarray(np.insert(starts, at, [place.x, place.y], axis=0))
        h = np.insert(h, at, np.nan if place.heading is None else np.radians(place.heading))
        requested = requested + 1
    # every fit's core takes them: a field over heading's inputs, and where the field is too slow
    # to have a heading, a steering vehicle's start (a fit over position ignores them otherwise)
    headings = (np.ascontiguousarray(h, dtype=np.float64), heading_speed(fit))
    seeds = [int(s) for s in rng.integers(0, 2**63, size=len(patterns), dtype=np.uint64)]
    spacing = motion_model(fit).spacing[patterns]
    unused = np.ones((1, 1))  # the core's histogram placement: not used when starts are given
    pos, vel, inside, low, sizes, log_ratios, picks, heads = _core.scene_rollouts(
        fit.sampler, [int(fit.slots[k]) for k in patterns], requested.tolist(), [0] * len(patterns),
        unused, (1, 1), tuple(psi.roi), spacing.tolist(),  # type: ignore[arg-type]
        motion_records(patterns, dynamics, motion_model(fit)), seeds, bool(stochastic), float(dt), int(steps), tuple(roi), low_data_threshold,
        starts, np.r_[0, np.cumsum(requested)].astype(np.int64), headings, shift,
    )  # fmt: skip
    sims = split(
        pos,
        vel,
        inside,
        low,
        sizes,
        patterns.tolist(),
        steps=steps,
        dt=dt,
        stochastic=stochastic,
        roi=roi,
        dynamics=dynamics,
        headings=heads,
    )
    if shift is None:
        return Scenarios(sims, patterns, np.asarray(sizes, dtype=np.int64))
    # weighed by the shifted innovation's ratio (the starting frames' is _sample's)
    return Scenarios(sims, patterns, np.asarray(sizes, dtype=np.int64), weights=np.exp(log_ratios), picks=picks)


__all__ = ["Scenarios", "sample_scenarios", "distributions", "pattern_positions", "MIN_OWN_POSITIONS", "MAX_SCENARIOS"]
