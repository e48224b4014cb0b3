"""Closed-form density baselines of :func:`dpgp.evaluate.evaluate`: each a proper density of a
frame's velocities (given whatever it conditions on), fitted by maximum likelihood on the
training frames, so that its per-frame log density is comparable nat for nat with the model's
``score_samples(test, positions=False)``.

- ``position_blind``: an independent Gaussian per velocity component, the same for every vehicle
  wherever it is (:func:`position_blind_scores`).
- ``constant_velocity`` (issue 34): each vehicle's velocity is a Gaussian around its previous
  velocity, ``N(v; prev_v, Σ)``, vehicles independent (:class:`ConstantVelocity`,
  :func:`constant_velocity_scores`). A density that conditions on the previous step (fields over
  heading, ``DPGP(inputs="position+heading")``) must beat this one, not only the position-blind
  one, to show that it learned something beyond "vehicles keep going".

**The spread Σ** is a full 2×2 covariance, the maximum-likelihood estimate with the mean fixed
at the previous velocity: ``Σ = (1/n) Σ_r (v_r − prev_v_r)(v_r − prev_v_r)ᵀ`` over the training
rows that have a previous velocity (not centred: the Gaussian is *around* the previous velocity,
so a mean drift such as braking belongs to the spread). Full rather than diagonal because a
change of velocity is mostly along the vehicle's path (speeding up, braking): on a road that runs
obliquely to the axes that makes the x and y changes correlated, which a diagonal Σ cannot
express; the full Σ also scores the same whatever the orientation of the map's axes, and its one
extra parameter is estimated from thousands of steps.

**Vehicles without a previous velocity** (a track's first grid point, or the first after a gap:
``prev_v`` NaN) get the position-blind density. It is itself fitted by maximum likelihood on the
training frames and defined wherever the position-blind baseline is, so every frame's velocities
have a proper density and no test frame is dropped. (A Gaussian fitted to the training frames'
first appearances only was the alternative; it rests on few rows — none at all where the framing
carries every track in from outside the ROI — and would make the baseline fail on data where the
position-blind one works.) It also nests the baselines: the two differ only on vehicles with a
previous velocity, so ``constant_velocity − position_blind`` is exactly what the previous
velocity is worth to a baseline.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..data.frames import Frames
from ..exceptions import InvalidInputError

#: Σ counts as singular (no spread in some direction) when its smallest eigenvalue is at most this
#: fraction of the training velocities' variance: steps that keep their velocity to round-off.
SINGULAR_SPREAD = 1e-12


def position_blind_scores(train: Frames, test: Frames) -> np.ndarray:
    """Per test frame: Σ over vehicles and components of log N(v; mean, var) of the training
    velocities (maximum-likelihood variance)."""
    return _frame_sums(_position_blind_rows(train, test.v), test)


@dataclass(frozen=True)
class ConstantVelocity:
    """The ``constant_velocity`` density baseline (see the module docstring): ``cov`` (2, 2) the
    maximum-likelihood Σ of ``v − prev_v`` over the ``n_steps`` training rows with a previous
    velocity; ``blind_mean``, ``blind_var`` (2,) the position-blind Gaussian of the vehicles
    without one."""

    cov: np.ndarray
    blind_mean: np.ndarray
    blind_var: np.ndarray
    n_steps: int

    @classmethod
    def fit(cls, train: Frames) -> ConstantVelocity:
        """Fit Σ and the fallback on ``train``; an :class:`~dpgp.InvalidInputError` when the frames
        carry no previous velocities, none of their vehicles has one, or Σ is singular."""
        prev = _prev_v(train, "training")
        mean, var = _blind(train)
        has = ~np.isnan(prev[:, 0])
        n = int(has.sum())
        if n == 0:
            raise InvalidInputError(
                "no training vehicle has a previous velocity (every row is a first appearance); "
                "the constant-velocity baseline cannot be fitted"
            )
        r = train.v[has] - prev[has]
        cov = r.T @ r / n
        eig = np.linalg.eigvalsh(cov)
        if not (np.all(np.isfinite(eig)) and eig[0] > SINGULAR_SPREAD * float(var.sum())):
            raise InvalidInputError(
                f"the training vehicles' velocity changes v - prev_v have no spread in some direction "
                f"(covariance eigenvalues {eig[0]:.3g}, {eig[1]:.3g} over {n} steps): they keep their velocity "
                "exactly, and the constant-velocity density is degenerate"
            )
        return cls(cov, mean, var, n)

    def score_rows(self, test: Frames) -> np.ndarray:
        """Per test row (vehicle): log N(v; prev_v, Σ), or the position-blind log density of v
        where the vehicle has no previous velocity."""
        prev = _prev_v(test, "test")
        has = ~np.isnan(prev[:, 0])
        out = np.empty(test.n_points)
        chol = np.linalg.cholesky(self.cov)
        z = np.linalg.solve(chol, (test.v[has] - prev[has]).T)  # (2, m) whitened changes
        log_det = 2.0 * np.log(np.diag(chol)).sum()
        out[has] = -0.5 * ((z * z).sum(axis=0) + log_det + 2.0 * np.log(2.0 * np.pi))
        out[~has] = _gaussian_rows(test.v[~has], self.blind_mean, self.blind_var)
        return out

    def score_frames(self, test: Frames) -> np.ndarray:
        """Per test frame: the sum of :meth:`score_rows` over its vehicles (independent)."""
        return _frame_sums(self.score_rows(test), test)


def constant_velocity_scores(train: Frames, test: Frames) -> np.ndarray:
    """Per test frame: log density of its velocities under the ``constant_velocity`` baseline
    fitted on ``train`` (:class:`ConstantVelocity`). Both need ``prev_v`` (frames made by
    :func:`dpgp.make_frames` from tracks)."""
    return ConstantVelocity.fit(train).score_frames(test)


def _prev_v(frames: Frames, which: str) -> np.ndarray:
    prev = getattr(frames, "prev_v", None)
    if prev is None:
        raise InvalidInputError(
            f"the {which} frames carry no previous velocities (prev_v), which the constant-velocity baseline "
            "conditions on; frame them with dpgp.make_frames from tracks"
        )
    return np.asarray(prev, dtype=np.float64)


def _blind(train: Frames) -> tuple[np.ndarray, np.ndarray]:
    mu, var = train.v.mean(axis=0), train.v.var(axis=0)
    if np.any(var <= 0):
        raise InvalidInputError(
            "the training velocities have zero variance in a component; the position-blind baseline is undefined"
        )
    return mu, var


def _position_blind_rows(train: Frames, v: np.ndarray) -> np.ndarray:
    mu, var = _blind(train)
    return _gaussian_rows(v, mu, var)


def _gaussian_rows(v: np.ndarray, mu: np.ndarray, var: np.ndarray) -> np.ndarray:
    return -0.5 * (np.log(2 * np.pi * var) + (v - mu) ** 2 / var).sum(axis=1)


def _frame_sums(rows: np.ndarray, frames: Frames) -> np.ndarray:
    return np.add.reduceat(rows, frames.offsets[:-1])


__all__ = ["ConstantVelocity", "constant_velocity_scores", "position_blind_scores", "SINGULAR_SPREAD"]
