"""Long scenarios that switch pattern over time (issue 20).

A scenario starts from a pattern (drawn by how recordings start, else by weight) with the vehicles
of one of its training frames, stays for a dwell time drawn from that pattern's recorded runs, then
moves to the next pattern by the learned transitions (the changes, self-transitions excluded),
and so on until ``duration`` (:class:`PatternSchedule`); with ``phases`` it switches phase by the
recorded phase changes and durations (:class:`PhaseSchedule`), and within a phase follows its
patterns' fields together (``phase_fields="together"``: at each point the patterns that know it
speak for it, as much as they know it; vehicles enter where the phase's did) or, ``"in turn"``,
one pattern at a time as inside the phase's recorded runs. Together, a vehicle nearing a red
light is told to stop by the one pattern of the phase that knows its queue, every step, not only
while that pattern is in force; at a change of phase each driver takes up the new phase's fields
where it is, as far as they know the point (a queue that stood at red wants to go at green,
whatever the time constant of the residual), and by phase, a red signal's stop line
(:mod:`.stop_lines`, learned from where the recorded queues' fronts stood) stops the vehicles of
its approach, and the fields' means are raised to the recorded free speeds (:mod:`.free_speeds`):
queues come from the stop lines and car-following, not from a slow mean. Vehicles keep moving across a switch: the rollout
goes on from where they are, each driver's state carried over (its wish, not its braked or
pushed velocity), with the residual dynamics and interactions of :mod:`.motion` under the new
pattern's field, followed only as far as that field has data where the vehicle is (a pattern's
zero prior mean is no wish to stand). New vehicles enter where the current pattern's vehicles
entered in the recording (track starts inside a recording, not at its first frame), at the
pattern's recorded entry rate (Poisson);
vehicles that leave the ROI, or every recorded path (:class:`Area`), are dropped. Rollouts run in
blocks of ``block`` seconds in the core (:func:`.rollout.motion_rollouts`), entries come at the
block ends.

The transitions come from :attr:`dpgp.DPGP.transitions_`, handed down as an object with ``counts``,
``entry_probs`` and ``dwell(k)``, the phases as :class:`dpgp.evaluate.phases.Phases` (this layer
does not import the evaluation layer)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
import pandas as pd

from .._validate import real_number
from ..data.timeorder import time_order
from ..exceptions import InvalidInputError
from ..gp.fitted import FittedPatterns
from .free_speeds import learn_free_speeds
from .headings import carried, heading_speed, start_headings
from .motion import consecutive_pairs, motion_model
from .rollout import motion_rollouts
from .scenarios import Ego, ego_rule, moving_along
from .stop_lines import learn_stop_lines

MAX_VEHICLES = 400  # a scene never holds more at once (entries beyond are skipped)
#: ``phase_fields="together"``: a phase's field is its patterns' fields together, those of at least
#: this share of its frames (at most :data:`MIXTURE_MAX` of them, the largest), renormalised
MIXTURE_MIN = 0.01
MIXTURE_MAX = 8


@dataclass(frozen=True, eq=False)
class LongScenario:
    """One long scenario: ``table`` rows ``t, vehicle, x, y, vx, vy`` of every vehicle inside the
    ROI at each step; ``patterns[i]`` the pattern in force at ``t[i]``; ``dt`` the step (s)."""

    table: pd.DataFrame
    t: np.ndarray
    patterns: np.ndarray
    dt: float
    #: the phase in force at each step (None: scheduled pattern by pattern)
    phases: np.ndarray | None = None
    #: the ego vehicle's number (``sample_long_scenarios(ego=...)``; -1: none)
    ego: int = -1

    def switches(self) -> int:
        return int(np.count_nonzero(np.diff(self.patterns)))

    def to_pandas(self) -> pd.DataFrame:
        """The table with the pattern in force at each row's step (and the phase, if scheduled by
        phase; and whether the row is the ego's, if the scenario has one)."""
        step = np.rint(self.table["t"].to_numpy() / self.dt).astype(int)
        out = self.table.assign(pattern=self.patterns[step])
        if self.phases is not None:
            out = out.assign(phase=self.phases[step])
        return out if self.ego < 0 else out.assign(ego=self.table["vehicle"].to_numpy() == self.ego)

    @cached_property
    def _grid(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities and presence as (times, vehicles) grids, built once."""
        steps = np.rint(self.table["t"].to_numpy() / self.dt).astype(np.int64)
        vid = self.table["vehicle"].to_numpy().astype(np.int64)
        shape = (len(self.t), int(vid.max()) + 1 if len(vid) else 0)
        pos, vel = np.full((*shape, 2), np.nan), np.full((*shape, 2), np.nan)
        inside = np.zeros(shape, dtype=bool)
        pos[steps, vid] = self.table[["x", "y"]].to_numpy()
        vel[steps, vid] = self.table[["vx", "vy"]].to_numpy()
        inside[steps, vid] = True
        return pos, vel, inside

    @property
    def positions(self) -> np.ndarray:
        """(times, vehicles, 2), NaN where a vehicle is not in the scene (vehicle ``i`` is column
        ``i``), as :class:`~dpgp.generate.simulation.Simulation` holds them: criticality
        measures (:func:`~dpgp.generate.criticality.criticality`) take long scenarios too."""
        return self._grid[0]

    @property
    def velocities(self) -> np.ndarray:
        return self._grid[1]

    @property
    def in_roi(self) -> np.ndarray:
        """(times, vehicles): whether each vehicle is in the scene at each time."""
        return self._grid[2]

    @property
    def steps(self) -> int:
        return len(self.t) - 1


@dataclass(frozen=True, eq=False)
class Entries:
    """Per pattern: track-start positions and velocities, and the entry rate (vehicles per second)."""

    xy: list[np.ndarray]
    v: list[np.ndarray]
    rate: np.ndarray


def learn_entries(fit: FittedPatterns, labels: np.ndarray | None = None, k: int | None = None) -> Entries:
    """Where and how often vehicles enter in each pattern (or, given the frames' ``labels`` of
    ``k`` groups, each phase), from the training frames' track starts."""
    frames = fit.frames
    if frames.tracks is None:
        raise InvalidInputError(
            "long scenarios need the frames' track ids to learn where vehicles enter; make frames "
            "from tracks with dpgp.make_frames"
        )
    order = time_order(frames)
    rows = frames.frame_of_row
    key = np.lexsort((order.time[rows], order.scene[rows], frames.tracks))
    first = key[np.r_[True, frames.tracks[key][1:] != frames.tracks[key][:-1]]]
    first = first[order.prev[rows[first]] >= 0]  # present at a recording's start: not an entry
    labels = fit.labels if labels is None else np.asarray(labels)
    k = fit.n_patterns if k is None else int(k)
    lab = labels[rows[first]]
    n_frames = np.bincount(labels, minlength=k)
    rate = np.bincount(lab, minlength=k) / np.maximum(n_frames * order.dt, 1e-12)
    return Entries([frames.xy[first[lab == j]] for j in range(k)], [frames.v[first[lab == j]] for j in range(k)], rate)


@dataclass(frozen=True, eq=False)
class Area:
    """Where the recording's agents drove: cells of side ``cell`` that a training track passed
    through (consecutive positions joined), grown by one cell. A long scenario drops an agent that
    leaves it, as one that leaves the ROI: the fields carry no lane geometry, and an agent that
    drifted off every recorded path would otherwise stand or wander there for the rest of the
    scenario."""

    origin: np.ndarray
    cell: float
    occupied: np.ndarray

    def contains(self, xy: np.ndarray) -> np.ndarray:
        ij = np.floor((np.asarray(xy, dtype=np.float64).reshape(-1, 2) - self.origin) / self.cell).astype(np.int64)
        n = np.array(self.occupied.shape)
        ok = np.all((ij >= 0) & (ij < n), axis=1)
        out = np.zeros(len(ij), dtype=bool)
        out[ok] = self.occupied[ij[ok, 0], ij[ok, 1]]
        return out


def first_at(scene: LongScenario, rule: Ego, reach: float, min_speed: float = 0.5) -> int:
    """The ego of a long scenario by ``rule``: the first vehicle (by time; the nearest of those at
    that time) within ``reach`` of the rule's point, and with a heading, one moving at least
    ``min_speed`` within :data:`~dpgp.generate.scenarios.EGO_HEADING_TOLERANCE` degrees of it (the
    first to come along that approach); ``-1`` when none does."""
    tab = scene.table
    xy, v = tab[["x", "y"]].to_numpy(), tab[["vx", "vy"]].to_numpy()
    d = np.hypot(xy[:, 0] - rule.x, xy[:, 1] - rule.y)
    ok = d <= reach
    if rule.heading is not None:
        ok &= moving_along(v, rule.heading, min_speed)
    if not ok.any():
        return -1
    rows = np.flatnonzero(ok)
    first = rows[np.lexsort((d[rows], tab["t"].to_numpy()[rows]))[0]]
    return int(tab["vehicle"].to_numpy()[first])


def lane_scale(motion: Any) -> float:
    """The cell of :func:`learn_area`: the width of the corridor in which vehicles follow a leader
    (a lane), for pedestrians their personal distance."""
    lateral = float(motion.lateral)
    return 2 * lateral if np.isfinite(lateral) and lateral > 0 else max(float(motion.personal), 1e-9)


def learn_area(fit: FittedPatterns, cell: float) -> Area:
    """The :class:`Area` of the training frames' tracks (cells of side ``cell``)."""
    frames = fit.frames
    xy = np.asarray(frames.xy, dtype=np.float64)
    a, b = consecutive_pairs(frames, time_order(frames).dt)
    pts = [xy]
    if len(a):  # points along each recorded step, half a cell apart
        n = int(min(np.ceil(np.max(np.hypot(*(xy[b] - xy[a]).T)) / (cell / 2)), 64)) + 1
        for f in np.linspace(0.0, 1.0, n + 1)[1:-1]:
            pts.append(xy[a] + f * (xy[b] - xy[a]))
    allp = np.concatenate(pts)
    origin = allp.min(axis=0) - 2 * cell
    ij = np.floor((allp - origin) / cell).astype(np.int64)
    grid = np.zeros(tuple(ij.max(axis=0) + 3), dtype=bool)
    grid[ij[:, 0], ij[:, 1]] = True
    grown = grid.copy()  # one cell around every visited one
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            grown |= np.roll(np.roll(grid, dx, axis=0), dy, axis=1)
    return Area(origin, float(cell), grown)


def _draw(counts: np.ndarray, rng: np.random.Generator) -> int:
    return int(rng.choice(len(counts), p=counts / counts.sum()))


def _next_of(counts: Any, current: int, fallback: np.ndarray, rng: np.random.Generator) -> int:
    """The next of ``current`` by recorded changes ``counts`` (itself excluded); by ``fallback``
    (another than itself where there is one) if it was never seen to change."""
    row = np.asarray(counts, dtype=np.float64).copy()
    row[current] = 0.0
    if row.sum() <= 0:
        row = np.asarray(fallback, dtype=np.float64).copy()
        if len(row) > 1:
            row[current] = 0.0
    return _draw(row, rng)


def _dwell_steps(runs_s: np.ndarray, dt: float, rng: np.random.Generator) -> int:
    """A dwell (steps) drawn from recorded run lengths in seconds (one step without any)."""
    return max(1, int(round((runs_s[rng.integers(len(runs_s))] if len(runs_s) else dt) / dt)))


class PatternSchedule:
    """Which pattern is in force: the first drawn by how recordings start (else by weight), each
    for a dwell drawn from its recorded runs, the next by the recorded changes (self-transitions
    excluded; by weight for a pattern never seen to change)."""

    def __init__(self, transitions: Any, weights: np.ndarray) -> None:
        self.tr, self.weights = transitions, weights
        self.phase = -1

    def first(self, rng: np.random.Generator) -> tuple[int, int]:
        start = np.asarray(self.tr.entry_probs, dtype=np.float64)
        self.k = _draw(self.weights if start.sum() <= 0 else start, rng)
        return self.k, _dwell_steps(self.tr.dwell(self.k), self.tr.dt, rng)

    def next(self, rng: np.random.Generator) -> tuple[int, int]:
        self.k = _next_of(self.tr.counts[self.k], self.k, self.weights, rng)  # never changed: by weight
        return self.k, _dwell_steps(self.tr.dwell(self.k), self.tr.dt, rng)

    def spent(self, steps: int) -> None:
        pass


class PhaseSchedule:
    """Patterns by phase (:class:`dpgp.evaluate.phases.Phases`): a phase is in force for a
    duration drawn from its recorded runs (phases in a cycle: ``splits="mean"``, every cycle's
    stages last the recorded cycles' mean stage durations, a fixed-time signal's one split; the
    decoded cycles' splits vary where traffic places the stage boundaries, by 5-6 s a stage on the
    SUMO junction; ``"recorded"``, the stages of one recorded cycle together, stretched to the
    recorded cycles' mean length), the next phase by the recorded
    phase changes; within a phase its patterns follow one another as inside its recorded runs
    (the pattern starting a run of the phase, the changes and the pattern runs of its frames
    only), so that the fields in force stay those of one regime."""

    def __init__(self, phases: Any, dt: float, splits: str = "mean") -> None:
        self.ph, self.dt = phases, dt
        self.phase_left = 0
        self.cycles = phases.cycles if phases.cycles is not None and len(phases.cycles) else None
        if self.cycles is not None:
            if splits == "mean":  # a fixed-time signal: one cycle, one split
                self.cycles = self.cycles.mean(axis=0, keepdims=True)
            # the recorded cycles' mean length, in steps
            self.cycle_steps = self.cycles.sum(axis=1).mean() * phases.dt / dt
        self.this_cycle: np.ndarray | None = None

    def _stage_steps(self, p: int, rng: np.random.Generator) -> int:
        """A phase's duration: in a cycle, its stage of the mean cycle, or of one recorded cycle
        drawn when the cycle starts (or the scenario does), so that the stages of a cycle come
        from one recorded cycle, which is stretched to the recorded cycles' mean length (a
        fixed-time signal's cycle has one length; its decoded cycles vary where the traffic
        places their boundaries); else drawn on its own from the phase's recorded runs."""
        if self.cycles is None:
            return _dwell_steps(self.ph.transitions.dwell(p), self.dt, rng)
        if p == 0 or self.this_cycle is None:
            row = self.cycles[rng.integers(len(self.cycles))].astype(np.float64)
            ends = np.rint(np.cumsum(row) * self.cycle_steps / row.sum()).astype(np.int64)  # rounded once
            self.this_cycle = np.diff(np.r_[0, ends])
        return max(1, int(self.this_cycle[p]))

    def _enter(self, p: int, rng: np.random.Generator) -> tuple[int, int]:
        self.phase = p
        self.phase_left = self._stage_steps(p, rng)
        runs = self.ph.pattern_runs[p]
        self.k = int(runs[rng.integers(len(runs)), 0]) if len(runs) else _draw(self.ph.emission[p], rng)
        return self.k, self._pattern_dwell(rng)

    def _pattern_dwell(self, rng: np.random.Generator) -> int:
        runs = self.ph.pattern_runs[self.phase]
        mine = runs[runs[:, 0] == self.k, 1] * self.dt if len(runs) else np.zeros(0)
        return min(_dwell_steps(mine, self.dt, rng), self.phase_left)

    def first(self, rng: np.random.Generator) -> tuple[int, int]:
        start = np.asarray(self.ph.transitions.entry_probs, dtype=np.float64)
        return self._enter(_draw(self.ph.start if start.sum() <= 0 else start, rng), rng)

    def next(self, rng: np.random.Generator) -> tuple[int, int]:
        if self.phase_left <= 0:  # the phase is over: the next one
            counts = self.ph.transitions.counts[self.phase]
            return self._enter(_next_of(counts, self.phase, np.ones(len(counts)), rng), rng)
        row = np.asarray(self.ph.within[self.phase, self.k], dtype=np.float64).copy()
        row[self.k] = 0.0
        if row.sum() > 0:
            self.k = _draw(row, rng)
        return self.k, self._pattern_dwell(rng)

    def spent(self, steps: int) -> None:
        self.phase_left -= steps


def _mixture(shares: np.ndarray) -> list[tuple[int, float]]:
    """A phase's patterns and weights for its field (:data:`MIXTURE_MIN`, :data:`MIXTURE_MAX`)."""
    top = np.argsort(-shares, kind="stable")[:MIXTURE_MAX]
    top = top[shares[top] >= MIXTURE_MIN] if shares[top[0]] >= MIXTURE_MIN else top[:1]
    w = shares[top] / shares[top].sum()
    return [(int(k), float(x)) for k, x in zip(top, w)]


def _largest_in_force(schedule: Any, largest: list[int]) -> tuple[int, int]:
    """With a phase's patterns together: its largest pattern (whose motion applies) for the rest
    of the phase."""
    assert isinstance(schedule, PhaseSchedule)
    return largest[schedule.phase], schedule.phase_left


def sample_long_scenarios(
    fit: FittedPatterns,
    transitions: Any,
    n: int,
    duration: float,
    seed: int | None = None,
    *,
    block: float = 2.0,
    stochastic: bool = True,
    roi: tuple[float, float, float, float] | None = None,
    dynamics: str = "interactive",
    phases: Any = None,
    phase_fields: str = "together",
    cycle_splits: str = "mean",
    stop_lines: bool = True,
    free_speeds: bool = True,
    ego: Any = None,
) -> list[LongScenario]:
    """``n`` :class:`LongScenario` of ``duration`` seconds; see the module's description.
    ``phases`` (:class:`dpgp.evaluate.phases.Phases`): switch by phase (:class:`PhaseSchedule`),
    else pattern by pattern (:class:`PatternSchedule`). ``phase_fields``: ``"together"``, a
    phase's field is its patterns' fields together (each mean weighted by the pattern's share of
    the phase and by what it knows where the vehicle is; the core's ``MixtureField``), vehicles
    enter where the phase's did, and the pattern recorded per step is the phase's largest; ``"in
    turn"``, its patterns follow one another as inside its recorded runs. ``cycle_splits``: phases
    in a cycle last the recorded cycles' mean stage durations (``"mean"``) or, cycle by cycle, one
    recorded cycle's (``"recorded"``; :class:`PhaseSchedule`). ``stop_lines``: by phase,
    vehicles stop at the red signals' stop lines (:func:`.stop_lines.learn_stop_lines`);
    ``free_speeds``: with them, each field is raised to the recorded free speeds where it is
    slower (:func:`.free_speeds.learn_free_speeds`). ``ego``: ``(x, y)`` or ``(x, y, heading in
    degrees)``, each scenario's ego vehicle is the first to come within a lane's width
    (:func:`lane_scale`) of that point, along that heading (:func:`first_at`)."""
    rule = ego_rule(ego)
    if rule is not None and rule.placed:
        raise InvalidInputError(
            "a placed ego joins scenarios of steps (sample_scenarios); in long scenarios the ego is the first vehicle "
            "to come to a point: give ego=(x, y) or (x, y, heading)"
        )
    if phase_fields not in ("together", "in turn"):
        raise InvalidInputError(f"phase_fields must be 'together' or 'in turn', got {phase_fields!r}")
    if cycle_splits not in ("mean", "recorded"):
        raise InvalidInputError(f"cycle_splits must be 'mean' or 'recorded', got {cycle_splits!r}")
    for name, value in (("duration", duration), ("block", block)):
        seconds = real_number(name, value)
        if not (np.isfinite(seconds) and seconds > 0):
            raise InvalidInputError(f"{name} must be a positive number of seconds, got {value!r}")
    dt = float(transitions.dt)
    steps = int(round(duration / dt))
    bsteps = max(1, int(round(block / dt)))
    box = fit.roi if roi is None else roi
    together = phases is not None and phase_fields == "together"
    # where vehicles enter: by pattern, or with a phase's patterns together, by phase
    entries = learn_entries(fit, phases.labels, phases.n_phases) if together else learn_entries(fit)
    if together:
        shares = phases.frame_shares
        mixtures = [_mixture(shares[p]) for p in range(phases.n_phases)]
        largest = [int(np.argmax(shares[p])) for p in range(phases.n_phases)]
    motion = motion_model(fit)
    area = learn_area(fit, lane_scale(motion))
    lines = learn_stop_lines(fit, phases.labels, phases.n_phases, motion) if phases is not None and stop_lines else None
    free = learn_free_speeds(fit, lane_scale(motion), motion) if lines is not None and free_speeds else None
    # what the core takes, once: each phase's red lines, the free-speed map
    red_lines = None if lines is None else [lines.in_force(p) for p in range(phases.n_phases)]
    free_map = None if free is None else free.core()
    rng = np.random.default_rng(seed)
    speed = heading_speed(fit)
    weights = np.asarray(fit.weights, dtype=np.float64)
    out = []
    for _ in range(int(n)):
        schedule = (
            PhaseSchedule(phases, dt, cycle_splits) if phases is not None else PatternSchedule(transitions, weights)
        )
        k, left = schedule.first(rng)
        if together:
            k, left = _largest_in_force(schedule, largest)
        members = phases.labels == schedule.phase if together else fit.labels == k
        f = fit.frames[int(rng.choice(np.flatnonzero(members)))]
        pos, vel = np.c_[f.x, f.y], np.c_[f.vx, f.vy]
        # a field over heading: each vehicle's previous heading, carried from block to block
        head = start_headings(vel, f.prev_heading, speed, len(pos))
        ids = np.arange(len(pos))
        drivers = None  # each vehicle's driver state, carried from block to block
        next_id = len(pos)
        chunks = [(np.zeros(len(pos)), ids, pos, vel)]
        patterns = np.empty(steps + 1, dtype=np.int64)
        in_phase = np.full(steps + 1, -1, dtype=np.int64)
        patterns[0], in_phase[0] = k, schedule.phase
        s = 0
        renew = False
        while s < steps:
            m = min(bsteps, left, steps - s)
            if len(pos):
                sim = motion_rollouts(
                    fit, [k], [pos], [vel], steps=m, dt=dt, seeds=[int(rng.integers(2**63))] if stochastic else None,
                    roi=box, low_data_threshold=None, dynamics=dynamics, motion=motion,
                    drivers=None if drivers is None else [drivers], support=True,
                    mixtures=[mixtures[schedule.phase]] if together else None, renew=renew,
                    stops=None if red_lines is None else [red_lines[schedule.phase]], free_speeds=free_map,
                    headings=[head],
                )[0]  # fmt: skip
                on_road = np.stack([area.contains(sim.positions[j]) for j in range(m + 1)])
                left_area = np.logical_or.accumulate(~on_road & sim.in_roi, axis=0)  # dropped from there on
                for j in range(1, m + 1):
                    keep = sim.in_roi[j] & ~left_area[j]
                    chunks.append(
                        (np.full(keep.sum(), (s + j) * dt), ids[keep], sim.positions[j][keep], sim.velocities[j][keep])
                    )
                keep = sim.in_roi[m] & ~left_area[m]
                head = carried(sim.velocities, head, speed)[keep]
                pos, vel, ids = sim.positions[m][keep], sim.velocities[m][keep], ids[keep]
                assert sim.drivers is not None
                drivers = sim.drivers[keep]
            patterns[s + 1 : s + m + 1] = k
            in_phase[s + 1 : s + m + 1] = schedule.phase
            s += m
            left -= m
            schedule.spent(m)
            renew = False
            if left == 0:
                before = schedule.phase
                k, left = schedule.next(rng)
                if together:
                    k, left = _largest_in_force(schedule, largest)
                    # the drivers see the stage change: a queue released at green wants to go
                    renew = schedule.phase != before
            # new vehicles of the pattern (or phase) now in force, where its vehicles entered
            e = schedule.phase if together else k
            arrivals = rng.poisson(entries.rate[e] * m * dt) if len(entries.xy[e]) else 0
            gap = max(motion.spacing[k] if len(motion.spacing) > k else 0.0, 1e-9)
            for _a in range(min(arrivals, MAX_VEHICLES - len(pos))):
                i = int(rng.integers(len(entries.xy[e])))
                p = entries.xy[e][i]
                if len(pos) and np.min(np.hypot(*(pos - p).T)) < gap:
                    continue  # the entry is occupied
                pos, vel = np.r_[pos, p[None]], np.r_[vel, entries.v[e][i][None]]
                head = np.r_[head, start_headings(entries.v[e][i][None], None, speed, 1)]
                if drivers is not None:
                    drivers = np.r_[drivers, motion.driver_states(entries.v[e][i])]
                ids = np.r_[ids, next_id]
                next_id += 1
        t, vid, xy, v = (np.concatenate([c[i] for c in chunks]) for i in range(4))
        table = pd.DataFrame({"t": t, "vehicle": vid, "x": xy[:, 0], "y": xy[:, 1], "vx": v[:, 0], "vy": v[:, 1]})
        scene = LongScenario(table, np.arange(steps + 1) * dt, patterns, dt, None if phases is None else in_phase)
        out.append(scene if rule is None else replace(scene, ego=first_at(scene, rule, lane_scale(motion))))
    return out


__all__ = ["LongScenario", "Entries", "learn_entries", "sample_long_scenarios", "first_at"]
