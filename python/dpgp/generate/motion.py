"""What generation learns from the training tracks (issue 15; docs/generation.md): how a vehicle's
velocity deviates from its pattern's field over time, how vehicles keep their gaps, and how far
apart a scene's vehicles stand. The Rust core (``rust/core/src/motion.rs``, ``placement.rs``)
applies it; ``docs/generation.md`` explains the rules.

**Residual** (per pattern). A vehicle's desired velocity relaxes toward the posterior mean
field ``m_k`` of its frame's pattern ``k`` as an Ornstein–Uhlenbeck process (``motion.rs``):
time constant ``τ``, stationary spread ``σ``. ``τ`` is chosen to predict the training tracks
best (:func:`time_constants`): training frames are rolled out from each vehicle's own velocity
(matched to its later positions by the track ids :func:`dpgp.make_frames` keeps) under each
``τ`` of :data:`TAU_GRID`, and the one with the least mean displacement error over
:data:`TAU_HORIZON` seconds is kept, per pattern where it has :data:`MIN_PAIRS` recorded
track-steps, else pooled. (A regression of the residual's autocorrelation was tried first and
rejected: the fitted fields are rough at the scale of the spacing between vehicles, so the
residual against them decorrelates within a second, and rollouts that relaxed that fast were
much worse than constant velocity.) A large ``τ`` says the field explains little of where a
vehicle goes next: the rollout then stays close to constant velocity. The spread ``σ`` (per
component) is the root mean square of the pattern's residuals ``v − m_k(x)``. Frames without
track ids give no tracks to follow: ``τ`` is then :data:`DEFAULT_TAU`.

**Agents.** ``"pedestrians"`` when 99% of the training speeds are below
:data:`PEDESTRIAN_SPEED` (data units per second), else ``"vehicles"``.

**Car-following** (vehicles, IDM). In every training frame, a vehicle's leader is the nearest
vehicle ahead along its heading within a corridor of half-width ``lateral`` (a quarter of the
median nearest-neighbour distance). Jam distance ``s0``: the 5th percentile of the gaps
(centre to centre) behind a leader of followers slower than a fifth of the median speed (queues;
all followers when there are too few). Time headway ``T``: the median of ``(gap − s0) / speed``
of followers moving at least 30% of the median speed within ``s0 + 3 s × speed`` of a leader
(car-following rather than free driving), clipped to [0.3, 3] s. Acceleration ``a`` and
comfortable deceleration ``b``: the 90th percentiles of the tracks' speed increases and
decreases per second.

**Personal distance.** Pedestrians: the :data:`SPACING_PERCENTILE` (5th) percentile of
nearest-neighbour distances. Vehicles: the same, at most half the jam distance (a last guard;
IDM keeps the gaps).

**Spacing** (per pattern, for placing a generated scene's vehicles): the 5th percentile of the
nearest-neighbour distances in the pattern's frames (the pooled one for a pattern with fewer
than :data:`MIN_DISTANCES`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import _core
from ..data.frames import Frames
from ..exceptions import DataFormatError
from ..gp.fitted import FittedPatterns
from .rollout import motion_rollouts

MIN_PAIRS = 50  # recorded track-steps for a pattern's own τ
MIN_DISTANCES = 20  # nearest-neighbour distances for a pattern's own spacing
#: The recorded minimum spacing, robustly: this percentile of the nearest-neighbour distances
#: (the closest few percent of recorded pairs are mostly tracking noise: 7% of the Peachtree
#: export's vehicles overlap a neighbour within 2 m, centre to centre)
SPACING_PERCENTILE = 5.0
DEFAULT_TAU = 2.0  # seconds, when the frames carry no track ids
TAU_GRID = np.geomspace(0.25, 32.0, 8)  # time constants tried (s): 0.25, 0.5, ..., 32
TAU_HORIZON = 4.0  # seconds of the training rollouts that choose τ
TAU_FRAMES = 120  # training frames rolled out to choose τ
PEDESTRIAN_SPEED = 5.0  # 99th percentile speed below this (data units per second): pedestrians
AGENTS = ("auto", "vehicles", "pedestrians")
_FORMAT_VERSION = 1
_KIND = {"free": 0, "vehicles": 1, "pedestrians": 2}


@dataclass(frozen=True, eq=False)
class MotionModel:
    """Learned generation parameters: per pattern ``tau`` (K,) seconds, ``sigma`` (K, 2),
    ``pairs`` (K,) recorded track-steps behind each pattern's own τ (0: the pooled one) and
    ``spacing`` (K,); for all, ``agents``, ``personal`` and the IDM ``jam``, ``headway``,
    ``accel``, ``decel``, ``lateral`` (NaN for pedestrians)."""

    agents: str
    tau: np.ndarray
    sigma: np.ndarray
    pairs: np.ndarray
    spacing: np.ndarray
    personal: float
    jam: float = float("nan")
    headway: float = float("nan")
    accel: float = float("nan")
    decel: float = float("nan")
    lateral: float = float("nan")

    def record(self, k: int, interaction: bool = True) -> np.ndarray:
        """Pattern ``k``'s flat record for the core (``motion.rs``: ``MOTION_FIELDS``)."""
        kind = _KIND[self.agents] if interaction else 0
        nan_free = lambda v: 1.0 if not np.isfinite(v) else float(v)  # unused by the rule  # noqa: E731
        return np.array(
            [self.tau[k], self.sigma[k, 0], self.sigma[k, 1], kind, self.personal,
             *(nan_free(v) for v in (self.jam, self.headway, self.accel, self.decel, self.lateral))],
            dtype=np.float64,
        )  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        """Plain lists and numbers (JSON, for the model file). Inverse of :meth:`from_dict`."""
        out: dict[str, Any] = {"version": _FORMAT_VERSION, "agents": self.agents}
        for name in ("tau", "sigma", "pairs", "spacing"):
            out[name] = np.asarray(getattr(self, name)).tolist()
        for name in ("personal", "jam", "headway", "accel", "decel", "lateral"):
            v = float(getattr(self, name))
            out[name] = v if np.isfinite(v) else None
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MotionModel:
        try:
            if int(d.get("version", 1)) > _FORMAT_VERSION:
                raise DataFormatError(f"motion model format {d['version']} is newer than this dpgp reads")
            tau = np.asarray(d["tau"], dtype=np.float64)
            m = cls(
                agents=str(d["agents"]),
                tau=tau,
                sigma=np.asarray(d["sigma"], dtype=np.float64).reshape(len(tau), 2),
                pairs=np.asarray(d["pairs"], dtype=np.int64),
                spacing=np.asarray(d["spacing"], dtype=np.float64),
                **{
                    k: float("nan") if d.get(k) is None else float(d[k])
                    for k in ("personal", "jam", "headway", "accel", "decel", "lateral")
                },
            )
        except (KeyError, TypeError, ValueError) as e:
            raise DataFormatError(f"not a stored motion model ({type(e).__name__}: {e})") from None
        if m.agents not in _KIND or len(m.spacing) != len(tau) or not np.all(tau > 0):
            raise DataFormatError("not a stored motion model: inconsistent fields")
        return m

    def __repr__(self) -> str:
        rule = (
            f"IDM s0={self.jam:.3g} T={self.headway:.2g}s a={self.accel:.3g} b={self.decel:.3g}"
            if self.agents == "vehicles" else f"personal distance {self.personal:.3g}"
        )  # fmt: skip
        return (
            f"MotionModel({self.agents}, {len(self.tau)} patterns, tau {np.median(self.tau):.3g} s (median), "
            f"sigma {np.median(self.sigma):.3g}; {rule})"
        )


def field_means(fit: FittedPatterns, xy: np.ndarray, row_label: np.ndarray) -> np.ndarray:
    """(n, 2): the posterior mean velocity at each position ``xy[i]`` under pattern ``row_label[i]``."""
    order = np.argsort(row_label, kind="stable")
    ks, starts = np.unique(row_label[order], return_index=True)
    offsets = np.r_[starts, len(order)].astype(np.int64)
    xy = np.ascontiguousarray(xy[order])
    means = np.asarray(_core.field_means(fit.sampler, [int(fit.slots[k]) for k in ks], xy, offsets))
    out = np.empty_like(means)
    out[order] = means
    return out


def consecutive_pairs(frames: Frames, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Row indices ``(a, b)``: row ``b`` is the same track as row ``a`` one ``dt`` later."""
    if frames.tracks is None or len(frames) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ids = frames.ids
    scene = np.array([str(i[0]) if isinstance(i, tuple) else "" for i in ids], dtype=object)
    times = np.array([float(i[-1]) if isinstance(i, tuple) else float(i) for i in ids])
    step = np.rint(times / dt).astype(np.int64)
    _, scene_code = np.unique(scene, return_inverse=True)
    # one integer key per (scene, track, step) of every row; a pair is key and key + 1
    rows = np.arange(frames.n_points)
    f = frames.frame_of_row
    track = frames.tracks
    tcode = np.unique(track, return_inverse=True)[1]
    span = int(step.max() - step.min()) + 2
    key = (scene_code[f] * (int(tcode.max()) + 1) + tcode) * span + (step[f] - step.min())
    order = np.argsort(key, kind="stable")
    ks = key[order]
    nxt = np.searchsorted(ks, ks + 1)
    hit = (nxt < len(ks)) & (ks[np.minimum(nxt, len(ks) - 1)] == ks + 1)
    return rows[order][hit], rows[order][nxt[hit]]


def time_constants(fit: FittedPatterns) -> tuple[np.ndarray, np.ndarray]:
    """Per pattern, the residual's time constant that best predicts the training tracks, and how
    many track-steps chose it (0: the pooled choice). From up to :data:`TAU_FRAMES` training
    frames spread in time, every vehicle is rolled out from its own velocity through its frame's
    pattern (mean mode, no interaction) for :data:`TAU_HORIZON` seconds under each ``τ`` of
    :data:`TAU_GRID`; the mean distance to where its track really was, over the steps it was
    recorded, is the error. The pooled ``τ`` minimises the error over all patterns (refined by
    a parabola in ``log τ`` through the best grid point and its neighbours); a pattern with at
    least :data:`MIN_PAIRS` track-steps takes its own minimiser."""
    frames, labels, dt, K = fit.frames, fit.labels, fit.dt, fit.n_patterns
    steps = max(1, int(round(TAU_HORIZON / dt)))
    a, b = consecutive_pairs(frames, dt)
    if len(a) < MIN_PAIRS:
        return np.full(K, DEFAULT_TAU), np.zeros(K, np.int64)
    nxt = np.full(frames.n_points, -1, dtype=np.int64)
    nxt[a] = b
    chosen = np.unique(np.linspace(0, len(frames) - 1, min(TAU_FRAMES, len(frames))).round().astype(np.int64))
    rows = np.concatenate([np.arange(frames.offsets[f], frames.offsets[f + 1]) for f in chosen])
    # truth[h, i]: row of vehicle i's track h steps later (-1: not recorded)
    truth = np.full((steps + 1, len(rows)), -1, dtype=np.int64)
    truth[0] = rows
    for h in range(1, steps + 1):
        prev = truth[h - 1]
        truth[h] = np.where(prev >= 0, nxt[np.maximum(prev, 0)], -1)
    known = truth[1:] >= 0
    if known.sum() < MIN_PAIRS:
        return np.full(K, DEFAULT_TAU), np.zeros(K, np.int64)
    pats = labels[chosen]
    row_pat = np.repeat(pats, frames.sizes[chosen])
    errors = np.zeros((len(TAU_GRID), K))
    counts = np.bincount(row_pat, weights=known.sum(axis=0), minlength=K)
    box = (-1e300, 1e300, -1e300, 1e300)  # vehicles keep moving: their tracks say where they went
    for g, tau in enumerate(TAU_GRID):
        m = MotionModel("vehicles", np.full(K, tau), np.zeros((K, 2)), np.zeros(K, np.int64), np.zeros(K), 1.0)
        sims = motion_rollouts(
            fit, pats.tolist(), [frames.xy[frames.offsets[f] : frames.offsets[f + 1]] for f in chosen],
            [frames.v[frames.offsets[f] : frames.offsets[f + 1]] for f in chosen], steps=steps, dt=dt, seeds=None,
            roi=box, low_data_threshold=None, dynamics="relaxed", motion=m,
        )  # fmt: skip
        pred = np.concatenate([s.positions for s in sims], axis=1)[1:]  # (steps, n, 2)
        dist = np.where(known, np.linalg.norm(pred - frames.xy[np.maximum(truth[1:], 0)], axis=-1), 0.0)
        errors[g] = np.bincount(row_pat, weights=dist.sum(axis=0), minlength=K)
    pooled = _refined(errors.sum(axis=1))
    tau = np.full(K, pooled)
    own = counts >= MIN_PAIRS
    for k in np.flatnonzero(own):
        tau[k] = _refined(errors[:, k])
    return tau, np.where(own, counts, 0).astype(np.int64)


def _refined(err: np.ndarray) -> float:
    """The τ of :data:`TAU_GRID` with the least error, refined by a parabola in log τ."""
    i = int(np.argmin(err))
    x = np.log(TAU_GRID)
    if 0 < i < len(err) - 1:
        y0, y1, y2 = err[i - 1], err[i], err[i + 1]
        den = y0 - 2 * y1 + y2
        if den > 0:
            shift = 0.5 * (y0 - y2) / den  # in grid steps, within (-0.5, 0.5)
            return float(np.exp(x[i] + shift * (x[i + 1] - x[i])))
    return float(TAU_GRID[i])


def nearest_distances(frames: Frames) -> np.ndarray:
    """Per row of frames with 2+ vehicles, the distance to the nearest other vehicle."""
    out = []
    for a, b in zip(frames.offsets[:-1], frames.offsets[1:]):
        if b - a < 2:
            continue
        xy = frames.xy[a:b]
        d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        out.append(d.min(axis=1))
    return np.concatenate(out) if out else np.zeros(0)


def leader_gaps(frames: Frames, lateral: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per vehicle with a leader (nearest ahead along its heading within ``lateral``): the gap
    (centre to centre), its speed and the leader's speed along its heading."""
    gaps, own, lead = [], [], []
    for a, b in zip(frames.offsets[:-1], frames.offsets[1:]):
        if b - a < 2:
            continue
        xy, v = frames.xy[a:b], frames.v[a:b]
        speed = np.hypot(v[:, 0], v[:, 1])
        moving = speed > 0
        e = np.zeros_like(v)
        e[moving] = v[moving] / speed[moving, None]
        d = xy[None, :, :] - xy[:, None, :]  # d[i, j] = x_j - x_i
        along = (d * e[:, None, :]).sum(-1)
        side = np.abs(d[..., 0] * e[:, None, 1] - d[..., 1] * e[:, None, 0])
        ok = (along > 0) & (side <= lateral) & moving[:, None]
        g = np.where(ok, along, np.inf)
        j = g.argmin(axis=1)
        has = np.isfinite(g[np.arange(len(g)), j])
        gaps.append(g[has, j[has]])
        own.append(speed[has])
        lead.append((v[j[has]] * e[has]).sum(-1))
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0)  # noqa: E731
    return cat(gaps), cat(own), cat(lead)


def learn(fit: FittedPatterns, agents: str = "auto") -> MotionModel:
    """Learn a :class:`MotionModel` from a fitted model's training frames (see the module docs)."""
    frames, labels, dt, K = fit.frames, fit.labels, fit.dt, fit.n_patterns
    row_label = np.repeat(labels, frames.sizes)
    resid = frames.v - field_means(fit, frames.xy, row_label)
    tau, pairs = time_constants(fit)
    sigma = np.tile(np.sqrt((resid**2).mean(axis=0)), (K, 1))
    nn_all = nearest_distances(frames)
    spacing = np.full(K, np.percentile(nn_all, SPACING_PERCENTILE) if len(nn_all) else 0.0)
    for k in range(K):
        rows = row_label == k
        if rows.sum() >= 2:
            sigma[k] = np.sqrt((resid[rows] ** 2).mean(axis=0))
        nn = nearest_distances(frames[np.flatnonzero(labels == k)])
        if len(nn) >= MIN_DISTANCES:
            spacing[k] = np.percentile(nn, SPACING_PERCENTILE)
    speed = np.hypot(frames.v[:, 0], frames.v[:, 1])
    if agents not in AGENTS:
        raise ValueError(f"agents must be one of {AGENTS}, got {agents!r}")
    if agents == "auto":
        agents = "pedestrians" if np.percentile(speed, 99) < PEDESTRIAN_SPEED else "vehicles"
    nn_floor = float(np.percentile(nn_all, SPACING_PERCENTILE)) if len(nn_all) else 0.0
    if agents == "pedestrians":
        personal = nn_floor
        return MotionModel(agents, tau, sigma, pairs, spacing, max(personal, 1e-9))
    lateral = 0.25 * float(np.median(nn_all)) if len(nn_all) else 1.0
    gap, u, lead = leader_gaps(frames, lateral)
    med = float(np.median(speed[speed > 0])) if np.any(speed > 0) else 1.0
    slow = gap[u < 0.2 * med]
    jam = float(np.percentile(slow if len(slow) >= 20 else gap, 5)) if len(gap) else 4.0 * lateral
    jam = max(jam, 1e-9)  # duplicated positions give zero gaps; IDM needs a positive jam distance
    follow = (u > 0.3 * med) & (gap < jam + 3.0 * u)
    headway = float(np.clip(np.median((gap[follow] - jam) / u[follow]), 0.3, 3.0)) if follow.any() else 1.5
    accel, decel = _accelerations(frames, *consecutive_pairs(frames, dt), dt, med)
    personal = max(min(nn_floor, 0.5 * jam), 1e-9)
    return MotionModel(agents, tau, sigma, pairs, spacing, personal, jam, headway, accel, decel, max(lateral, 1e-9))


def _accelerations(
    frames: Frames, a: np.ndarray, b: np.ndarray, dt: float, typical_speed: float
) -> tuple[float, float]:
    """90th percentiles of the tracks' speed increases and decreases per second; without
    tracks, a fifth of the typical speed per second for both."""
    default = max(0.2 * typical_speed, 1e-6)
    if len(a) < MIN_PAIRS:
        return default, default
    speed = np.hypot(frames.v[:, 0], frames.v[:, 1])
    dv = (speed[b] - speed[a]) / dt
    up, down = dv[dv > 0], -dv[dv < 0]
    return (
        float(np.percentile(up, 90)) if len(up) >= 10 else default,
        float(np.percentile(down, 90)) if len(down) >= 10 else default,
    )


def motion_model(fit: FittedPatterns, agents: str = "auto") -> MotionModel:
    """The fitted model's :class:`MotionModel`: kept in its cache (and in the model file), else
    learned from its training frames."""
    cached = fit.cache.get("motion")
    if cached is not None and cached[0] is fit.frames and (agents == "auto" or cached[1].agents == agents):
        return cached[1]
    m = learn(fit, agents)
    if agents == "auto":
        fit.cache["motion"] = (fit.frames, m)
    return m


__all__ = [
    "MotionModel",
    "learn",
    "motion_model",
    "time_constants",
    "consecutive_pairs",
    "nearest_distances",
    "DEFAULT_TAU",
]
