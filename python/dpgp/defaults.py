"""Defaults that hold in any units: what ``noise_var="auto"``, ``length_scale_prior="auto"`` and
``preset="paper"`` resolve to before sampling.

The paper's constants — σ_n² = 1 and a Gamma(10, 1) length-scale prior — were chosen for feet
and ft/s. On data in metres they make the fit worse than ignoring position. The rules here
scale with the data, so that converting units (positions and velocities by a factor ``c``)
scales the resolved values by ``c`` (length scales) and ``c²`` (noise variance), and the fit
gives the same partition.

**Length-scale prior** ``"auto"``: Gamma with the paper's shape 10 and its mean at
:data:`SPACING_MULTIPLE` (2) times the data's *spacing*, the median distance from a vehicle to its
nearest neighbour in the same frame (on NGSIM US-101 the spacing is 17 ft, so the mean is 34 ft
against the paper's 10). The spacing is the distance over which the velocities of different
vehicles in one frame inform each other. The multiple was chosen by held-out score
(``benches/evaluate.py``, 20 sweeps): against a mean of one spacing it gains 1.03 nats per
vehicle on Peachtree and 0.23 on Zara and loses 0.11 on US-101 and 0.03 on ETH. Data with too
few multi-vehicle frames fall back to ``sqrt(area / vehicles per frame)`` of the positions'
bounding box.

**Noise variance** ``"auto"``: one global σ_n² chosen by held-out score before sampling, the
criterion the model is judged by (:mod:`dpgp.evaluate`). :data:`PILOT_FRAMES` frames spread
evenly over the training frames are split in time, 70/30; for each σ_n² of a grid
(:data:`NOISE_GRID` times the mean velocity variance, a factor √10 apart), a short pilot
(:data:`PILOT_SWEEPS` map sweeps, the resolved length-scale prior) is fitted to the first part
and scores the velocities of the second (``score_samples(positions=False)``); the best grid
point is refined by a parabola through it and its neighbours in log σ_n².

Estimates by marginal likelihood were measured and rejected. σ_n² is the spread of a
pattern's velocities about its field between the frames of the pattern. Local GPs on single
frames or on runs of consecutive frames see only the noise within an instant, far below that
(and collapse to 0 where consecutive frames repeat the same vehicles): on the synthetic highway
(true σ_n² = 0.49) they gave 0.03–0.05 and 29 patterns for 3. One GP over frames pooled from
the whole recording counts the differences between patterns as noise (9.1 on the synthetic
intersection: 2 patterns for 4). Re-estimating σ_n² from a pilot's partition recovers the truth
on synthetic data but runs away to 0 on real data (each smaller σ_n² splits the patterns
further: US-101 7.7 → 0.02 (ft/s)² in 8 rounds). Every step is unit-free: the pilots run in the
data's units with unit-free settings, and the grid is relative to the velocity variance.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Callable

import numpy as np

from .exceptions import InvalidInputError
from .frames import Frames
from .gp import _pair

PRESETS = ("paper",)
PAPER = {"length_scale_prior": (10.0, 1.0), "noise_var": 1.0, "assignment": "map"}

LENGTH_SCALE_SHAPE = 10.0  # the paper's shape: the prior's CV is 1/sqrt(10) = 0.32
SPACING_MULTIPLE = 2.0  # the prior's mean, in vehicle spacings
PILOT_FRAMES = 80  # frames of the pilots, spread evenly over the training frames
PILOT_SWEEPS = 4  # map sweeps of each pilot fit
NOISE_GRID = tuple(10.0 ** np.arange(-3.5, -0.4, 0.5))  # times the mean velocity variance


@dataclass(frozen=True)
class Resolved:
    """The settings a fit runs with, and where each came from (``"auto"``, ``"paper"``, ``"user"``)."""

    assignment: str
    noise_var: float
    length_scale_prior: tuple[float, float]
    noise_var_source: str
    length_scale_prior_source: str
    spacing: float | None = None  # what the auto length-scale prior was set from
    noise_scores: tuple[tuple[float, float], ...] | None = None  # (σ_n², pilot held-out score) per grid point

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def check_preset(preset: Any) -> None:
    if preset is not None and preset not in PRESETS:
        raise InvalidInputError(f"preset must be None or one of {PRESETS}, got {preset!r}")


def resolve(
    frames: Frames,
    *,
    preset: str | None,
    assignment: str,
    noise_var: Any,
    length_scale_prior: Any,
    signal_var: Any = None,
    mean: Any = None,
    pilot: Pilot | None = None,
) -> Resolved:
    """Resolve ``"auto"`` settings against the training ``frames``. An explicit number always
    wins; ``preset="paper"`` stands in for ``"auto"`` and sets map assignment."""
    check_preset(preset)
    paper = preset == "paper"
    assignment = PAPER["assignment"] if paper else assignment
    spacing = None
    if isinstance(length_scale_prior, str):
        if length_scale_prior != "auto":
            raise InvalidInputError(f"length_scale_prior must be 'auto' or (shape, scale), got {length_scale_prior!r}")
        if paper:
            prior, prior_source = PAPER["length_scale_prior"], "paper"
        else:
            spacing = vehicle_spacing(frames)
            prior, prior_source = (LENGTH_SCALE_SHAPE, SPACING_MULTIPLE * spacing / LENGTH_SCALE_SHAPE), "auto"
    else:
        prior, prior_source = _gamma("length_scale_prior", length_scale_prior), "user"
    if isinstance(noise_var, str):
        if noise_var != "auto":
            raise InvalidInputError(f"noise_var must be 'auto' or a positive number, got {noise_var!r}")
        if paper:
            sn2, noise_source = float(PAPER["noise_var"]), "paper"
        else:
            if pilot is None:
                raise InvalidInputError("noise_var='auto' needs a pilot fit (DPGP.fit provides one); pass a number")
            sv, _ = _moments(frames, signal_var, mean)
            sn2, trace = estimate_noise_var(frames, sv, prior, pilot)
            noise_source = "auto"
    else:
        sn2, noise_source = _positive("noise_var", noise_var), "user"
    return Resolved(assignment, sn2, prior, noise_source, prior_source, spacing, tuple(trace) if noise_source == "auto" else None)


# --- length-scale prior ------------------------------------------------------------------------
def vehicle_spacing(frames: Frames, min_pairs: int = 20) -> float:
    """Median distance from a vehicle to its nearest neighbour in the same frame; with fewer
    than ``min_pairs`` such vehicles, ``sqrt(bounding-box area / mean vehicles per frame)``."""
    nearest = []
    for a, b in zip(frames.offsets[:-1], frames.offsets[1:]):
        if b - a < 2:
            continue
        xy = frames.xy[a:b]
        d2 = ((xy[:, None, :] - xy[None, :, :]) ** 2).sum(axis=-1)
        np.fill_diagonal(d2, np.inf)
        nearest.append(d2.min(axis=1))
    if nearest and sum(len(n) for n in nearest) >= min_pairs:
        spacing = float(np.median(np.sqrt(np.concatenate(nearest))))
        if spacing > 0:
            return spacing
    x0, x1, y0, y1 = frames.bounds()
    area = max(x1 - x0, 0.0) * max(y1 - y0, 0.0)
    if area <= 0:
        area = max(x1 - x0, y1 - y0, 0.0) ** 2
    if area <= 0:
        raise InvalidInputError("every vehicle is at the same position: no length scale can be set from the data; pass length_scale_prior=")
    return float(np.sqrt(area / frames.sizes.mean()))


# --- noise variance ----------------------------------------------------------------------------
Pilot = Callable[[Frames, Frames, float, "tuple[float, float]"], float]
"""``pilot(train, test, noise_var, length_scale_prior) -> held-out log density`` (summed over the
test frames' velocities) of a short fit to ``train`` with those settings. The estimator provides
it, so that this module needs no estimator."""


def spread(frames: Frames, n: int) -> Frames:
    """``n`` frames spread evenly over ``frames`` (all of them if there are fewer)."""
    if len(frames) <= n:
        return frames
    return frames[np.unique(np.linspace(0, len(frames) - 1, n).round().astype(int))]


def estimate_noise_var(
    frames: Frames, signal_var: tuple[float, float], length_scale_prior: tuple[float, float], pilot: Pilot
) -> tuple[float, list[tuple[float, float]]]:
    """σ_n² by the held-out rule of this module's docstring, and the ``(σ_n², score)`` of each
    grid point."""
    sub = spread(frames, PILOT_FRAMES)
    if len(sub) < 4:
        raise InvalidInputError(f"noise_var='auto' needs at least 4 training frames, got {len(sub)}; pass a number")
    cut = int(round(0.7 * len(sub)))
    train, test = sub[:cut], sub[cut:]
    v_scale = float(np.mean(signal_var))
    grid = np.asarray(NOISE_GRID) * v_scale
    scores = np.array([pilot(train, test, float(g), length_scale_prior) for g in grid])
    return refine_grid(grid, scores), [(float(g), float(s)) for g, s in zip(grid, scores)]


def refine_grid(grid: np.ndarray, scores: np.ndarray) -> float:
    """The maximiser of a parabola in log(grid) through the best point and its two neighbours
    (the best point itself at an end of the grid or where the parabola does not curve down)."""
    i = int(np.nanargmax(np.where(np.isfinite(scores), scores, -np.inf)))
    if i == 0 or i == len(grid) - 1 or not np.all(np.isfinite(scores[i - 1 : i + 2])):
        return float(grid[i])
    x = np.log(grid[i - 1 : i + 2])
    y = scores[i - 1 : i + 2]
    h = x[1] - x[0]
    curvature = y[0] - 2 * y[1] + y[2]
    if curvature >= 0:
        return float(grid[i])
    offset = 0.5 * h * (y[0] - y[2]) / curvature  # vertex of the parabola, within half a step
    return float(np.exp(x[1] + np.clip(offset, -h / 2, h / 2)))


# --- helpers -----------------------------------------------------------------------------------
def _moments(frames: Frames, signal_var: Any, mean: Any) -> tuple[tuple[float, float], tuple[float, float]]:
    sv = tuple(frames.v.var(axis=0)) if signal_var is None else _pair("signal_var", signal_var)
    mu = tuple(frames.v.mean(axis=0)) if mean is None else _pair("mean", mean)
    if min(sv) <= 0:
        raise InvalidInputError(f"the training velocities have zero variance in an output ({sv}); pass signal_var= and noise_var=")
    return (float(sv[0]), float(sv[1])), (float(mu[0]), float(mu[1]))


def _positive(name: str, value: Any) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be 'auto' or a positive number, got {value!r}") from None
    if not (np.isfinite(x) and x > 0):
        raise InvalidInputError(f"{name} must be 'auto' or a positive number, got {value!r}")
    return x


def _gamma(name: str, value: Any) -> tuple[float, float]:
    a, b = _pair(name, value)
    if not (np.isfinite(a) and np.isfinite(b) and a > 0 and b > 0):
        raise InvalidInputError(f"{name} must be 'auto' or a Gamma (shape, scale) with both positive, got {value!r}")
    return (a, b)


__all__ = [
    "Resolved", "resolve", "vehicle_spacing", "estimate_noise_var", "refine_grid", "spread", "Pilot",
    "PAPER", "PRESETS",
]  # fmt: skip
