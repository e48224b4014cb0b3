"""Criticality measures of scenes (issue 35): how near their vehicles come to colliding.

:func:`criticality` measures generated :class:`~dpgp.scenarios.Scenarios`, single simulations,
or recorded :class:`~dpgp.Frames` (cut into windows of consecutive frames by
:func:`recorded_scenes`). Each vehicle is a rectangle of ``size`` (length, width) along its
heading: its velocity's direction when at least ``min_speed`` fast, else its recorded heading where
the scene has one (recorded frames' ``prev_heading``: the way it last moved), else the last such
(before any, the first one after; a vehicle that never moves and has no recorded heading faces
+x). Per pair of vehicles, over the times both are in the scene:

- ``ttc``: time to collision, the least over the times of how long until their rectangles would
  touch if both kept their velocities (0 when they touch, ``inf`` when they never would);
- ``gap``: the least distance between the rectangles (0 when they touch);
- ``pet``: post-encroachment time, where the centre paths cross, from the first vehicle's rear
  leaving the crossing point to the second's front reaching it (0 when both are on it at once),
  the least over the crossings (``inf`` without one);
- ``collision``: the rectangles touch at one of the times.

Per vehicle, ``deceleration``: the largest drop of its speed per second between consecutive
times (0 when it never slows). The geometry runs in the core (``dpgp_core::criticality``), scenes
in parallel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import _core
from ..exceptions import InvalidInputError

if TYPE_CHECKING:
    import pandas as pd

#: A passenger car's (length, width) in metres, for scenes whose data carry no size.
DEFAULT_SIZE = (4.5, 1.8)
#: Speed (the data's length unit per second) from which a velocity gives a heading.
MIN_SPEED = 0.5
#: The measures of a pair, and how a scene's pairs combine into the scene's.
PAIR_MEASURES = {"ttc": "min", "gap": "min", "pet": "min", "collision": "any"}


@dataclass(frozen=True)
class Criticality:
    """Measures of ``n_scenes`` scenes: ``pairs`` (columns ``scene``, ``a``, ``b``, ``ttc``,
    ``gap``, ``pet``, ``collision``; one row per pair of vehicles in a scene together) and
    ``vehicles`` (``scene``, ``vehicle``, ``deceleration``). :meth:`per_scene` combines them."""

    pairs: dict[str, np.ndarray]
    vehicles: dict[str, np.ndarray]
    n_scenes: int

    def per_scene(self) -> dict[str, np.ndarray]:
        """Per scene: the least ``ttc``, ``gap`` and ``pet`` over its pairs (``inf`` without a
        pair), whether any pair collided, and its hardest ``deceleration`` (0 without vehicles)."""
        n, s = self.n_scenes, self.pairs["scene"]
        out: dict[str, np.ndarray] = {}
        for name, how in PAIR_MEASURES.items():
            if how == "min":
                col = np.full(n, np.inf)
                np.minimum.at(col, s, self.pairs[name])
            else:
                col = np.zeros(n, dtype=bool)
                np.logical_or.at(col, s, self.pairs[name])
            out[name] = col
        decel = np.zeros(n)
        np.maximum.at(decel, self.vehicles["scene"], self.vehicles["deceleration"])
        out["deceleration"] = decel
        return out

    def to_pandas(self) -> pd.DataFrame:
        """The pairs as a table (one row per pair)."""
        import pandas as pd

        return pd.DataFrame(self.pairs)


def _grid(scene: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A simulation's positions, velocities (times, vehicles, 2) and presence (times, vehicles)."""
    pos = np.asarray(scene.positions, dtype=np.float64)
    vel = np.asarray(scene.velocities, dtype=np.float64)
    inside = np.asarray(scene.in_roi, dtype=bool)
    if pos.ndim != 3 or pos.shape[2] != 2 or vel.shape != pos.shape or inside.shape != pos.shape[:2]:
        raise InvalidInputError(
            "a scene needs positions and velocities of shape (times, vehicles, 2) and in_roi of shape "
            f"(times, vehicles); got {pos.shape}, {vel.shape} and {inside.shape}"
        )
    return pos, vel, inside


def default_size(summary: Any) -> tuple[float, float]:
    """The size frames' vehicles have: their recorded median (``summary.object_size``), else
    :data:`DEFAULT_SIZE` in their length unit."""
    recorded = getattr(summary, "object_size", None)
    if recorded is not None:
        return float(recorded[0]), float(recorded[1])
    per_metre = 1 / 0.3048 if getattr(summary, "length_unit", None) == "ft" else 1.0
    return DEFAULT_SIZE[0] * per_metre, DEFAULT_SIZE[1] * per_metre


def _check_size(size: Any) -> tuple[float, float]:
    try:
        vals = tuple(float(v) for v in size)
    except (TypeError, ValueError):
        raise InvalidInputError(f"size must be (length, width), got {size!r}") from None
    if len(vals) != 2 or not all(math.isfinite(v) and v > 0 for v in vals):
        raise InvalidInputError(f"size must be two positive lengths (length, width), got {size!r}")
    return vals[0], vals[1]


def criticality(
    scenes: Any,
    *,
    size: Any = None,
    dt: float | None = None,
    min_speed: float = MIN_SPEED,
    ego: bool | int | Sequence[int] | np.ndarray | None = None,
    steps: int | None = None,
) -> Criticality:
    """Criticality measures of ``scenes``: :class:`~dpgp.scenarios.Scenarios`, one
    :class:`~dpgp.simulation.Simulation` or a list of them, or recorded
    :class:`~dpgp.Frames` (windows of ``steps + 1`` consecutive frames, :func:`recorded_scenes`).
    ``size``: every vehicle's (length, width) in the data's unit (default: the frames' recorded
    median size when they carry one, else :data:`DEFAULT_SIZE` in their unit). ``dt``: seconds between times
    (default: the scenes' own). ``ego``: a vehicle per scene (or one for all): only the pairs
    with it and its own deceleration, ``-1`` none; ``True``: the scenarios' own, :attr:`~dpgp.scenarios.Scenarios.ego`)."""
    from ..data.frames import Frames

    if ego is True:
        ego = getattr(scenes, "ego", None)
        if ego is None and isinstance(scenes, (list, tuple)) and scenes and all(hasattr(s, "ego") for s in scenes):
            ego = np.array([s.ego for s in scenes], dtype=np.int64)  # long scenarios, each with its own
        if ego is None:
            raise InvalidInputError(
                "ego=True measures against the scenarios' own ego vehicles, and these have none: "
                "generate them with sample_scenarios(..., ego=(x, y))"
            )

    if isinstance(scenes, Frames):
        size = default_size(scenes.summary) if size is None else size
        scenes = recorded_scenes(scenes, 40 if steps is None else steps, dt=dt)
    elif steps is not None:
        raise InvalidInputError("steps= cuts recorded frames into scenes; generated scenes have their own")
    sims = getattr(scenes, "simulations", None)
    if sims is None:
        sims = list(scenes) if isinstance(scenes, (list, tuple)) else [scenes]
    length, width = _check_size(DEFAULT_SIZE if size is None else size)
    if not (isinstance(min_speed, (int, float)) and math.isfinite(min_speed) and min_speed >= 0):
        raise InvalidInputError(f"min_speed must be a finite speed >= 0, got {min_speed!r}")
    grids = [_grid(s) for s in sims]
    steps_dt = {float(s.dt) for s in sims} if dt is None else {float(dt)}
    if len(steps_dt) > 1:
        raise InvalidInputError(f"the scenes have different time steps {sorted(steps_dt)}: measure them apart")
    step = steps_dt.pop() if steps_dt else 1.0
    if not (math.isfinite(step) and step > 0):
        raise InvalidInputError(f"dt must be a positive number of seconds, got {step!r}")
    vehicles = [g[0].shape[1] for g in grids]
    rows = np.r_[0, np.cumsum([g[0].shape[0] * g[0].shape[1] for g in grids])].astype(np.int64)

    def flat(i: int, shape: tuple[int, ...]) -> np.ndarray:
        parts = [g[i].reshape(shape) for g in grids]
        return np.ascontiguousarray(np.concatenate(parts) if parts else np.zeros((0, *shape[1:])))

    pos, vel, present = flat(0, (-1, 2)), flat(1, (-1, 2)), flat(2, (-1,)).astype(bool)
    sizes = np.tile([length, width], (sum(vehicles), 1)).astype(np.float64)
    # recorded scenes' headings (a standing vehicle faces the way it last moved); NaN: not known
    known = [getattr(s, "headings", None) for s in sims]
    heads = None
    if any(h is not None for h in known):
        heads = np.ascontiguousarray(np.concatenate(
            [np.full(g[2].size, np.nan) if h is None else np.asarray(h, np.float64).reshape(-1) for g, h in zip(grids, known)]
        ))  # fmt: skip
    scene, a, b, ttc, gap, pet, hit, decel = _core.criticality(
        pos, vel, present, rows, vehicles, sizes, step, float(min_speed), heads
    )
    pairs = {"scene": scene, "a": a, "b": b, "ttc": ttc, "gap": gap, "pet": pet, "collision": hit}
    per_vehicle = {
        "scene": np.repeat(np.arange(len(grids)), vehicles).astype(np.int64),
        "vehicle": np.concatenate([np.arange(n) for n in vehicles]).astype(np.int64)
        if grids
        else np.zeros(0, np.int64),
        "deceleration": decel,
    }
    if ego is not None:
        e = np.broadcast_to(np.asarray(ego), (len(grids),))
        if e.dtype.kind not in "iu" or np.any(e < -1) or np.any(e >= np.maximum(vehicles, 1)):
            raise InvalidInputError(
                f"ego must be a vehicle of each scene (0 <= ego < its vehicles, or -1: none), got {ego!r}"
            )
        mine = (a == e[scene]) | (b == e[scene])
        pairs = {k: v[mine] for k, v in pairs.items()}
        own = per_vehicle["vehicle"] == e[per_vehicle["scene"]]  # the ego's own deceleration
        per_vehicle = {k: v[own] for k, v in per_vehicle.items()}
    return Criticality(pairs, per_vehicle, len(grids))


def compare(model: Any, frames: Any, *, steps: int = 16, n: int = 500, seed: int = 0) -> pd.DataFrame:
    """Recorded against generated: the per-scene measures of ``frames`` cut into windows of
    ``steps + 1`` frames and of ``n`` scenes of ``steps`` steps from ``model`` (its
    ``sample_scenarios`` with every default), a vehicle the training frames' size
    (:func:`default_size`). Rows ``recorded`` and ``generated``; columns the number of scenes, the
    shares of scenes with a collision, a time to collision under 1 s and a post-encroachment time
    under 1 s, and the medians of the least time to collision and gap and of the hardest
    deceleration."""
    import pandas as pd

    size = default_size(getattr(model.frames_, "summary", None))
    rows = {}
    for name, c in (
        ("recorded", criticality(frames, steps=steps, size=size)),
        ("generated", criticality(model.sample_scenarios(n, steps=steps, seed=seed), size=size)),
    ):
        per = c.per_scene()
        rows[name] = {
            "scenes": c.n_scenes,
            "collision": per["collision"].mean() if c.n_scenes else np.nan,
            "ttc_under_1s": np.mean(per["ttc"] < 1.0) if c.n_scenes else np.nan,
            "pet_under_1s": np.mean(per["pet"] < 1.0) if c.n_scenes else np.nan,
            "median_ttc": np.median(per["ttc"]) if c.n_scenes else np.nan,
            "median_gap": np.median(per["gap"]) if c.n_scenes else np.nan,
            "median_deceleration": np.median(per["deceleration"]) if c.n_scenes else np.nan,
        }
    return pd.DataFrame(rows).T


#: The measures an event may name, and which way is critical: below a threshold, or above it.
EVENT_MEASURES = {"ttc": "<", "gap": "<", "pet": "<", "deceleration": ">"}


@dataclass(frozen=True)
class Event:
    """A critical event of a scene: ``measure`` (``ttc``, ``gap``, ``pet`` or ``deceleration``,
    :meth:`Criticality.per_scene`) below (``<``) or above (``>``) ``threshold``, or
    ``"collision"``. ``Event.parse("ttc<1.0")``; ``ego``: the measure against the scenes' ego
    vehicles only."""

    measure: str
    threshold: float = 0.0
    ego: bool = False

    @classmethod
    def parse(cls, text: Any, ego: bool = False) -> Event:
        if isinstance(text, Event):
            return text
        t = str(text).replace(" ", "")
        if t == "collision":
            return cls("collision", 0.0, ego)
        for name, op in EVENT_MEASURES.items():
            if t.startswith(name + op):
                try:
                    value = float(t[len(name) + 1 :])
                except ValueError:
                    break
                if math.isfinite(value):
                    return cls(name, value, ego)
        raise InvalidInputError(
            f"an event is 'collision' or one of {', '.join(n + o + 'VALUE' for n, o in EVENT_MEASURES.items())} "
            f"(e.g. 'ttc<1.0'), got {text!r}"
        )

    def score(self, per_scene: dict[str, np.ndarray]) -> np.ndarray:
        """How critical each scene is, larger more (the event: a score at or above :attr:`level`):
        minus the measure for ``<``, the measure for ``>``, minus the gap for a collision."""
        if self.measure == "collision":
            return -per_scene["gap"]
        value = per_scene[self.measure]
        return -value if EVENT_MEASURES[self.measure] == "<" else value

    @property
    def level(self) -> float:
        if self.measure == "collision":
            return 0.0
        return -self.threshold if EVENT_MEASURES[self.measure] == "<" else self.threshold

    def happened(self, per_scene: dict[str, np.ndarray]) -> np.ndarray:
        if self.measure == "collision":
            return per_scene["collision"].copy()
        value = per_scene[self.measure]
        return value < self.threshold if EVENT_MEASURES[self.measure] == "<" else value > self.threshold

    def __str__(self) -> str:
        text = (
            "collision"
            if self.measure == "collision"
            else f"{self.measure}{EVENT_MEASURES[self.measure]}{self.threshold:g}"
        )
        return text + (" (ego)" if self.ego else "")


@dataclass(frozen=True)
class Estimate:
    """An event's natural rate from weighted scenes: per scene, with its standard error and 95 %
    interval (normal), per hour of simulated traffic (scenes of ``seconds`` each), how many scenes
    had it (``hits``) of ``n``, the effective sample size of the weights, ``(Σw)² / Σw²``, and
    the :attr:`acceleration` over crude Monte Carlo."""

    event: str
    rate: float
    stderr: float
    interval: tuple[float, float]
    per_hour: float
    hits: int
    n: int
    ess: float
    seconds: float

    @classmethod
    def of(cls, hit: Any, weights: Any = None, *, event: str = "", seconds: float = float("nan")) -> Estimate:
        """The estimate from each scene's ``hit`` (whether the event happened) and likelihood-ratio
        ``weights`` (default 1: natural draws): ``mean(w 1[hit])``, unbiased whatever the tilt
        that drew the scenes. Batches combine by concatenating their hits and weights."""
        hit = np.asarray(hit, dtype=bool).ravel()
        n = len(hit)
        w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)
        if w.shape != (n,) or not np.all(np.isfinite(w) & (w >= 0)):
            raise InvalidInputError(f"weights must be {n} finite numbers >= 0, one per scene")
        if n == 0:
            raise InvalidInputError("no scenes to estimate a rate from")
        x = w * hit
        rate = float(x.mean())
        se = float(x.std(ddof=1) / math.sqrt(n)) if n > 1 else math.inf
        ess = float(w.sum() ** 2 / np.sum(w * w)) if np.any(w > 0) else 0.0
        per_hour = rate * 3600.0 / seconds if seconds > 0 else float("nan")
        interval = (max(rate - 1.96 * se, 0.0), rate + 1.96 * se)
        return cls(event, rate, se, interval, per_hour, int(hit.sum()), n, ess, float(seconds))

    @property
    def acceleration(self) -> float:
        """How many natural scenes crude Monte Carlo would need for this standard error, per scene
        this estimate took: ``rate (1 − rate) / (stderr² n)``. About 1 for natural draws ((n − 1) /
        n exactly); above 1 where a tilt helped, below 1 where its weights' spread cost more than
        it drew the event more often (``docs/criticality.md``). NaN without a hit or a standard
        error; ``inf`` for a standard error of 0 (every weighted hit the same)."""
        if not (self.rate > 0 and math.isfinite(self.stderr)):
            return math.nan
        if self.stderr == 0:
            return math.inf
        return self.rate * (1.0 - self.rate) / (self.stderr**2 * self.n)

    def __str__(self) -> str:
        lo, hi = self.interval
        return (
            f"{self.event}: {self.rate:.4g} a scene (95 % interval {lo:.4g} to {hi:.4g}; {self.per_hour:.4g} an hour "
            f"of {self.seconds:g} s scenes), {self.hits} of {self.n} scenes, effective sample size {self.ess:.1f}, "
            f"{self.acceleration:.3g}x crude Monte Carlo's scenes for this error"
        )


def estimate(scenes: Any, event: Any, *, size: Any = None, weights: Any = None, measures: Any = None) -> Estimate:
    """The natural rate of ``event`` (:class:`Event` or its text) from ``scenes`` drawn with
    likelihood-ratio ``weights`` against the natural generator (default: the scenes' own, else
    1: natural draws): ``mean(w 1[event])``, unbiased whatever the tilt that drew them.
    ``measures``: the scenes' :meth:`Criticality.per_scene` when already computed (against the
    ego for an ego event), so they are not measured twice."""
    ev = Event.parse(event)
    if measures is None:
        measures = criticality(scenes, size=size, ego=True if ev.ego else None).per_scene()
    w = getattr(scenes, "weights", None) if weights is None else weights
    sims = getattr(scenes, "simulations", scenes)
    seconds = float(sims[0].steps * sims[0].dt) if len(sims) and hasattr(sims[0], "steps") else float("nan")
    return Estimate.of(ev.happened(measures), w, event=str(ev), seconds=seconds)


@dataclass(frozen=True)
class RecordedScene:
    """A window of recorded frames as a scene: ``positions``, ``velocities`` (times, vehicles,
    2), ``in_roi`` (times, vehicles: the vehicle is in that frame), its ``tracks`` (vehicles,),
    ``dt`` and ``headings`` (times, vehicles: the frames' ``prev_heading``, the heading each
    vehicle last moved with, NaN where not known; ``None`` when the frames carry none): a
    vehicle standing through the window faces it, not +x."""

    positions: np.ndarray
    velocities: np.ndarray
    in_roi: np.ndarray
    tracks: np.ndarray
    dt: float
    headings: np.ndarray | None = None


def recorded_scenes(
    frames: Any, steps: int, *, dt: float | None = None, stride: int | None = None
) -> list[RecordedScene]:
    """Recorded frames as scenes of ``steps + 1`` times each, a scene starting every ``stride``
    frames (default ``steps + 1``: scenes side by side). A frame's id is its time when numeric
    (frames made by :func:`dpgp.make_frames`); a scene ends before a frame that does not lie on its
    time grid (``dt`` apart: a gap or another recording). Vehicles are followed by their track
    ids; frames without tracks give scenes of one frame each."""
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 0:
        raise InvalidInputError(f"steps must be a whole number >= 0, got {steps!r}")
    step = dt if dt is not None else getattr(frames.summary, "dt", None)
    if frames.tracks is None:
        steps, step = 0, 1.0 if step is None else step
    if step is None or not (math.isfinite(float(step)) and float(step) > 0):
        raise InvalidInputError("dt: the frames' time step in seconds is not known from them; pass dt=")
    step = float(step)
    stride = steps + 1 if stride is None else int(stride)
    if stride < 1:
        raise InvalidInputError(f"stride must be >= 1, got {stride!r}")
    ids = np.asarray(frames.ids)
    times = ids.astype(np.float64) if ids.dtype.kind in "iuf" else np.arange(len(frames)) * step
    out = []
    for i in range(0, len(frames), stride):
        k = np.rint((times[i : i + steps + 1] - times[i]) / step)
        on = np.abs(times[i : i + steps + 1] - times[i] - k * step) <= 1e-6 * step
        keep = np.cumprod(on & (k == np.arange(len(k)))).astype(bool)  # consecutive grid times
        n = int(keep.sum())
        rows = [np.arange(frames.offsets[i + j], frames.offsets[i + j + 1]) for j in range(n)]
        track = frames.tracks[np.concatenate(rows)] if frames.tracks is not None else np.arange(len(rows[0]))
        cols, col_of = np.unique(track, return_inverse=True)
        pos = np.zeros((n, len(cols), 2))
        vel = np.zeros((n, len(cols), 2))
        inside = np.zeros((n, len(cols)), dtype=bool)
        t_of = np.repeat(np.arange(n), [len(r) for r in rows])
        all_rows = np.concatenate(rows)
        pos[t_of, col_of] = frames.xy[all_rows]
        vel[t_of, col_of] = frames.v[all_rows]
        inside[t_of, col_of] = True
        heads = None
        if frames.prev_heading is not None:
            heads = np.full((n, len(cols)), np.nan)
            heads[t_of, col_of] = frames.prev_heading[all_rows]
        out.append(RecordedScene(pos, vel, inside, cols, step, heads))
    return out


__all__ = [
    "Criticality", "criticality", "compare", "Event", "Estimate", "estimate", "EVENT_MEASURES", "default_size", "recorded_scenes", "RecordedScene", "DEFAULT_SIZE",
    "MIN_SPEED",
]  # fmt: skip
