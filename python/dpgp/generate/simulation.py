"""Simulating the vehicles of a frame forward through a fitted motion pattern
(docs/guide/generating.md; the rules: docs/generation.md).

Each vehicle moves with the pattern's posterior mean velocity at its position (or, with
``stochastic=True``, with velocities drawn jointly for all moving vehicles from the pattern's
latent posterior at every step), integrated by forward Euler (the paper's) or RK4 in the Rust
core. A vehicle that leaves the region of interest stops there. Steps where a vehicle is where
the pattern has little data — its posterior variance above ``low_data_threshold`` times the prior
variance, in either output — are flagged, because the field there is mostly the prior (the paper
notes that extrapolated fields give unreasonable trajectories).

In stochastic mode the draw at a step's start positions is held over the step: Euler moves with
it; RK4 adds its deviation from the mean to every stage (so RK4 integrates the mean field
accurately and the noise enters as in Euler-Maruyama). Draws at successive steps are
independent given the positions; they are joint across the vehicles of one step.

With ``dynamics="interactive"`` (the default) or ``"relaxed"``, a rollout starts from each
vehicle's own velocity (the field's mean where the frame has none) and relaxes toward the field
by the residual model of :mod:`dpgp.motion` (``stochastic``: with its noise, seeded); it
integrates by forward Euler only. ``dynamics="field"`` is the paper's rollout described above.
See ``docs/generation.md``.

Cost: following the mean is ``n m`` per step for a pattern of ``n`` observations and ``m``
moving vehicles (``M m`` for a reduced-rank pattern of ``M`` basis functions). The stochastic
draws need the posterior covariance, ``n² m`` (``M² m``) per step. The low-data flags need it only
where a cheap exact bound (the variance given a vehicle's nearest training points, never below
the full one) cannot rule a flag out; pass ``low_data_threshold=None`` to skip them.

Limits: one call records at most :data:`MAX_ROWS` (2·10⁷) rows, ``(steps + 1) × vehicles``
summed over its rollouts (about 1-2 GB); a larger request is an ``InvalidInputError`` raised
before anything is allocated. Simulate longer rollouts in pieces, each starting where the last
ended.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from .. import _core
from .._arrays import as_float_array, check_finite
from .._constants import LOW_DATA_THRESHOLD
from .._validate import check_roi, real_number
from ..data.frames import Frame, Frames
from ..exceptions import InvalidInputError, ShapeError
from ..gp.fitted import DEFAULT_DT, FittedPatterns, as_fitted, frames_dt, frames_roi
from .headings import check_max_curvature, for_core, heading_speed, start_headings
from .motion import field_means, motion_model
from .rollout import Simulation, motion_rollouts, split
from .rollout import motion_records as motion_records  # re-exported: its home before rollout.py

if TYPE_CHECKING:
    pass


#: Most rows ((steps + 1) x vehicles, summed over rollouts) one call may record. A row costs
#: about 50 bytes for one rollout and up to 100 while many are joined, so this is 1-2 GB; a
#: larger request (say steps=2e8) is refused up front, because the core cannot recover from a
#: failed allocation (it aborts the interpreter). Simulate in pieces for longer rollouts.
MAX_ROWS = 20_000_000

_METHODS = ("euler", "rk4")
#: How vehicles move. ``"interactive"`` (the default; ``dynamics=None`` is it, or ``"field"``
#: with ``method="rk4"``): the field is each vehicle's desired
#: velocity, its actual velocity deviates from it by an Ornstein–Uhlenbeck residual learned from
#: the training tracks (:mod:`dpgp.motion`), and vehicles keep their gaps (IDM behind a leader)
#: and a personal distance. ``"relaxed"``: the same without interaction. ``"field"``: the
#: paper's rollout — every vehicle moves with the field itself (bitwise today's rollouts).
DYNAMICS = ("interactive", "relaxed", "field")


def default_dt(model: Any) -> float:
    """The training frames' time step (``make_frames`` records it), else :data:`DEFAULT_DT`;
    ``model`` a fitted estimator or its :class:`~dpgp.fitted.FittedPatterns`."""
    return frames_dt(model.frames if isinstance(model, FittedPatterns) else model.frames_)


def default_roi(model: Any) -> tuple[float, float, float, float]:
    """The ROI the training frames were cropped to, else their bounding box; for a fitted model,
    an axis of zero width widened (:attr:`FittedPatterns.roi`)."""
    if isinstance(model, FittedPatterns) or hasattr(model, "_fitted"):
        return as_fitted(model).roi
    return frames_roi(model.frames_)


def _check(steps: Any, method: Any, dt: Any, low_data_threshold: Any) -> tuple[int, str, float | None]:
    if isinstance(steps, (bool, np.bool_)) or not isinstance(steps, (int, np.integer)) or steps < 0:
        raise InvalidInputError(f"steps must be a whole number >= 0, got {steps!r}")
    if method not in _METHODS:
        raise InvalidInputError(f"method must be one of {_METHODS}, got {method!r}")
    step = real_number("dt", dt)
    if not (np.isfinite(step) and step > 0):
        raise InvalidInputError(f"dt must be a positive number of seconds, got {dt!r}")
    if not np.isfinite(step * float(steps)):  # the recorded times t = 0, dt, ..., steps * dt
        raise InvalidInputError(f"steps * dt must be a finite time, got {steps} steps of {dt!r} s; use a smaller dt")
    thr = None if low_data_threshold is None else real_number("low_data_threshold", low_data_threshold)
    if thr is not None and not (np.isfinite(thr) and thr >= 0):
        raise InvalidInputError(
            f"low_data_threshold must be >= 0 (a fraction of the prior variance), got {low_data_threshold!r}"
        )
    return int(steps), method, thr


def _check_rows(rows: int, what: str, fix: str = "ask for fewer steps or vehicles, or simulate in pieces") -> None:
    """Refuse a rollout of more than :data:`MAX_ROWS` rows before anything is allocated."""
    if rows > MAX_ROWS:
        raise InvalidInputError(
            f"{what} would record {rows:.3g} rows ((steps + 1) x vehicles), more than the {MAX_ROWS:.0e} one call may hold; {fix}"
        )


def _check_pattern(fit: FittedPatterns, k: Any) -> int:
    if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)) or not 0 <= k < fit.n_patterns:
        raise InvalidInputError(f"pattern must be an index 0..{fit.n_patterns - 1}, got {k!r}")
    return int(k)


def _seeds(seed: Any, n: int) -> list[int]:
    """``n`` 64-bit stream keys: from ``seed`` (reproducible) or fresh entropy (``None``)."""
    if seed is not None and (isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0):
        raise InvalidInputError(f"seed must be a whole number >= 0 or None, got {seed!r}")
    return [int(s) for s in np.random.SeedSequence(seed).generate_state(n, np.uint64)]


def rollouts(
    fit: FittedPatterns,
    patterns: list[int],
    starts: list[np.ndarray],
    *,
    steps: int,
    dt: float,
    method: str,
    seeds: list[int] | None,
    roi: tuple[float, float, float, float],
    low_data_threshold: float | None,
    headings: list[np.ndarray] | None = None,
    max_curvature: float | None = None,
) -> list[Simulation]:
    """Many rollouts in one call into the core (run in parallel): ``starts[i]`` (l_i, 2) through
    pattern ``patterns[i]``, stochastic with ``seeds[i]`` when ``seeds`` is given; a fit over
    heading starts the vehicles at ``headings[i]`` (l_i,) (:mod:`.headings`; ``NaN`` or none:
    unknown); ``max_curvature``: the turning limit of fields over heading (:mod:`.headings`)."""
    _check_rows(int(steps) + 1, f"a time axis of {steps} steps", "ask for fewer steps")  # allocated even for no rollout
    sizes = np.array([len(s) for s in starts], dtype=np.int64)
    offsets = np.r_[0, np.cumsum(sizes)].astype(np.int64)
    start = np.ascontiguousarray(np.concatenate(starts) if starts else np.zeros((0, 2)), dtype=np.float64)
    slots = [int(fit.slots[k]) for k in patterns]
    pos, vel, inside, low = _core.rollouts(
        fit.sampler,
        slots,
        start,
        offsets,
        float(dt),
        int(steps),
        method,
        tuple(roi),  # type: ignore[arg-type]
        seeds,
        low_data_threshold,
        for_core(fit, np.concatenate(headings) if headings else None),
        max_curvature,
    )
    return split(
        pos,
        vel,
        inside,
        low,
        sizes,
        patterns,
        steps=steps,
        dt=dt,
        stochastic=seeds is not None,
        roi=roi,
        dynamics="field",
        method=method,
    )


def check_dynamics(dynamics: Any, method: str) -> str:
    """``dynamics`` checked; ``None`` is ``"interactive"``, or ``"field"`` with ``method="rk4"``
    (RK4 integrates the pure field only)."""
    if dynamics is None:
        return "field" if method == "rk4" else "interactive"
    if dynamics not in DYNAMICS:
        raise InvalidInputError(f"dynamics must be one of {DYNAMICS}, got {dynamics!r}")
    if dynamics != "field" and method != "euler":
        raise InvalidInputError(
            f"method={method!r} integrates the pure field only: pass dynamics='field', or method='euler' for {dynamics!r} dynamics"
        )
    return dynamics


def _start(fit: FittedPatterns, frame: Any) -> tuple[np.ndarray, np.ndarray | None, int | None, np.ndarray]:
    """(positions, velocities or None, training index or None, start headings) of what the user
    passed (:func:`.headings.start_headings`: recorded ones, else of the velocities, else NaN)."""
    xy, v, index, prev = _given(fit, frame)
    return xy, v, index, start_headings(v, prev, heading_speed(fit), len(xy))


def _prev_velocities(fit: FittedPatterns, frame: Any) -> np.ndarray | None:
    """The previous velocities (l, 2) a recorded frame carries (``None``: none, or an array)."""
    if isinstance(frame, (int, np.integer)) and not isinstance(frame, (bool, np.bool_)):
        return fit.frames[int(frame)].prev_v
    if isinstance(frame, Frames):
        frame = frame[0]
    return frame.prev_v if isinstance(frame, Frame) else None


def _given(fit: FittedPatterns, frame: Any) -> tuple[np.ndarray, np.ndarray | None, int | None, np.ndarray | None]:
    if isinstance(frame, (bool, np.bool_)):
        raise InvalidInputError("frame must be a training frame index, a Frame or an array, not a bool")
    if isinstance(frame, (int, np.integer)):
        n = len(fit.frames)
        if not -n <= frame < n:
            raise InvalidInputError(f"frame index {frame} out of range for {n} training frames")
        f = fit.frames[int(frame)]
        return f.xy, f.v, int(frame) % n, f.prev_heading
    if isinstance(frame, Frames):
        if len(frame) != 1:
            raise ShapeError(f"simulate takes one frame, got Frames with {len(frame)}; pass frames[i]")
        frame = frame[0]
    if isinstance(frame, Frame):
        return frame.xy, frame.v, None, frame.prev_heading
    arr = as_float_array("frame", frame.to_numpy() if hasattr(frame, "to_numpy") else frame)
    if arr.ndim != 2 or arr.shape[1] not in (2, 4) or len(arr) == 0:
        raise ShapeError(f"frame as an array must be (l, 2) positions or (l, 4) x, y, vx, vy; got shape {arr.shape}")
    check_finite("frame", arr)
    return (
        np.ascontiguousarray(arr[:, :2]),
        (np.ascontiguousarray(arr[:, 2:]) if arr.shape[1] == 4 else None),
        None,
        None,
    )


def simulate(
    model: Any,
    frame: Any,
    pattern: int | None = None,
    steps: int = 100,
    dt: float | None = None,
    method: str = "euler",
    stochastic: bool = False,
    seed: int | None = None,
    roi: tuple[float, float, float, float] | None = None,
    low_data_threshold: float | None = LOW_DATA_THRESHOLD,
    dynamics: str | None = None,
    max_curvature: float | str | None = None,
) -> Simulation:
    """Roll the vehicles of ``frame`` forward through a pattern; see :meth:`dpgp.DPGP.simulate`.
    ``model``: a :class:`~dpgp.fitted.FittedPatterns` (or a fitted estimator, which hands one down)."""
    fit = as_fitted(model)
    xy, v, index, h = _start(fit, frame)
    if pattern is None:
        if index is not None:
            pattern = int(fit.labels[index])  # a training frame's own assignment
        elif v is not None:
            one = Frames(np.array([0]), np.array([0, len(xy)]), xy, v)
            pattern = int(fit.predict(one, h)[0])
        else:
            raise InvalidInputError(
                "frame has positions only: pass pattern=k (there are no velocities to assign it by)"
            )
    k = _check_pattern(fit, pattern)
    steps, method, thr = _check(steps, method, fit.dt if dt is None else dt, low_data_threshold)
    _check_rows((steps + 1) * len(xy), f"{steps} steps of {len(xy)} vehicle(s)")
    box = fit.roi if roi is None else check_roi(roi)
    dt = fit.dt if dt is None else float(dt)
    dynamics = check_dynamics(dynamics, method)
    kappa = check_max_curvature(max_curvature, fit, dynamics)
    if dynamics != "field":
        if v is None:  # positions only: start on the field
            v = field_means(fit, xy, np.full(len(xy), k), h)
        motion = motion_model(fit)
        driver = motion.recorded_drivers(v, _prev_velocities(fit, frame), dt)
        return motion_rollouts(
            fit, [k], [xy], [v], steps=steps, dt=dt, seeds=_seeds(seed, 1) if stochastic else None, roi=box,
            low_data_threshold=thr, dynamics=dynamics, motion=motion, recorded=True, headings=[h],
            drivers=None if driver is None else [driver],
        )[0]  # fmt: skip
    return rollouts(
        fit,
        [k],
        [xy],
        steps=steps,
        dt=dt,
        method=method,
        seeds=_seeds(seed, 1) if stochastic else None,
        roi=box,
        low_data_threshold=thr,
        headings=[h],
        max_curvature=kappa,
    )[0]


def integrate_affine(
    xy: Any,
    a: Any,
    b: Any = (0.0, 0.0),
    steps: int = 100,
    dt: float = DEFAULT_DT,
    method: str = "euler",
    roi: tuple[float, float, float, float] | None = None,
) -> Simulation:
    """Roll vehicles through the known field ``v(p) = a @ p + b`` with the same integrator as
    :func:`simulate` — constant for ``a = 0``, a rigid rotation for ``a = [[0, -ω], [ω, 0]]`` —
    to check it against exact solutions. ``roi`` ``None``: unbounded."""
    from .._arrays import as_pairs

    steps, method, _ = _check(steps, method, dt, None)
    start = as_pairs("xy", xy)
    _check_rows((steps + 1) * len(start), f"{steps} steps of {len(start)} vehicle(s)")
    roi = None if roi is None else check_roi(roi)
    a = as_float_array("a", a)
    b = as_float_array("b", b)
    if a.shape != (2, 2) or b.shape != (2,):
        raise ShapeError(f"a must be 2x2 and b a pair, got shapes {a.shape} and {b.shape}")
    pos, vel, inside, low = _core.integrate_affine(
        start,
        a.tolist(),
        b.tolist(),
        float(dt),
        steps,
        method,
        None if roi is None else tuple(roi),  # type: ignore[arg-type]
    )
    l = len(start)
    return Simulation(
        positions=pos.reshape(steps + 1, l, 2),
        velocities=vel.reshape(steps + 1, l, 2),
        t=np.arange(steps + 1) * float(dt),
        in_roi=inside.reshape(steps + 1, l),
        low_data=low.reshape(steps + 1, l),
        pattern=-1,
        method=method,
        stochastic=False,
        roi=(-np.inf, np.inf, -np.inf, np.inf) if roi is None else tuple(float(v) for v in roi),  # type: ignore[arg-type]
    )


__all__ = [
    "Simulation",
    "simulate",
    "integrate_affine",
    "default_dt",
    "default_roi",
    "DEFAULT_DT",
    "LOW_DATA_THRESHOLD",
    "MAX_ROWS",
    "DYNAMICS",
]
