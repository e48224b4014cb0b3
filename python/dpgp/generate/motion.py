"""What generation learns from the training tracks (issue 15; docs/generation.md): how a vehicle's
velocity deviates from its pattern's field over time, how vehicles keep their gaps, and how far
apart a scene's vehicles stand. The Rust core (``rust/core/src/motion.rs``, ``placement.rs``)
applies it; ``docs/generation.md`` explains the rules.

**Residual** (per pattern). A vehicle's desired velocity relaxes toward the posterior mean
field ``m_k`` of its frame's pattern ``k`` as an Ornstein–Uhlenbeck process (``motion.rs``):
time constant ``τ``, stationary spread ``σ``. ``τ`` is the one whose rollouts predict tracks
best (:func:`time_constants`): frames are rolled out from each vehicle's own velocity (matched
to its later positions by the track ids :func:`dpgp.make_frames` keeps) under each ``τ`` of
:data:`TAU_GRID` (0.25 s to ∞, constant velocity), and the one with the least mean displacement
error over :data:`TAU_HORIZON` seconds is kept, per pattern where it has enough track-steps,
else pooled. Two choices are kept:

- ``tau_rollout``, for rollouts of recorded frames (``simulate``): out of sample. The fields
  are conditioned on the first three quarters of the training frames only and frames of the
  last quarter are rolled out as ``simulate`` rolls out a test frame (with interaction,
  :data:`ROLLOUT_DYNAMICS`); per pattern from
  :data:`TAU_PATTERN_STEPS` held-out track-steps. On the frames the fields were fitted to, the
  field has already seen each vehicle's velocity, which biases the choice toward short ``τ``
  (Peachtree: 4.8 s in sample, ∞ held out; test rollouts at 4 s 2.03 against 1.27 ft, constant
  velocity 1.50).
- ``tau``, for generated scenes (``sample_scenarios``, long scenarios): in sample, per pattern
  from :data:`MIN_PAIRS` track-steps. A generated agent moves in the model's own fields, so what
  matters is how its deviation from them decays, not how far the fields can be trusted for an
  unseen vehicle; the held-out ``τ`` (mostly ∞) starves generated agents of the residual's
  innovations (``σ √(1 − ρ²)`` per step): realism ratio 0.53, 0.43, 0.73 on Peachtree, ETH,
  Zara against 0.82, 0.62, 0.79 with this one.

(A regression of the residual's autocorrelation was tried first and rejected: the fitted fields
are rough at the scale of the spacing between vehicles, so the residual against them
decorrelates within a second, and rollouts that relaxed that fast were much worse than constant
velocity.) A large ``τ`` says the field explains little of where a
vehicle goes next: the rollout then stays close to constant velocity. The spread ``σ`` is
given along and across the field's local heading ``e = m_k(x) / |m_k(x)|`` (``sigma_frame =
"heading"``): ``σ_along``, ``σ_across`` are the root mean squares of the pattern's residuals
``v − m_k(x)`` projected on ``e`` and on its normal, over the rows where ``|m_k(x)|`` is at
least ``min_speed`` (:data:`HEADING_SHARE` of the median field speed; slower, the field has no
heading and the core draws an isotropic residual of spread ``√((σ_along² + σ_across²) / 2)``).
Recorded vehicles keep their lane: on the SUMO junction the residual spreads 1.38 m/s along
the heading and 0.53 m/s across it, and an isotropic residual made every generated car's
heading jitter. The across part relaxes with its own time constant ``τ × tau_across_share``
(:data:`TAU_ACROSS_SHARE`): held (∞) for vehicles, whose across offset from the field is the
lane they keep, ``τ`` for pedestrians. Rollouts of recorded frames relax both parts with
``τ_rollout`` (holding a recorded vehicle's across velocity raised the junction's FDE at 4 s
from 6.14 to 6.45 m, relaxed dynamics). Model files written before this keep ``σ`` per x/y component (``sigma_frame =
"xy"``) and are generated with it as before. Frames without track ids give no tracks to
follow: ``τ`` is then :data:`DEFAULT_TAU`.

**Spread profile** (all agents). The residual's spread depends on the field's speed: on the SUMO
junction it is 0.07 m/s along the heading where ``|m| ≈ 0.06`` (queues) and 1.7 m/s where
``|m| ≈ 3``; one spread for both made queued vehicles creep and jitter. :func:`spread_profile`
learns (along, across) factors at :data:`PROFILE_KNOTS` field speeds (bins of equal count,
pooled over patterns); ``sigma[k]`` is then the spread of the residuals divided by the factors
(:func:`heading_spreads`), and the core draws innovations with ``sigma[k] × factor(|m(x)|)``.

**Steering** (vehicles, generated scenes). A vehicle keeps a heading and a desired speed instead
of a residual vector: the speed relaxes toward ``|m(x)|`` as the along residual does (a negative
one stands: vehicles do not reverse), and the heading turns toward the field's with the time
constant ``tau_heading`` (:func:`heading_time_constant`: the one that best predicts the
recorded heading changes from the field's heading one step on; out of sample, :func:`steering`).
The fitted fields are rough at
the scale of a lane (their heading along the recorded SUMO paths changes by 0.5 rad/s at the
90th percentile, the vehicles' by 0.11), so a vehicle that took the field's heading at every
step turned where recorded ones drive straight. It turns only by the part of its angle to the
field's heading beyond a tolerance (:func:`heading_tolerance`, least squared error of the
same prediction, kept where it beats none beyond noise; 0 on the current junction and Peachtree
fits), and a desired speed below the recorded speed
next to a stand (:func:`stand_speed`) stands: the field of a queue is slow, not at rest, and
queued vehicles crept. Vehicles steer only where their recorded headings are not mostly noise
(:data:`STEER_NOISE_SHARE`, :func:`heading_noise_share`: NGSIM US-101's are, 77 % of their step
changes). A generated vehicle starts along the field's heading (where the field is too slow to have one, along its recorded frame's heading). Rollouts of recorded frames do not steer (they keep their own heading and relax with
``τ_rollout``).

**Agents.** ``"pedestrians"`` when 99% of the training speeds are below
:data:`PEDESTRIAN_SPEED` (data units per second), else ``"vehicles"``.

**Car-following** (vehicles, IDM+: the core takes the lesser of IDM's free-road and
interaction terms, so a follower at its desired speed and gap keeps its speed). In every training frame, a vehicle's leader is the nearest
vehicle ahead along its heading within a corridor of half-width ``lateral`` (a quarter of the
median nearest-neighbour distance). Jam distance ``s0``: the 5th percentile of the gaps
(centre to centre) behind a leader of followers slower than a fifth of the median speed (queues;
all followers when there are too few). Time headway ``T``: the median of ``(gap − s0) / speed``
of followers moving at least 30% of the median speed within ``s0 + 3 s × speed`` of a leader
(car-following rather than free driving), clipped to [0.3, 3] s. Acceleration ``a`` and
comfortable deceleration ``b``: the 90th percentiles of the tracks' speed increases and
decreases per second. A free vehicle (no leader) changes speed by IDM's free-road term too,
toward its desired speed and not past it, instead of taking it at once: the residual's
innovations change the wish, not the speed, from one step to the next. In generated scenes the
jam distance is at least the vehicles' recorded length and the corridor's half-width at least
their width (:attr:`MotionModel.bounded`): a leader is any vehicle ahead whose side overlaps one's
own, and no queue stands closer than a length (US-101's generated scenes touched in 14.7 % of
scenes before, 11.9 % after; Peachtree's realism ratio 0.843 before, 0.857 after).

**Personal distance.** Pedestrians: the :data:`SPACING_PERCENTILE` (5th) percentile of
nearest-neighbour distances. Vehicles: the same, at most half the jam distance (a last guard;
IDM keeps the gaps).

**Spacing** (per pattern, for placing a generated scene's vehicles): the 5th percentile of the
nearest-neighbour distances in the pattern's frames (the pooled one for a pattern with fewer
than :data:`MIN_DISTANCES`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np

from .. import _core
from ..data._previous import in_frame_units
from ..data.frames import Frames
from ..exceptions import DataFormatError
from ..gp.fitted import FittedPatterns
from .criticality import default_size
from .headings import carried, heading_speed, start_headings
from .rollout import motion_rollouts

MIN_PAIRS = 50  # recorded track-steps to learn τ, a and b from at all
#: held-out track-steps for a pattern's own τ (fewer: the pooled one). Measured on ETH and Zara
#: (test FDE at 4 s): 50 let patterns pick τ on a handful of pedestrians, 2-5% worse than 200
TAU_PATTERN_STEPS = 200
MIN_DISTANCES = 20  # nearest-neighbour distances for a pattern's own spacing
#: The recorded minimum spacing, robustly: this percentile of the nearest-neighbour distances
#: (the closest few percent of recorded pairs are mostly tracking noise: 7% of the Peachtree
#: export's vehicles overlap a neighbour within 2 m, centre to centre)
SPACING_PERCENTILE = 5.0
DEFAULT_TAU = 2.0  # seconds, when the frames carry no track ids
#: time constants tried (s): 0.25, 0.5, ..., 256, and ∞ (constant velocity)
TAU_GRID = np.r_[np.geomspace(0.25, 256.0, 11), np.inf]
#: the last share of the training frames that chooses τ (fields conditioned on the rest)
TAU_HOLDOUT = 0.25
TAU_HORIZON = 4.0  # seconds of the training rollouts that choose τ
TAU_FRAMES = 120  # training frames rolled out to choose τ
#: how the held-out rollouts that choose ``τ_rollout`` move: as ``simulate`` moves a recorded
#: frame by default. Chosen without interaction (the batched relaxed rollouts, before), the SUMO
#: junction's patterns took τ of 0.25-5 s toward fields that car following already beat, and its
#: test rollouts at 1 s were 1.14x constant velocity (1.02x chosen so; s52 notes)
ROLLOUT_DYNAMICS = "interactive"
PEDESTRIAN_SPEED = 5.0  # 99th percentile speed below this (data units per second): pedestrians
AGENTS = ("auto", "vehicles", "pedestrians")
#: vehicles moving at least this share of the median speed show their heading (learning τ_h)
STEER_SPEED_SHARE = 0.3
#: below this share of the median field speed |m| of the training rows, the field has no heading
#: (isotropic residual). Measured on the SUMO junction (realism ratio, interactive): 0.3 → 0.37,
#: 0.1 → 0.43, 0.02 → 0.46, 0 → 0.47 (queued vehicles stand in slow parts of the field);
#: Peachtree 0.84 and ETH, Zara unchanged at 0.1 and 0.02
HEADING_SHARE = 0.02
#: per kind of agent, the across-heading residual's time constant as a share of τ. Vehicles keep
#: their lane: the across part is a lane's offset from the field, held (∞). Measured (realism
#: ratio, interactive, HEADING_SHARE 0.1; share 1 / 4 / 16 / ∞): SUMO junction 0.26 / 0.32 /
#: 0.37 / 0.43 (0.25: 0.20), Peachtree 0.84 / - / - / 0.84; pedestrians have no lanes (ETH 0.74 against 0.65 at
#: ∞, Zara 0.94 against 0.92): the same τ
TAU_ACROSS_SHARE = {"vehicles": float("inf"), "pedestrians": 1.0}
SIGMA_FRAMES = ("xy", "heading")
_FORMAT_VERSION = 2
#: learn the spread's profile over the field's speed (all agents) and steering (vehicles)
PROFILE = True
STEER = True
#: vehicles steer only where white noise is less than this share of the recorded heading
#: changes (:func:`heading_noise_share`): a noiseless steered heading cannot give the jitter of
#: headings that are mostly noise. Measured (realism ratio, steering / none; s53 notes): US-101
#: linked (share 0.77) 0.790 / 0.895, Peachtree (0.44) 0.837 / 0.781, SUMO left turn linked
#: (0) 0.544 / 0.465
STEER_NOISE_SHARE = 0.5
#: shares of a recorded vehicle's acceleration its driver's desired speed is started from in
#: rollouts of recorded frames (:meth:`MotionModel.recorded_drivers`), chosen out of sample as
#: ``τ_rollout`` is; 0 is a driver that wants its own speed
ACCEL_TRUSTS = np.array([0.0, 0.5, 1.0])
#: the largest share of IDM's maximum acceleration inverted into a desired speed (at 0.9 the
#: desired speed is 1.78 times the current one)
MAX_ACCEL_SHARE = 0.9
#: learn :attr:`MotionModel.accel_trust` (:func:`accel_trust`)
ACCEL_TRUST = True
#: learn the pedestrians' step jitter (:func:`step_jitter`)
JITTER = True
#: learn the pedestrians' personal distance of rollouts of recorded frames
#: (:func:`rollout_personal_distance`) from these shares of the personal distance (0: no rule)
ROLLOUT_PERSONAL = True
PERSONAL_SHARES = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
#: steering tolerances tried (rad, :func:`heading_tolerance`): 0, and 0.01 to 0.64
TOLERANCE_GRID = np.r_[0.0, np.geomspace(0.01, 0.64, 13)]
#: standard errors of the paired per-step gain over δ = 0 that a heading tolerance must reach
TOLERANCE_SE = 2.0
PROFILE_KNOTS = 8  # knots of the spread's profile over the field's speed (motion.rs: PROFILE_KNOTS)
#: the hardest a generated vehicle brakes (m/s²): emergency braking on a dry road, about 0.9 g (SUMO's
#: emergency deceleration of a passenger car). Without it IDM stopped US-101 vehicles from 40 ft/s in
#: one 0.5 s step when a neighbour drifted into their corridor (issue 35)
MAX_BRAKE = 9.0
_KIND = {"free": 0, "vehicles": 1, "pedestrians": 2}


def _size(v: Any) -> tuple[float, float]:
    length, width = (float(x) for x in v)
    return length, width


@dataclass(frozen=True, eq=False)
class MotionModel:
    """Learned generation parameters: per pattern ``tau`` (K,) seconds (generated scenes),
    ``sigma`` (K, 2), ``pairs`` (K,) recorded track-steps behind each pattern's own τ (0: the
    pooled one) and ``spacing`` (K,); for all, ``agents``, ``personal`` and the IDM ``jam``,
    ``headway``, ``accel``, ``decel``, ``lateral`` (NaN for pedestrians). ``tau_rollout`` (K,):
    the time constant of rollouts of recorded frames, chosen out of sample (``None``, in files
    written before it: ``tau``); :attr:`rollout_tau` gives whichever applies.
    ``sigma_frame``: ``"heading"``, ``sigma[k]`` is (along, across) the field's local heading,
    isotropic where the field is slower than ``min_speed``, the across part relaxing with
    ``tau_across_share × τ`` in generated scenes (with ``τ_rollout`` in rollouts of recorded
    frames); ``"xy"`` (files written before it), per x/y component. ``accel_trust``: the share
    of a recorded vehicle's acceleration its driver's desired speed starts from in rollouts of
    recorded frames (:meth:`recorded_drivers`; 0, and in files written before it: its own speed).
    ``size``: the vehicles' (length, width), the recorded median (:attr:`bounded` uses it; ``None``
    for pedestrians, and in files written before it, where :func:`motion_model` supplies it).
    ``brake``: the hardest generated vehicles brake (:data:`MAX_BRAKE` in the frames' length unit;
    NaN for pedestrians, and in files written before it, where :func:`motion_model` supplies it)."""

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
    tau_rollout: np.ndarray | None = None
    sigma_frame: str = "xy"
    min_speed: float = 0.0
    tau_across_share: float = 1.0
    tau_heading: float = float("nan")
    profile: np.ndarray | None = None
    heading_tolerance: float = 0.0
    stand_speed: float = 0.0
    jitter: np.ndarray | None = None
    personal_rollout: float = float("nan")
    accel_trust: float = 0.0
    size: tuple[float, float] | None = None
    brake: float = float("nan")

    @property
    def rollout_tau(self) -> np.ndarray:
        """Per pattern, the time constant of rollouts of recorded frames."""
        return self.tau if self.tau_rollout is None else self.tau_rollout

    @property
    def steers(self) -> bool:
        """Generated vehicles keep a heading and a desired speed (``motion.rs``: steering)."""
        return self.sigma_frame == "heading" and self.tau_heading > 0

    def driver_states(self, v: np.ndarray) -> np.ndarray:
        """The driver states (:attr:`dpgp.generate.rollout.Simulation.drivers`) of agents that
        start moving at ``v`` (n, 2) and want to: heading and speed if they steer, else ``v``."""
        v = np.asarray(v, dtype=np.float64).reshape(-1, 2)
        return np.c_[np.arctan2(v[:, 1], v[:, 0]), np.hypot(v[:, 0], v[:, 1])] if self.steers else v.copy()

    def recorded_drivers(self, v: np.ndarray, prev_v: np.ndarray | None, dt: float) -> np.ndarray | None:
        """The drivers (desired velocities) of a recorded frame's vehicles at ``v`` (n, 2) that
        moved at ``prev_v`` (n, 2; NaN: unknown) one step ``dt`` before; ``None`` (each wants its
        own velocity) without trust, previous velocities or car following. A vehicle accelerating
        by ``a₀`` along its velocity wants more than its speed ``u``: IDM's free-road term
        ``a (1 − (u / u₀)⁴)`` gives ``a₀`` at the desired speed ``u₀ = u (1 − κ a₀ / a)^(−1/4)``,
        ``κ`` :attr:`accel_trust` (a braking vehicle's ``u₀`` is below ``u``), in ``v``'s
        direction. Recorded rollouts do not steer, so a driver is a velocity."""
        if self.accel_trust <= 0 or prev_v is None or self.agents != "vehicles" or not self.accel > 0:
            return None
        v = np.asarray(v, dtype=np.float64).reshape(-1, 2)
        prev_v = np.asarray(prev_v, dtype=np.float64).reshape(-1, 2)
        speed = np.hypot(v[:, 0], v[:, 1])
        known = np.all(np.isfinite(prev_v), axis=1) & (speed > 0)
        a0 = np.zeros(len(v))
        a0[known] = np.einsum("ij,ij->i", v[known] - prev_v[known], v[known]) / speed[known] / dt
        share = np.minimum(self.accel_trust * a0 / self.accel, MAX_ACCEL_SHARE)
        return v * ((1.0 - share) ** -0.25)[:, None]

    @property
    def bounded(self) -> tuple[float, float]:
        """The IDM jam distance and corridor half-width of generated vehicles: the learned ones, at
        least the vehicles' length and width (:attr:`size`). Learned from where recorded vehicles
        stood, they can be less: a leader's centre is then closer than a length (Peachtree's
        queues: 7 ft against 16 ft vehicles), or a vehicle whose side overlaps one's own is no
        leader (US-101: a corridor of 4.2 ft against 5.9 ft wide vehicles), and generated
        vehicles overlap. Rollouts of recorded frames keep the learned ones, with which their time
        constant was chosen."""
        if self.size is None or self.agents != "vehicles":
            return self.jam, self.lateral
        return max(self.jam, self.size[0]), max(self.lateral, self.size[1])

    def _braking(self, recorded: bool) -> tuple[float, float, float]:
        """The core's ``brake``, ``length`` and ``width`` (``motion.rs``: ``Idm``; 0: none)."""
        if recorded or self.agents != "vehicles":
            return 0.0, 0.0, 0.0
        brake = self.brake if np.isfinite(self.brake) and self.brake > 0 else 0.0  # 0: no bound
        return (brake, 0.0, 0.0) if self.size is None else (brake, *self.size)

    def record(self, k: int, interaction: bool = True, recorded: bool = False) -> np.ndarray:
        """Pattern ``k``'s flat record for the core (``motion.rs``: ``MOTION_FIELDS``);
        ``recorded``: for a rollout of a recorded frame (its time constant :attr:`rollout_tau`)."""
        kind = _KIND[self.agents] if interaction else 0
        jam, lateral = (self.jam, self.lateral) if recorded else self.bounded
        personal = self.personal
        if recorded and self.agents == "pedestrians" and np.isfinite(self.personal_rollout):
            # rollouts of recorded frames: the personal distance that predicts recorded tracks
            # best (:func:`rollout_personal_distance`; 0: none)
            personal = self.personal_rollout
            kind = kind if personal > 0 else 0
        nan_free = lambda v: 1.0 if not np.isfinite(v) else float(v)  # unused by the rule  # noqa: E731
        tau = (self.rollout_tau if recorded else self.tau)[k]
        heading = self.sigma_frame == "heading"
        return np.array(
            [tau, self.sigma[k, 0], self.sigma[k, 1], kind, personal if personal > 0 else self.personal,
             *(nan_free(v) for v in (jam, self.headway, self.accel, self.decel, lateral)),
             self.min_speed if heading else -1.0, tau if recorded or not heading else tau * self.tau_across_share,
             # rollouts of recorded frames do not steer: their vehicles keep their own heading
             # and relax it with τ_rollout (steering toward the field raised Peachtree's FDE at
             # 1 s from 0.395 to 0.463 ft, relaxed dynamics)
             self.tau_heading if heading and not recorded and self.tau_heading > 0 else -1.0,
             *(self.profile.T.ravel() if heading and self.profile is not None else [-1.0] + [0.0] * (3 * PROFILE_KNOTS - 1)),
             *((self.heading_tolerance, self.stand_speed) if heading and not recorded and self.tau_heading > 0 else (0.0, 0.0)),
             # the step jitter (pedestrians; stochastic rollouts only: mean rollouts draw none)
             *(self.jitter if heading and self.jitter is not None else (0.0, 0.0)),
             # generated vehicles: the braking bound, and the size for cut-ins and for keeping out
             # of a side alongside (0: none; rollouts of recorded frames keep the IDM+ their time
             # constant was chosen with)
             *self._braking(recorded)],
            dtype=np.float64,
        )  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        """Plain lists and numbers (JSON, for the model file). Inverse of :meth:`from_dict`."""
        out: dict[str, Any] = {"version": _FORMAT_VERSION, "agents": self.agents}
        for name in ("sigma", "pairs", "spacing"):
            out[name] = np.asarray(getattr(self, name)).tolist()
        # strict JSON has no infinity: an infinite τ (the residual held) is the string "inf"
        out["tau"] = [float(t) if np.isfinite(t) else "inf" for t in self.tau]
        if self.tau_rollout is not None:
            out["tau_rollout"] = [float(t) if np.isfinite(t) else "inf" for t in self.tau_rollout]
        for name in ("personal", "jam", "headway", "accel", "decel", "lateral"):
            v = float(getattr(self, name))
            out[name] = v if np.isfinite(v) else None
        out["sigma_frame"] = self.sigma_frame
        out["min_speed"] = float(self.min_speed)
        share = float(self.tau_across_share)
        out["tau_across_share"] = share if np.isfinite(share) else "inf"
        th = float(self.tau_heading)
        out["tau_heading"] = None if np.isnan(th) else (th if np.isfinite(th) else "inf")
        out["profile"] = None if self.profile is None else np.asarray(self.profile).tolist()
        out["heading_tolerance"] = float(self.heading_tolerance)
        out["stand_speed"] = float(self.stand_speed)
        out["jitter"] = None if self.jitter is None else [float(x) for x in self.jitter]
        out["personal_rollout"] = None if np.isnan(self.personal_rollout) else float(self.personal_rollout)
        out["accel_trust"] = float(self.accel_trust)
        out["size"] = None if self.size is None else [float(v) for v in self.size]
        out["brake"] = None if np.isnan(self.brake) else float(self.brake)
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MotionModel:
        try:
            if int(d.get("version", 1)) > _FORMAT_VERSION:
                raise DataFormatError(f"motion model format {d['version']} is newer than this dpgp reads")
            tau, roll = (
                None if d.get(key) is None else np.array([float(t) for t in d[key]], dtype=np.float64)
                for key in ("tau", "tau_rollout")
            )
            if tau is None:
                raise KeyError("tau")
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
                tau_rollout=roll,
                # files of format 1 hold σ per x/y component
                sigma_frame=str(d.get("sigma_frame", "xy")),
                min_speed=float(d.get("min_speed", 0.0)),
                tau_across_share=float(d.get("tau_across_share", 1.0)),
                # files written before steering and the profile: neither
                tau_heading=float("nan") if d.get("tau_heading") is None else float(d["tau_heading"]),
                profile=None if d.get("profile") is None else np.asarray(d["profile"], dtype=np.float64),
                # files written before the tolerance: none
                heading_tolerance=float(d.get("heading_tolerance", 0.0)),
                stand_speed=float(d.get("stand_speed", 0.0)),
                # files written before the step jitter: none
                jitter=None if d.get("jitter") is None else np.asarray(d["jitter"], dtype=np.float64).reshape(2),
                personal_rollout=float("nan") if d.get("personal_rollout") is None else float(d["personal_rollout"]),
                # files written before it: each driver wants its own speed
                accel_trust=float(d.get("accel_trust", 0.0)),
                # files written before it: the frames' (motion_model)
                size=None if d.get("size") is None else _size(d["size"]),
                brake=float("nan") if d.get("brake") is None else float(d["brake"]),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise DataFormatError(f"not a stored motion model ({type(e).__name__}: {e})") from None
        if (
            m.agents not in _KIND
            or m.sigma_frame not in SIGMA_FRAMES
            or not (np.isfinite(m.min_speed) and m.min_speed >= 0)
            or not m.tau_across_share > 0
            or not (np.isnan(m.tau_heading) or m.tau_heading > 0)
            or not (0.0 <= m.heading_tolerance < np.pi)
            or not (np.isfinite(m.stand_speed) and m.stand_speed >= 0)
            or (m.jitter is not None and not (np.all(np.isfinite(m.jitter)) and np.all(m.jitter >= 0)))
            or not (np.isnan(m.personal_rollout) or (np.isfinite(m.personal_rollout) and m.personal_rollout >= 0))
            or not (0.0 <= m.accel_trust <= 1.0)
            or (m.size is not None and not all(np.isfinite(v) and v > 0 for v in m.size))
            or not (np.isnan(m.brake) or m.brake > 0)
            or (
                m.profile is not None
                and (
                    m.profile.shape != (PROFILE_KNOTS, 3)
                    or not np.all(np.isfinite(m.profile))
                    or np.any(m.profile < 0)
                    or np.any(np.diff(m.profile[:, 0]) < 0)
                )
            )
            or len(m.spacing) != len(tau)
            or not np.all(tau > 0)  # NaN fails too
            or (roll is not None and (roll.shape != tau.shape or not np.all(roll > 0)))
        ):
            raise DataFormatError("not a stored motion model: inconsistent fields")
        return m

    def __repr__(self) -> str:
        rule = (
            f"IDM s0={self.jam:.3g} T={self.headway:.2g}s a={self.accel:.3g} b={self.decel:.3g}"
            if self.agents == "vehicles" else f"personal distance {self.personal:.3g}"
        )  # fmt: skip
        return (
            f"MotionModel({self.agents}, {len(self.tau)} patterns, tau {np.median(self.tau):.3g} s (median), "
            f"sigma {self._sigma_text()}; {rule}"
            + ("" if np.isnan(self.tau_heading) else f"; heading tau {self.tau_heading:.3g} s")
            + (f", tolerance {self.heading_tolerance:.3g} rad" if self.heading_tolerance > 0 else "")
            + (f", stands below {self.stand_speed:.3g}" if self.stand_speed > 0 else "")
            + (f"; step jitter {self.jitter[0]:.3g}, {self.jitter[1]:.3g}" if self.jitter is not None else "")
            + (f"; rollouts keep {self.personal_rollout:.3g}" if np.isfinite(self.personal_rollout) else "")
            + ")"
        )

    def _sigma_text(self) -> str:
        if self.sigma_frame == "heading":
            return f"along {np.median(self.sigma[:, 0]):.3g}, across {np.median(self.sigma[:, 1]):.3g} (median)"
        return f"{np.median(self.sigma):.3g}"


def field_means(fit: FittedPatterns, xy: np.ndarray, row_label: np.ndarray, h: np.ndarray | None = None) -> np.ndarray:
    """(n, 2): the posterior mean velocity at each position ``xy[i]`` under pattern ``row_label[i]``;
    a field over heading at the previous heading ``h[i]`` (``NaN`` or no ``h``: averaged over it)."""
    order = np.argsort(row_label, kind="stable")
    ks, starts = np.unique(row_label[order], return_index=True)
    offsets = np.r_[starts, len(order)].astype(np.int64)
    xy = np.ascontiguousarray(xy[order])
    hh = None if h is None or not fit.headed else np.ascontiguousarray(np.asarray(h, np.float64)[order])
    means = np.asarray(_core.field_means(fit.sampler, [int(fit.slots[k]) for k in ks], xy, offsets, hh))
    out = np.empty_like(means)
    out[order] = means
    return out


def _along_across(resid: np.ndarray, means: np.ndarray, min_speed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows with a heading, their field speeds, (n, 2) residuals along and across the heading)."""
    speed = np.hypot(means[:, 0], means[:, 1])
    ok = (speed > min_speed) & (speed > 0)
    e = means[ok] / speed[ok, None]
    r = resid[ok]
    return ok, speed[ok], np.stack([(r * e).sum(axis=1), r[:, 1] * e[:, 0] - r[:, 0] * e[:, 1]], axis=1)


def profile_factors(profile: np.ndarray | None, speed: np.ndarray) -> np.ndarray:
    """(n, 2): the spread's (along, across) factors at field speeds ``speed`` (linear between
    the knots, constant beyond; ``motion.rs``: ``Profile::at``); ones without a profile."""
    if profile is None:
        return np.ones((len(speed), 2))
    return np.stack([np.interp(speed, profile[:, 0], profile[:, c]) for c in (1, 2)], axis=1)


def spread_profile(resid: np.ndarray, means: np.ndarray, min_speed: float) -> np.ndarray | None:
    """(PROFILE_KNOTS, 3): field speed, along factor, across factor. The rows with a heading are
    cut into :data:`PROFILE_KNOTS` bins of equal count by their field speed ``|m|``; a knot is
    a bin's median field speed, its factors the root mean squares of the residuals along and
    across the heading in the bin over those of all the rows. ``None`` with fewer than
    ``PROFILE_KNOTS × MIN_DISTANCES`` such rows."""
    _, speed, aa = _along_across(resid, means, min_speed)
    if len(speed) < PROFILE_KNOTS * MIN_DISTANCES:
        return None
    edges = np.quantile(speed, np.linspace(0.0, 1.0, PROFILE_KNOTS + 1))
    b = np.clip(np.searchsorted(edges, speed, side="right") - 1, 0, PROFILE_KNOTS - 1)
    n = np.bincount(b, minlength=PROFILE_KNOTS)
    if np.any(n == 0):  # ties in the field speeds: too few distinct speeds for a profile
        return None
    knots = np.array([np.median(speed[b == i]) for i in range(PROFILE_KNOTS)])
    rms = np.sqrt(
        np.stack([np.bincount(b, weights=aa[:, c] ** 2, minlength=PROFILE_KNOTS) for c in (0, 1)], 1) / n[:, None]
    )
    total = np.sqrt((aa**2).mean(axis=0))
    factor = np.where(total > 0, rms / np.where(total > 0, total, 1.0), 1.0)
    return np.column_stack([np.maximum.accumulate(knots), factor])


def heading_spreads(
    resid: np.ndarray,
    means: np.ndarray,
    row_label: np.ndarray,
    K: int,
    min_speed: float,
    profile: np.ndarray | None = None,
) -> np.ndarray:
    """(K, 2): per pattern, the root mean square of the residuals ``resid`` along and across the
    heading of the field means ``means`` at the same rows, over rows whose field is faster than
    ``min_speed`` (the pooled spreads for a pattern with fewer than 2 such rows; isotropic from
    every row when no row has a heading). With a ``profile`` (:func:`spread_profile`), of the
    residuals divided by its factors at each row's field speed: the spread where the factors
    are 1."""
    ok, speed, aa = _along_across(resid, means, min_speed)
    f = profile_factors(profile, speed)
    sq = np.where(f > 0, aa / np.where(f > 0, f, 1.0), 0.0) ** 2
    if len(sq) == 0:
        iso = np.sqrt((resid**2).mean()) if len(resid) else 0.0
        return np.full((K, 2), iso)
    lab = row_label[ok]
    out = np.tile(np.sqrt(sq.mean(axis=0)), (K, 1))
    n = np.bincount(lab, minlength=K)
    for c in range(2):
        tot = np.bincount(lab, weights=sq[:, c], minlength=K)
        out[n >= 2, c] = np.sqrt(tot[n >= 2] / n[n >= 2])
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


def time_constants(
    fit: FittedPatterns,
    holdout: float | None = TAU_HOLDOUT,
    grid: np.ndarray = TAU_GRID,
    pattern_steps: int = TAU_PATTERN_STEPS,
    held: tuple[FittedPatterns, int] | None = None,
    motion: MotionModel | None = None,
    setup: HeldOut | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per pattern, the residual's time constant that best predicts held-out tracks, and how
    many track-steps chose it (0: the pooled choice). ``setup``: the caller's
    :func:`_held_out_setup` of ``fit``, ``holdout`` and ``held``, when it has one.

    ``motion`` given: the frames are rolled out as :func:`~dpgp.generate.simulation.simulate`
    rolls out a recorded frame, by that motion model with interaction (:data:`ROLLOUT_DYNAMICS`,
    mean mode, the fit's ROI), each ``τ`` of the grid in turn for every pattern; else by the
    batched relaxed rollouts (no interaction, no ROI).

    Out of sample (the default): the fields are conditioned on the first ``1 − holdout`` of the
    training frames only (:meth:`~dpgp.gp.fitted.FittedPatterns.conditioned_on`; same
    assignments, length scales, α and noise), and up to :data:`TAU_FRAMES` frames of the last
    ``holdout`` are rolled out as a test frame is: through the pattern those fields predict for
    it, every vehicle from its own velocity (mean mode, no interaction) for :data:`TAU_HORIZON`
    seconds under each ``τ`` of :data:`TAU_GRID`; the error is the mean distance to where its
    track really was, over the steps it was recorded. Rolling out the very frames the fields
    were fitted to (``holdout=None``, the earlier choice; also the fallback when the fit cannot
    be conditioned) favours short ``τ``: there the field has already seen each vehicle's
    velocity. The grid ends at ``τ = ∞`` (constant velocity: the residual never relaxes), so the
    choice does at least as well as constant velocity on the frames that choose it.

    The pooled ``τ`` minimises the error over all patterns (refined by a parabola in ``log τ``
    through the best finite grid point and its finite neighbours); a pattern (of this fit) with
    at least :data:`TAU_PATTERN_STEPS` held-out track-steps takes its own minimiser."""
    K = fit.n_patterns
    default = np.full(K, DEFAULT_TAU), np.zeros(K, np.int64)
    setup = setup if setup is not None else _held_out_setup(fit, holdout, held)
    if setup is None:
        return default
    roll, chosen, through, rows, steps = setup.roll, setup.chosen, setup.through, setup.rows, setup.steps
    frames, dt = fit.frames, fit.dt
    if motion is None:
        h0 = None if frames.prev_heading is None else frames.prev_heading[rows]
        pred = relaxed_mean_rollouts(
            roll, np.repeat(through, frames.sizes[chosen]), frames.xy[rows], frames.v[rows], grid, steps, dt, h0
        )
    else:
        candidates = [replace(motion, tau_rollout=np.full(len(motion.tau), float(t))) for t in grid]
        pred = interactive_rollouts(roll, candidates, frames[chosen], through, steps, dt)
    errors, counts = _held_out_errors(fit, setup, pred)
    pooled = _refined(errors.sum(axis=1), grid)
    tau = np.full(K, pooled)
    own = counts >= pattern_steps
    for k in np.flatnonzero(own):
        tau[k] = _refined(errors[:, k], grid)
    return tau, np.where(own, counts, 0).astype(np.int64)


class HeldOut(NamedTuple):
    """What the out-of-sample choices roll out (:func:`_held_out_setup`)."""

    roll: FittedPatterns  # the fields that roll
    chosen: np.ndarray  # the frames rolled out
    through: np.ndarray  # the pattern each goes through
    rows: np.ndarray  # their rows
    steps: int
    truth: np.ndarray  # (steps + 1, len(rows)): each vehicle's row h steps later (-1: not recorded)


def _held_out_setup(
    fit: FittedPatterns, holdout: float | None, held: tuple[FittedPatterns, int] | None
) -> HeldOut | None:
    """What :func:`time_constants` and :func:`accel_trust` roll out; ``None`` with too few
    recorded track-steps."""
    frames, labels, dt = fit.frames, fit.labels, fit.dt
    steps = max(1, int(round(TAU_HORIZON / dt)))
    a, b = consecutive_pairs(frames, dt)
    if len(a) < MIN_PAIRS:
        return None
    n = len(frames)
    if holdout is None:
        held = None
    elif held is None:  # else the caller's held_out_fields(fit, holdout)
        held = held_out_fields(fit, holdout)
    if held is None:  # in sample: the fields as fitted, frames spread over the whole period
        roll, pool = fit, np.arange(n)
    else:
        roll, cut = held
        pool = np.arange(cut, n)
    chosen = pool[np.unique(np.linspace(0, len(pool) - 1, min(TAU_FRAMES, len(pool))).round().astype(np.int64))]
    rows = np.concatenate([np.arange(frames.offsets[f], frames.offsets[f + 1]) for f in chosen])
    nxt = np.full(frames.n_points, -1, dtype=np.int64)
    nxt[a] = b
    truth = np.full((steps + 1, len(rows)), -1, dtype=np.int64)
    truth[0] = rows
    for h in range(1, steps + 1):
        prev = truth[h - 1]
        truth[h] = np.where(prev >= 0, nxt[np.maximum(prev, 0)], -1)
    if (truth[1:] >= 0).sum() < MIN_PAIRS:
        return None
    # rolled out through the pattern of the fields that roll it (a new frame's: predicted)
    through = labels[chosen] if held is None else roll.predict(frames[chosen])
    return HeldOut(roll, chosen, through, rows, steps, truth)


def _held_out_errors(fit: FittedPatterns, setup: HeldOut, pred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Of the rollouts ``pred`` (steps + 1, n, G, 2) of :func:`_held_out_setup`'s frames: per
    candidate and pattern (of this fit) the summed distance to where the tracks really were over
    the steps they were recorded (G, K), and per pattern how many track-steps (K,)."""
    frames, K, chosen, truth = fit.frames, fit.n_patterns, setup.chosen, setup.truth
    known = truth[1:] >= 0
    dist = np.linalg.norm(pred[1:] - frames.xy[np.maximum(truth[1:], 0)][:, :, None, :], axis=-1)  # (steps, n, G)
    dist = np.where(known[:, :, None], dist, 0.0).sum(axis=0)  # (n, G)
    row_pat = np.repeat(fit.labels[chosen], frames.sizes[chosen])  # grouped by this fit's pattern of the frame
    errors = np.stack([np.bincount(row_pat, weights=dist[:, g], minlength=K) for g in range(pred.shape[2])])
    counts = np.bincount(row_pat, weights=known.sum(axis=0), minlength=K)
    return errors, counts


def accel_trust(
    fit: FittedPatterns, held: tuple[FittedPatterns, int] | None, model: MotionModel, setup: HeldOut | None = None
) -> float:
    """The share of recorded accelerations the drivers of rollouts of recorded frames start from
    (:meth:`MotionModel.recorded_drivers`): of :data:`ACCEL_TRUSTS`, the one whose rollouts
    (interactive, each pattern at its ``τ_rollout``) predict the held-out tracks best, as
    :func:`time_constants` chooses ``τ_rollout``; 0 without previous velocities, car following,
    or enough tracks. On the SUMO junction (a 0.5 s step) the recorded acceleration of a vehicle
    leaving a queue or a turn says where it will be; on NGSIM's Peachtree it is mostly noise.
    ``setup``: as :func:`time_constants` takes it."""
    frames = fit.frames
    if frames.prev_v is None or model.agents != "vehicles" or not model.accel > 0:
        return 0.0
    setup = setup if setup is not None else _held_out_setup(fit, TAU_HOLDOUT, held)
    if setup is None:
        return 0.0
    candidates = [replace(model, accel_trust=float(t)) for t in ACCEL_TRUSTS]
    pred = interactive_rollouts(setup.roll, candidates, frames[setup.chosen], setup.through, setup.steps, fit.dt)
    errors, _ = _held_out_errors(fit, setup, pred)
    return float(ACCEL_TRUSTS[int(np.argmin(errors.sum(axis=1)))])


def held_out_fields(fit: FittedPatterns, holdout: float) -> tuple[FittedPatterns, int] | None:
    """The fit's patterns conditioned on its first ``1 − holdout`` training frames, and the index
    of the first frame held out; ``None`` where the fit cannot be conditioned or nothing is left
    on either side."""
    n = len(fit.frames)
    cut = int(round(n * (1.0 - holdout)))
    held = fit.conditioned_on(np.arange(cut)) if 0 < cut < n else None
    return None if held is None else (held[0], cut)


def interactive_rollouts(
    fit: FittedPatterns,
    candidates: list[MotionModel],
    frames: Frames,
    patterns: np.ndarray,
    steps: int,
    dt: float,
) -> np.ndarray:
    """(steps + 1, n, len(candidates), 2): the mean rollouts ``simulate`` runs of each of
    ``frames`` (its ``n`` rows in order) through ``patterns`` (one per frame), by each motion model
    of ``candidates`` in turn: interaction, the fit's ROI, each vehicle starting from its own
    velocity and previous heading (and its driver from :meth:`MotionModel.recorded_drivers`)."""
    speed = heading_speed(fit)
    starts = [f.xy for f in frames]
    velocities = [f.v for f in frames]
    headings = [start_headings(f.v, f.prev_heading, speed, len(f.xy)) for f in frames]
    out = np.empty((steps + 1, frames.n_points, len(candidates), 2))
    for g, candidate in enumerate(candidates):
        sims = motion_rollouts(
            fit, [int(k) for k in patterns], starts, velocities, steps=steps, dt=dt, seeds=None, roi=fit.roi,
            low_data_threshold=None, dynamics=ROLLOUT_DYNAMICS, motion=candidate, recorded=True, headings=headings,
            drivers=recorded_drivers(candidate, frames, dt),
        )  # fmt: skip
        out[:, :, g] = np.concatenate([s.positions for s in sims], axis=1)
    return out


def recorded_drivers(motion: MotionModel, frames: Frames, dt: float) -> list[np.ndarray] | None:
    """Per frame, its vehicles' drivers in a rollout of recorded frames
    (:meth:`MotionModel.recorded_drivers`); ``None``: each its own velocity."""
    out = [motion.recorded_drivers(f.v, f.prev_v, dt) for f in frames]
    known = [d for d in out if d is not None]
    return known if len(known) == len(out) else None


def relaxed_mean_rollouts(
    fit: FittedPatterns,
    patterns: np.ndarray,
    xy: np.ndarray,
    v: np.ndarray,
    taus: np.ndarray,
    steps: int,
    dt: float,
    h0: np.ndarray | None = None,
) -> np.ndarray:
    """(steps + 1, n, len(taus), 2): positions of vehicles starting at ``xy`` with velocities
    ``v`` through ``patterns`` (per vehicle, this fit's) under each time constant, mean mode, no
    interaction, no ROI: the core's ``dynamics="relaxed"`` rollout (``motion.rs``; Euler, the
    residual relaxing at the new position), every vehicle and ``τ`` in one field evaluation per
    step (a call per frame and ``τ`` costs milliseconds each on a reduced-rank field). A field over
    heading is asked at each vehicle's previous heading, kept as the core keeps it (from ``h0``, the
    recorded ones)."""
    order = np.argsort(patterns, kind="stable")
    ks, starts = np.unique(patterns[order], return_index=True)
    n, g = len(order), len(taus)
    offsets = (np.r_[starts, n] * g).astype(np.int64)
    slots = [int(fit.slots[k]) for k in ks]
    rho = np.exp(-dt / np.asarray(taus, dtype=np.float64))[None, :, None]
    x = np.repeat(xy[order][:, None, :], g, axis=1)  # (n, g, 2)
    w = np.repeat(v[order][:, None, :], g, axis=1)
    out = np.empty((steps + 1, n, g, 2))
    out[0] = x
    speed = heading_speed(fit)
    h = None
    if fit.headed:
        start = start_headings(v, h0, speed, len(v))[order]
        h = np.repeat(start[:, None], g, axis=1).reshape(-1)
    for t in range(1, steps + 1):
        x = x + dt * w
        if h is not None:
            h = carried(w.reshape(1, -1, 2), h, speed)
        m = np.asarray(_core.field_means(fit.sampler, slots, np.ascontiguousarray(x.reshape(-1, 2)), offsets, h))
        m = m.reshape(n, g, 2)
        w = m + rho * (w - m)
        out[t] = x
    back = np.empty_like(out)
    back[:, order] = out
    return back


def _refined(err: np.ndarray, grid: np.ndarray) -> float:
    """The τ of ``grid`` with the least error, refined by a parabola in log τ when it and both
    neighbours are finite."""
    i = int(np.argmin(err))
    x = np.log(grid)
    if 0 < i < len(err) - 1 and np.isfinite(x[i + 1]):
        y0, y1, y2 = err[i - 1], err[i], err[i + 1]
        den = y0 - 2 * y1 + y2
        if den > 0:
            shift = 0.5 * (y0 - y2) / den  # in grid steps, within (-0.5, 0.5)
            return float(np.exp(x[i] + shift * (x[i + 1] - x[i])))
    return float(grid[i])


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
    means = field_means(fit, frames.xy, row_label, frames.prev_heading)
    resid = frames.v - means
    # generated scenes: the residual's decay against the fields as fitted; rollouts of recorded
    # frames: the held-out choice, which also pays for the fields' error at an unseen vehicle
    tau, pairs = time_constants(fit, holdout=None, pattern_steps=MIN_PAIRS)
    held = held_out_fields(fit, TAU_HOLDOUT)  # conditioning refactors every pattern: once, for τ_rollout and steering
    field_speed = np.hypot(means[:, 0], means[:, 1])
    min_speed = HEADING_SHARE * float(np.median(field_speed)) if len(field_speed) else 0.0
    profile = spread_profile(resid, means, min_speed) if PROFILE else None
    sigma = heading_spreads(resid, means, row_label, K, min_speed, profile)
    frame: dict[str, Any] = {"sigma_frame": "heading", "min_speed": min_speed, "profile": profile}
    nn_all = nearest_distances(frames)
    spacing = np.full(K, np.percentile(nn_all, SPACING_PERCENTILE) if len(nn_all) else 0.0)
    for k in range(K):
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
        share = TAU_ACROSS_SHARE["pedestrians"]
        jitter = step_jitter(frames, means, dt, min_speed) if JITTER else None
        personal = max(personal, 1e-9)
        near = rollout_personal_distance(frames, dt, personal) if ROLLOUT_PERSONAL else float("nan")
        return _rollout_choice(fit, held, MotionModel(
            agents, tau, sigma, pairs, spacing, personal, tau_across_share=share,
            jitter=jitter, personal_rollout=near, **frame,
        ))  # fmt: skip
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
    tau_h, tol = steering(fit, held, means, min_speed, med) if STEER else (float("nan"), 0.0)
    stand = stand_speed(frames, dt) if STEER else 0.0
    return _rollout_choice(fit, held, MotionModel(
        agents, tau, sigma, pairs, spacing, personal, jam, headway, accel, decel, max(lateral, 1e-9),
        tau_across_share=TAU_ACROSS_SHARE["vehicles"], tau_heading=tau_h, heading_tolerance=tol, stand_speed=stand,
        size=default_size(frames.summary), brake=max_brake(frames.summary), **frame,
    ))  # fmt: skip


def _rollout_choice(fit: FittedPatterns, held: tuple[FittedPatterns, int] | None, model: MotionModel) -> MotionModel:
    """``model`` with ``τ_rollout`` chosen on held-out frames rolled out as ``simulate`` rolls
    them: by this very model (its car following or personal distance), interacting; then its
    ``accel_trust`` on the same frames."""
    setup = _held_out_setup(fit, TAU_HOLDOUT, held)
    model = replace(model, tau_rollout=time_constants(fit, held=held, motion=model, setup=setup)[0])
    return replace(model, accel_trust=accel_trust(fit, held, model, setup)) if ACCEL_TRUST else model


def steering(
    fit: FittedPatterns,
    held: tuple[FittedPatterns, int] | None,
    means: np.ndarray,
    min_speed: float,
    typical_speed: float,
) -> tuple[float, float]:
    """``(τ_h, δ)`` of steering vehicles (:func:`heading_time_constant`, :func:`heading_tolerance`),
    learned out of sample: from the last :data:`TAU_HOLDOUT` of the training frames, against the
    fields conditioned on the rest (through the pattern those fields predict for each frame), as
    ``tau_rollout`` is. In sample, a pattern whose noise is far below its velocities' variance
    (a pair per pattern: down to 1e-9 m²/s² on the SUMO junction) puts the field's heading at a
    recorded vehicle on the vehicle's own, so every recorded turn looks like an instant turn toward
    the field (``τ_h`` at the grid's 0.25 s, ``δ`` 0) while a generated vehicle, which is never on
    a training point, turns with every roughness of the field (junction: realism ratio 0.754 in
    sample, 0.924 out of sample, on one fit). In sample where the fit cannot be conditioned or the
    held-out frames hold too few track pairs. No steering (NaN) where the recorded headings are
    mostly noise (:data:`STEER_NOISE_SHARE`). ``held``: :func:`held_out_fields` of ``fit`` at
    :data:`TAU_HOLDOUT`."""
    frames, dt = fit.frames, fit.dt
    if heading_noise_share(frames, dt, typical_speed) >= STEER_NOISE_SHARE:
        return float("nan"), 0.0
    if held is not None:
        late = frames[np.arange(held[1], len(frames))]
        through = np.repeat(held[0].predict(late), late.sizes)
        late_means = field_means(held[0], late.xy, through, late.prev_heading)
        tau_h = heading_time_constant(late, late_means, dt, min_speed, typical_speed)
        if not np.isnan(tau_h):
            return tau_h, heading_tolerance(late, late_means, dt, min_speed, typical_speed, tau_h)
    tau_h = heading_time_constant(frames, means, dt, min_speed, typical_speed)
    return tau_h, heading_tolerance(frames, means, dt, min_speed, typical_speed, tau_h)


def step_jitter(frames: Frames, means: np.ndarray, dt: float, min_speed: float) -> np.ndarray:
    """(along, across) spreads of the pedestrians' step jitter (``motion.rs``: ``Motion::jitter``),
    zeros without enough tracks. Over four consecutive rows of a track, the step velocities
    ``u_i = (p_{i+1} − p_i) / dt`` (from positions, as the realism features measure them) give
    two successive changes ``Δ₁ = u₂ − u₁``, ``Δ₂ = u₃ − u₂``, projected on the field's heading
    at the second row and on its normal (rows where the field is faster than ``min_speed``). A
    velocity ``s + η``, ``s`` smooth and ``η`` independent per step with variance ``j²``, has
    ``cov(Δ₁, Δ₂) = cov(Δs₁, Δs₂) − j²``: ``j² = max(−cov(Δ₁, Δ₂), 0)`` per axis (a lower bound
    when the smooth part's changes persist). Recorded pedestrians change velocity by 0.3 m/s
    per 0.4 s step (ETH) and half of it is undone the next step (correlation −0.43 along the
    heading, −0.22 across): ``j`` = 0.21, 0.15 m/s; Zara's changes persist (+0.27): 0."""
    a, b = consecutive_pairs(frames, dt)
    nxt = np.full(frames.n_points, -1, dtype=np.int64)
    nxt[a] = b
    r0 = np.arange(frames.n_points)
    r1 = nxt
    r2 = np.where(r1 >= 0, nxt[np.maximum(r1, 0)], -1)
    r3 = np.where(r2 >= 0, nxt[np.maximum(r2, 0)], -1)
    ok = r3 >= 0
    ms = np.hypot(means[:, 0], means[:, 1])
    ok[ok] &= (ms[r1[ok]] > min_speed) & (ms[r1[ok]] > 0)
    if ok.sum() < MIN_PAIRS:
        return np.zeros(2)
    p = [frames.xy[r[ok]] for r in (r0, r1, r2, r3)]
    u = [(p[i + 1] - p[i]) / dt for i in range(3)]
    d1, d2 = u[1] - u[0], u[2] - u[1]
    e = means[r1[ok]] / ms[r1[ok], None]
    out = np.zeros(2)
    along = [(d * e).sum(axis=1) for d in (d1, d2)]
    across = [d[:, 1] * e[:, 0] - d[:, 0] * e[:, 1] for d in (d1, d2)]
    for c, (x1, x2) in enumerate((along, across)):
        cov = float(np.mean((x1 - x1.mean()) * (x2 - x2.mean())))
        out[c] = np.sqrt(max(-cov, 0.0))
    return out


def _keep_distance(x: np.ndarray, v: np.ndarray, d: float, dt: float) -> np.ndarray:
    """The core's personal-distance rule (``motion.rs``: ``keep_distance``) on one frame's
    positions ``x`` and velocities ``v`` (n, 2)."""
    diff = x[:, None, :] - x[None, :, :]
    dist = np.hypot(diff[..., 0], diff[..., 1])
    speed = np.hypot(v[:, 0], v[:, 1])
    near = (dist < 2.0 * d + dt * (speed[:, None] + speed[None, :])) & (dist > 1e-12)
    unit = diff / np.where(dist > 1e-12, dist, 1.0)[..., None]
    grow = ((v[:, None, :] - v[None, :, :]) * unit).sum(-1)
    need = (d - dist) / dt
    push = np.where(near & (grow < need), 0.5 * (need - grow), 0.0)
    return v + (push[..., None] * unit).sum(axis=1)


def rollout_personal_distance(frames: Frames, dt: float, personal: float) -> float:
    """The pedestrians' personal distance for rollouts of recorded frames (NaN without enough
    tracks: ``personal``): of ``share × personal``, ``share`` in :data:`PERSONAL_SHARES` (0: no
    rule), the one whose rollouts predict the training tracks best. Every frame with two or more
    pedestrians is rolled out for :data:`TAU_HORIZON` seconds, each at its own velocity (constant
    velocity, the rule's only input) with the rule applied at every step; the error is the mean
    distance to where the tracks really were, over the steps they were recorded. The rule is a
    guard for generated scenes; recorded pedestrians do not keep it as a rollout would: on ETH's
    training tracks every share above 0 predicts worse (4 s: 1.568 m at 0, 1.627 at 1)."""
    a, b = consecutive_pairs(frames, dt)
    if len(a) < MIN_PAIRS:
        return float("nan")
    nxt = np.full(frames.n_points, -1, dtype=np.int64)
    nxt[a] = b
    steps = max(1, int(round(TAU_HORIZON / dt)))
    err = np.zeros(len(PERSONAL_SHARES))
    n = 0
    for lo, hi in zip(frames.offsets[:-1], frames.offsets[1:]):
        if hi - lo < 2:
            continue
        truth = np.arange(lo, hi)
        x = np.repeat(frames.xy[lo:hi][None], len(PERSONAL_SHARES), axis=0)
        v = frames.v[lo:hi]
        for _ in range(steps):
            truth = np.where(truth >= 0, nxt[np.maximum(truth, 0)], -1)
            for g, share in enumerate(PERSONAL_SHARES):
                x[g] = x[g] + dt * (_keep_distance(x[g], v, share * personal, dt) if share > 0 else v)
            known = truth >= 0
            if not known.any():
                break
            err += np.hypot(*(x[:, known] - frames.xy[truth[known]][None]).transpose(2, 0, 1)).sum(axis=1)
            n += int(known.sum())
    if n < MIN_PAIRS:
        return float("nan")
    return float(PERSONAL_SHARES[int(np.argmin(err))] * personal)


def _heading_pairs(
    frames: Frames, means: np.ndarray, dt: float, min_speed: float, typical_speed: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Over consecutive track pairs ``(a, b)`` both moving at least :data:`STEER_SPEED_SHARE` of
    ``typical_speed``, with a field heading at ``b``: the field's heading at ``b`` less the
    vehicle's at ``a``, and the vehicle's heading change ``θ_b − θ_a`` (both wrapped); ``None``
    with fewer than :data:`MIN_PAIRS`."""
    a, b = consecutive_pairs(frames, dt)
    v = frames.v
    speed = np.hypot(v[:, 0], v[:, 1])
    ms = np.hypot(means[:, 0], means[:, 1])
    ok = (speed[a] >= STEER_SPEED_SHARE * typical_speed) & (speed[b] >= STEER_SPEED_SHARE * typical_speed)
    ok &= (ms[b] > min_speed) & (ms[b] > 0)
    if ok.sum() < MIN_PAIRS:
        return None
    a, b = a[ok], b[ok]
    th = np.arctan2(v[:, 1], v[:, 0])
    return _wrap(np.arctan2(means[b, 1], means[b, 0]) - th[a]), _wrap(th[b] - th[a])


def _wrap(x: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * x))


def heading_time_constant(
    frames: Frames, means: np.ndarray, dt: float, min_speed: float, typical_speed: float
) -> float:
    """The time constant ``τ_h`` with which a vehicle's heading turns toward the field's (NaN
    without enough tracks). Over consecutive track pairs ``(a, b)`` (:func:`_heading_pairs`): the
    heading ``θ_b`` is predicted by ``θ_a + (1 − exp(−dt / τ_h)) wrap(θ_m(b) − θ_a)`` (the core's
    steering step), and ``τ_h`` of :data:`TAU_GRID` with the least mean squared (wrapped) error
    is kept, refined as ``τ`` is. A rough field turns where vehicles drive straight; this is how
    much of its turning the recorded vehicles follow per step."""
    pairs = _heading_pairs(frames, means, dt, min_speed, typical_speed)
    if pairs is None:
        return float("nan")
    d, turned = pairs
    err = np.array([np.mean(_wrap(turned - (1.0 - np.exp(-dt / t)) * d) ** 2) for t in TAU_GRID])
    return _refined(err, TAU_GRID)


def heading_noise_share(frames: Frames, dt: float, typical_speed: float) -> float:
    """The share of the recorded heading changes' variance that is white noise from step to step
    (0 with fewer than :data:`MIN_PAIRS` triples of a track's consecutive rows, each moving at
    least :data:`STEER_SPEED_SHARE` of ``typical_speed``). The noise's variance ``s²`` is minus
    the covariance of consecutive changes ``θ_b − θ_a`` and ``θ_c − θ_b`` (noise at ``θ_b`` enters
    both with opposite signs; a turn held over steps adds a positive covariance, so this errs
    low), and each change holds ``2 s²`` of it."""
    a, b = consecutive_pairs(frames, dt)
    after = np.full(frames.n_points, -1, dtype=np.int64)
    after[a] = b
    c = after[b]
    a, b, c = a[c >= 0], b[c >= 0], c[c >= 0]
    v = frames.v
    speed = np.hypot(v[:, 0], v[:, 1])
    ok = np.minimum(np.minimum(speed[a], speed[b]), speed[c]) >= STEER_SPEED_SHARE * typical_speed
    if ok.sum() < MIN_PAIRS:
        return 0.0
    th = np.arctan2(v[:, 1], v[:, 0])
    first, second = _wrap(th[b[ok]] - th[a[ok]]), _wrap(th[c[ok]] - th[b[ok]])
    cov = np.cov(first, second)
    changes = 0.5 * (cov[0, 0] + cov[1, 1])
    return float(np.clip(-2.0 * cov[0, 1] / changes, 0.0, 1.0)) if changes > 0 else 0.0


def heading_tolerance(
    frames: Frames, means: np.ndarray, dt: float, min_speed: float, typical_speed: float, tau_heading: float
) -> float:
    """The angle ``δ`` (rad) within which a steering vehicle does not turn toward the field's
    heading (0 without enough tracks or without ``τ_h``): over the pairs of
    :func:`heading_time_constant`, ``θ_b`` is predicted by ``θ_a + (1 − exp(−dt / τ_h))
    sign(Δ) max(|Δ| − δ, 0)``, ``Δ = wrap(θ_m(b) − θ_a)``, and ``δ`` of :data:`TOLERANCE_GRID`
    with the least mean squared (wrapped) error is kept (refined as ``τ`` is), the criterion of
    ``τ_h``. (The least absolute error was used while both were learned in sample, against fields
    that turned at every lane-scale roughness; out of sample it ran to the grid's end on the SUMO
    junction, 0.64 rad, and to 0.27 rad on Peachtree, whose held-out errors change by < 2% over the
    grid: too weak a signal to stop generated vehicles turning.) A ``δ`` > 0 is kept only when
    its gain over 0 is at least :data:`TOLERANCE_SE` standard errors of the paired per-step
    gains; junction 0 (the least error is at 0), Peachtree 0 (0.053 rad gains 0.45%)."""
    pairs = _heading_pairs(frames, means, dt, min_speed, typical_speed)
    if pairs is None or not (tau_heading > 0):
        return 0.0
    d, turned = pairs
    k = 1.0 - np.exp(-dt / tau_heading)
    sq = np.stack([_wrap(turned - k * np.sign(d) * np.maximum(np.abs(d) - t, 0.0)) ** 2 for t in TOLERANCE_GRID])
    err = sq.mean(axis=1)
    # a tolerance only where the pairs support it beyond their noise: the gain over δ = 0 of the
    # best δ, paired pair by pair, at least TOLERANCE_SE standard errors
    gain = sq[0] - sq[int(np.argmin(err))]
    if gain.mean() < TOLERANCE_SE * gain.std() / np.sqrt(len(gain)):
        return 0.0
    with np.errstate(divide="ignore"):
        return min(_refined(err, TOLERANCE_GRID), float(TOLERANCE_GRID[-1]))


def stand_speed(frames: Frames, dt: float) -> float:
    """The desired speed below which a steering vehicle stands (0 without enough tracks): the
    median of the recorded speeds next to a stand, at the step before a vehicle stops and the
    step after it starts (speed exactly 0 is a stand). Recorded vehicles go from and to a stand
    through about this speed; a wish slower than that is a queue's, where the field's mean is
    slow but not at rest (SUMO junction: |m| ≈ 0.06 m/s) and vehicles that took it crept at
    0.01–0.5 m/s (23% of generated steps against 7% recorded). SUMO junction: 0.21 m/s;
    Peachtree: 0.09 ft/s."""
    a, b = consecutive_pairs(frames, dt)
    speed = np.hypot(frames.v[:, 0], frames.v[:, 1])
    sa, sb = speed[a], speed[b]
    near = np.r_[sa[(sa > 0) & (sb == 0)], sb[(sa == 0) & (sb > 0)]]
    return float(np.median(near)) if len(near) >= MIN_PAIRS else 0.0


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


def max_brake(summary: Any) -> float:
    """:data:`MAX_BRAKE` in the frames' length unit (``summary.length_unit``; metres when not known)."""
    return in_frame_units(MAX_BRAKE, getattr(summary, "length_unit", None))


def motion_model(fit: FittedPatterns, agents: str = "auto") -> MotionModel:
    """The fitted model's :class:`MotionModel`: kept in its cache (and in the model file), else
    learned from its training frames."""
    cached = fit.cache.get("motion")
    if cached is not None and cached[0] is fit.frames and (agents == "auto" or cached[1].agents == agents):
        m = cached[1]
        if m.agents == "vehicles" and (m.size is None or np.isnan(m.brake)):  # a file written before them
            size = default_size(fit.frames.summary) if m.size is None else m.size
            fit.cache["motion"] = (fit.frames, replace(m, size=size, brake=max_brake(fit.frames.summary)))
        return fit.cache["motion"][1]
    m = learn(fit, agents)
    if agents == "auto":
        fit.cache["motion"] = (fit.frames, m)
    return m


__all__ = [
    "MotionModel",
    "learn",
    "motion_model",
    "time_constants",
    "heading_spreads",
    "consecutive_pairs",
    "nearest_distances",
    "DEFAULT_TAU",
]
