"""Rollouts as the core records them, cut into :class:`Simulation` results: the part of
simulation that learning the motion model (:mod:`.motion`, which rolls the training frames out to
fit its time constants) and simulating (:mod:`.simulation`) share, so neither imports the other
back."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import _core
from ..gp.fitted import FittedPatterns
from .headings import for_core

if TYPE_CHECKING:
    import pandas as pd


@dataclass(frozen=True, eq=False)
class Simulation:
    """A rollout: ``steps + 1`` recorded times of ``l`` vehicles.

    ``positions`` and ``velocities`` have shape ``(steps + 1, l, 2)``; ``t`` (``steps + 1``,) is
    in seconds from the start; ``in_roi`` and ``low_data`` are ``(steps + 1, l)`` booleans. A
    vehicle's velocity at a time is the one it moves with from there (RK4: the field at its
    position); once it has left the ROI it stands at its first position outside with velocity 0.
    """

    positions: np.ndarray
    velocities: np.ndarray
    t: np.ndarray
    in_roi: np.ndarray
    low_data: np.ndarray
    pattern: int
    method: str
    stochastic: bool
    roi: tuple[float, float, float, float]
    #: "field" (the paper's rollout), "relaxed" or "interactive" (:data:`DYNAMICS`)
    dynamics: str = "field"
    #: interactive rollouts: each vehicle's driver state after the last step, ``(l, 2)`` (its
    #: desired velocity, or heading and desired speed when it steers), to continue it
    drivers: np.ndarray | None = None
    #: generated scenes of steering vehicles: each vehicle's heading (radians) at each time,
    #: ``(steps + 1, l)``, NaN where not there: a standing vehicle's velocity (0) has none, and
    #: criticality measures turn its rectangle with this
    headings: np.ndarray | None = None

    @property
    def steps(self) -> int:
        return len(self.t) - 1

    @property
    def n_vehicles(self) -> int:
        return int(self.positions.shape[1])

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0]) if len(self.t) > 1 else float("nan")

    def to_pandas(self) -> pd.DataFrame:
        """One row per time and vehicle: ``step, t, vehicle, x, y, vx, vy, in_roi, low_data``."""
        import pandas as pd

        T, l = self.in_roi.shape
        return pd.DataFrame(
            {
                "step": np.repeat(np.arange(T), l),
                "t": np.repeat(self.t, l),
                "vehicle": np.tile(np.arange(l), T),
                "x": self.positions[..., 0].ravel(),
                "y": self.positions[..., 1].ravel(),
                "vx": self.velocities[..., 0].ravel(),
                "vy": self.velocities[..., 1].ravel(),
                "in_roi": self.in_roi.ravel(),
                "low_data": self.low_data.ravel(),
            }
        )

    def __repr__(self) -> str:
        mode = "stochastic" if self.stochastic else "mean"
        return (
            f"Simulation(pattern {self.pattern}, {self.n_vehicles} vehicles, {self.steps} {self.method} steps "
            f"of {self.dt:g} s, {mode}; {int(self.in_roi[-1].sum())} still in the ROI, "
            f"{int(self.low_data.any(axis=0).sum())} entered low-data regions)"
        )


def motion_records(patterns: Any, dynamics: str, motion: Any, recorded: bool = False) -> np.ndarray:
    """(len(patterns), MOTION_FIELDS): each rollout's residual model and interaction rule, from
    ``motion`` (a :class:`dpgp.generate.motion.MotionModel`); ``recorded``: rollouts of recorded
    frames (their own time constant)."""
    rec = {
        int(k): motion.record(int(k), interaction=dynamics == "interactive", recorded=recorded)
        for k in np.unique(patterns)
    }
    return np.array([rec[int(k)] for k in patterns], dtype=np.float64).reshape(len(patterns), -1)


def split(pos: np.ndarray, vel: np.ndarray, inside: np.ndarray, low: np.ndarray, sizes: Any, patterns: list[int], *,
          steps: int, dt: float, stochastic: bool, roi: Any, dynamics: str, method: str = "euler",
          headings: np.ndarray | None = None) -> list[Simulation]:  # fmt: skip
    """The core's concatenated time-major arrays cut into one :class:`Simulation` per rollout
    (``headings``, the steering vehicles': kept where any is known)."""
    t = np.arange(steps + 1) * float(dt)
    out, row = [], 0
    for i, l in enumerate(sizes):
        l = int(l)
        sl = slice(row, row + (steps + 1) * l)
        row += (steps + 1) * l
        out.append(
            Simulation(
                positions=pos[sl].reshape(steps + 1, l, 2),
                velocities=vel[sl].reshape(steps + 1, l, 2),
                t=t,
                in_roi=inside[sl].reshape(steps + 1, l),
                low_data=low[sl].reshape(steps + 1, l),
                pattern=int(patterns[i]),
                method=method,
                stochastic=stochastic,
                roi=tuple(float(v) for v in roi),  # type: ignore[arg-type]
                dynamics=dynamics,
                headings=None
                if headings is None or np.isnan(headings[sl]).all()
                else headings[sl].reshape(steps + 1, l),
            )
        )
    return out


def motion_rollouts(
    fit: FittedPatterns, patterns: list[int], starts: list[np.ndarray], velocities: list[np.ndarray], *,
    steps: int, dt: float, seeds: list[int] | None, roi: Any, low_data_threshold: float | None, dynamics: str,
    motion: Any, recorded: bool = False, drivers: list[np.ndarray] | None = None, support: bool = False,
    mixtures: list[list[tuple[int, float]]] | None = None, renew: bool = False,
    stops: list[list[tuple[float, float, float, float]]] | None = None,
    free_speeds: tuple[float, float, float, np.ndarray] | None = None, headings: list[np.ndarray] | None = None,
) -> list[Simulation]:  # fmt: skip
    """Rollouts by the residual model ``motion`` (a :class:`dpgp.generate.motion.MotionModel`)
    and interaction: ``starts[i]`` (l_i, 2) from their own ``velocities[i]`` through pattern
    ``patterns[i]``, run in parallel in the core. ``recorded``: the starts are a recorded frame
    (:meth:`dpgp.generate.motion.MotionModel.record`), not a generated scene. ``drivers[i]``
    (l_i, 2): continue each driver from an earlier rollout's :attr:`Simulation.drivers`.
    ``support``: drivers follow the field only as far as it has data where they are (a pattern's
    zero prior mean is no wish to stand); costs a triangular solve per vehicle and step.
    ``mixtures[i]``: ``(pattern, weight)`` pairs whose fields together replace pattern
    ``patterns[i]``'s (its motion still applies): each pattern's mean counts by its weight and by
    what it knows where the vehicle is (the core's ``MixtureField``; with support). ``renew``:
    the scene's regime changed since ``drivers`` were carried (a signal's next stage), and each
    driver takes up the field where it is, as far as the field knows it (the core's ``Carried``).
    ``stops[i]``: the red stop lines ``(x, y, heading x, heading y)`` in force in rollout ``i``
    (:mod:`.stop_lines`; the core's ``Stop``). ``free_speeds``: every field raised to these
    (:meth:`.free_speeds.FreeSpeeds.core`; the core's ``AtFreeSpeed``). ``headings[i]`` (l_i,):
    a fit over heading starts the vehicles at these previous headings (:mod:`.headings`)."""
    sizes = np.array([len(s) for s in starts], dtype=np.int64)
    offsets = np.r_[0, np.cumsum(sizes)].astype(np.int64)
    cat = lambda a: np.ascontiguousarray(np.concatenate(a) if a else np.zeros((0, 2)), dtype=np.float64)  # noqa: E731
    pos, vel, inside, low, states = _core.motion_rollouts(
        fit.sampler, [int(fit.slots[k]) for k in patterns], cat(starts), cat(velocities), offsets,
        motion_records(patterns, dynamics, motion, recorded), float(dt), int(steps), tuple(roi), seeds, low_data_threshold,
        None if drivers is None else cat(drivers), support,
        None if mixtures is None else [[(int(fit.slots[k]), float(w)) for k, w in m] for m in mixtures], renew, stops,
        free_speeds, for_core(fit, np.concatenate(headings) if headings else None),
    )  # fmt: skip
    sims = split(
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
        dynamics=dynamics,
    )
    return [replace(s, drivers=states[a:b]) for s, a, b in zip(sims, offsets[:-1], offsets[1:])]


__all__ = ["Simulation", "motion_records", "motion_rollouts", "split"]
