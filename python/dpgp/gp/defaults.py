"""Defaults that hold in any units: what ``noise_var="auto"``, ``length_scale_prior="auto"`` and
``preset="paper"`` resolve to before sampling.

The paper's constants — σ_n² = 1 and a Gamma(10, 1) length-scale prior — were chosen for feet
and ft/s. On data in metres they make the fit worse than ignoring position. The rules here
scale with the data, so that converting units (positions and velocities by a factor ``c``)
scales the resolved values by ``c`` (length scales) and ``c²`` (noise variances), and the fit
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

**Noise variance** ``"auto"`` (the default; also ``"per_pattern"``): sampled inside the chain
(``rust/core/src/noise.rs``, docs/inference.md), each pattern its own pair (``noise_var_source``
``"per_pattern"``), slice-sampled on the log scale each sweep under the weakly informative prior
``log(σ_n,η² / σ_η²) ~ N(log 0.1, 2²)`` (:data:`NOISE_PRIOR`), relative to the component's
velocity variance σ_η², so the chain is the same in any units; a new pattern draws its pair from
the prior. The chain starts at the prior's median, ``0.1 σ_η²``. ``pattern_noise_var_`` holds
each pattern's pair; ``noise_var_`` (and ``history_``'s ``noise_var_x``, ``noise_var_y``) the
frame-weighted median of the patterns' pairs, per component.

**Noise variance** ``"global"`` (the default before per-pattern noise was measured better held
out, docs/inference.md): one pair shared by all patterns, sampled the same way
(``noise_var_source`` ``"sampled"``); ``noise_var_`` is the chain's last draw.

**Noise variance** ``"pilot"`` (the earlier default, kept to reproduce its figures): a noise variance per velocity component, σ_n,η² = ρ_η σ_η², a
fraction of the component's signal variance, chosen by held-out score before sampling, the
criterion the model is judged by (:mod:`dpgp.evaluate`). :data:`PILOT_FRAMES` frames spread
evenly over the training frames are split in time, 70/30; a short pilot (:data:`PILOT_SWEEPS`
map sweeps, the resolved length-scale prior) is fitted to the first part and scores the
velocities of the second (``score_samples(positions=False)``). The fractions are found by one
round of coordinate ascent over the grid :data:`NOISE_GRID` (a factor √10 apart): first one ρ
for both components, then ρ_x with ρ_y held there, then ρ_y with ρ_x held; each scan's best grid
point is refined by a parabola through it and its neighbours in log ρ (24 pilots in all).

One noise variance per component, not one shared: along and across a road velocities differ by
orders of magnitude (NGSIM US-101: variances 0.34 and 150 (ft/s)²). A shared σ_n² that suits the
lateral component is far below the longitudinal spread, and the sampler splits the traffic into
hundreds of patterns to explain it (US-101: K ≈ 380 and +0.10 nats per vehicle over a
position-blind Gaussian, 20 sweeps); with σ_n,η² = ρ σ_η² the same fit finds K ≈ 40 and +0.69
nats. The fraction is not always the same for both components: on the synthetic highway the
noise is isotropic (0.49 in both) while the variances are 0.53 and 73, so ρ_x ≈ 0.9 and
ρ_y ≈ 0.007, which the coordinate scans find and one shared ρ cannot.

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

from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .. import _core
from .._constants import TRAIN_FRACTION
from ..data.frames import Frames
from ..exceptions import InvalidInputError
from .exact import _pair

PRESETS = ("paper",)
PAPER: dict[str, Any] = {"length_scale_prior": (10.0, 1.0), "noise_var": (1.0, 1.0), "assignment": "map"}

LENGTH_SCALE_SHAPE = 10.0  # the paper's shape: the prior's CV is 1/sqrt(10) = 0.32
SPACING_MULTIPLE = 2.0  # the prior's mean, in vehicle spacings
PILOT_FRAMES = 80  # frames of the pilots, spread evenly over the training frames
PILOT_SWEEPS = 4  # map sweeps of each pilot fit
NOISE_GRID = tuple(10.0 ** np.arange(-3.5, 0.1, 0.5))  # ρ: noise variance / signal variance, per component
#: Prior of the sampled noise: log(σ_n,η² / σ_η²) ~ N(mean, sd²) (natural log), per component.
NOISE_PRIOR = (float(np.log(0.1)), 2.0)
#: Split–merge moves per sweep (``split_merge="auto"``): chosen by how far a US-101 chain gets in
#: the same seconds (its burn-in outlasts any ESS estimate; 30 and 100 moves tie, 10 lag by ~550
#: nats of log joint) and by held-out spread on ETH and Zara (docs/inference.md).
SPLIT_MERGE_MOVES = 30
#: The sub-cluster sampler's split–merge moves per sweep keep about this many frames' work (at
#: least one move, at most SPLIT_MERGE_MOVES): 30 moves below 3,334 frames, 1 from 100,000.
SUBCLUSTER_MOVE_FRAMES = 100_000


@dataclass(frozen=True)
class Resolved:
    """The settings a fit runs with, and where each came from (``"auto"``, ``"paper"``, ``"user"``)."""

    assignment: str
    noise_var: tuple[float, float]  # per velocity component
    length_scale_prior: tuple[float, float]
    noise_var_source: str
    length_scale_prior_source: str
    spacing: float | None = None  # what the auto length-scale prior was set from
    noise_scores: tuple[tuple[float, ...], ...] | None = None  # (ρ_x, ρ_y, pilot held-out score) per pilot

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
        if noise_var not in ("auto", "per_pattern", "global", "pilot"):
            raise InvalidInputError(
                f"noise_var must be 'auto' (sampled per pattern), 'per_pattern' (the same), 'global' (one pair "
                f"sampled for all patterns), 'pilot', a positive number or a pair of them, got {noise_var!r}"
            )
        if paper and noise_var == "auto":
            sn2, noise_source = PAPER["noise_var"], "paper"
        elif noise_var in ("auto", "per_pattern", "global"):
            sv, _ = _moments(frames, signal_var, mean)
            start = float(np.exp(NOISE_PRIOR[0]))
            sn2 = (start * sv[0], start * sv[1])
            noise_source = "sampled" if noise_var == "global" else "per_pattern"
        else:
            if pilot is None:
                raise InvalidInputError("noise_var='pilot' needs a pilot fit (DPGP.fit provides one); pass a number")
            sv, _ = _moments(frames, signal_var, mean)
            sn2, trace = estimate_noise_var(frames, sv, prior, pilot)
            noise_source = "pilot"
    else:
        sn2, noise_source = _positive_pair("noise_var", noise_var), "user"
    return Resolved(
        assignment, sn2, prior, noise_source, prior_source, spacing, tuple(trace) if noise_source == "pilot" else None
    )


# --- length-scale prior ------------------------------------------------------------------------
def vehicle_spacing(frames: Frames, min_pairs: int = 20) -> float:
    """Median distance from a vehicle to its nearest neighbour in the same frame; with fewer
    than ``min_pairs`` such vehicles, ``sqrt(bounding-box area / mean vehicles per frame)``."""
    nearest = _nearest_neighbour_sq(frames)
    if len(nearest) >= min_pairs:
        spacing = float(np.median(np.sqrt(nearest)))
        if spacing > 0:
            return spacing
    x0, x1, y0, y1 = frames.bounds()
    area = max(x1 - x0, 0.0) * max(y1 - y0, 0.0)
    if area <= 0:
        area = max(x1 - x0, y1 - y0, 0.0) ** 2
    if area <= 0:
        raise InvalidInputError(
            "every vehicle is at the same position: no length scale can be set from the data; pass length_scale_prior="
        )
    return float(np.sqrt(area / frames.sizes.mean()))


def _nearest_neighbour_sq(frames: Frames) -> np.ndarray:
    """Squared distance from every vehicle of a frame of two or more to its nearest neighbour in
    that frame, in row order (the core computes it in parallel: a million frames in a second)."""
    from .. import _core

    return _core.nearest_neighbour_sq(
        np.ascontiguousarray(frames.xy, dtype=np.float64), np.asarray(frames.offsets, dtype=np.int64)
    )


# --- noise variance ----------------------------------------------------------------------------
Pilot = Callable[[Frames, Frames, "tuple[float, float]", "tuple[float, float]"], float]
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
) -> tuple[tuple[float, float], list[tuple[float, float, float]]]:
    """``(σ_n,x², σ_n,y²) = (ρ_x σ_x², ρ_y σ_y²)`` by the held-out rule of this module's
    docstring, and the ``(ρ_x, ρ_y, score)`` of each pilot."""
    sub = spread(frames, PILOT_FRAMES)
    if len(sub) < 4:
        raise InvalidInputError(f"noise_var='auto' needs at least 4 training frames, got {len(sub)}; pass a number")
    cut = int(round(TRAIN_FRACTION * len(sub)))
    train, test = sub[:cut], sub[cut:]
    sv, grid = np.asarray(signal_var, dtype=float), np.asarray(NOISE_GRID)
    trace: list[tuple[float, float, float]] = []

    def scan(fractions: list[tuple[float, float]]) -> np.ndarray:
        scores = []
        for rx, ry in fractions:
            scores.append(pilot(train, test, (float(rx * sv[0]), float(ry * sv[1])), length_scale_prior))
            trace.append((float(rx), float(ry), float(scores[-1])))
        return np.asarray(scores)

    both = refine_grid(grid, scan([(g, g) for g in grid]))
    rx = refine_grid(grid, scan([(g, both) for g in grid]))
    ry = refine_grid(grid, scan([(rx, g) for g in grid]))
    return (float(rx * sv[0]), float(ry * sv[1])), trace


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
        raise InvalidInputError(
            f"the training velocities have zero variance in an output ({sv}); pass signal_var= and noise_var="
        )
    return (float(sv[0]), float(sv[1])), (float(mu[0]), float(mu[1]))


def _positive_pair(name: str, value: Any) -> tuple[float, float]:
    """A positive number (both components) or a pair of them."""
    message = f"{name} must be 'auto', a positive number or a pair (x, y) of them, got {value!r}"
    try:
        x = np.broadcast_to(np.asarray(value, dtype=float), (2,))
    except (TypeError, ValueError):
        raise InvalidInputError(message) from None
    if not (np.all(np.isfinite(x)) and np.all(x > 0)):
        raise InvalidInputError(message)
    return (float(x[0]), float(x[1]))


def _gamma(name: str, value: Any) -> tuple[float, float]:
    """A Gamma (shape, scale) pair, checked by the core's rule (its limits keep the chain's log
    joint finite in double precision; issue 17)."""
    a, b = _pair(name, value)
    _core.check_length_scale_prior((a, b))
    return (a, b)


__all__ = [
    "Resolved", "resolve", "vehicle_spacing", "estimate_noise_var", "refine_grid", "spread", "Pilot",
    "PAPER", "PRESETS", "NOISE_PRIOR", "SPLIT_MERGE_MOVES", "SUBCLUSTER_MOVE_FRAMES",
]  # fmt: skip
