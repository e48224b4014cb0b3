"""The DP-GP estimator: a Dirichlet-process mixture of Gaussian-process velocity fields, fitted by
collapsed Gibbs sampling in the Rust core. Follows scikit-learn's conventions: settings in
``__init__``, ``fit`` returns ``self``, learned state ends in ``_``."""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import _core
from .._arrays import MAX_MAGNITUDE as _MAX_MAGNITUDE
from .._arrays import compact_labels
from .._constants import LOW_DATA_THRESHOLD
from .._resources import check_thread_reservations, default_memory_budget, parse_bytes
from ..data.frames import Frames, as_frames
from ..evaluate.metrics import adjusted_rand_index, adjusted_rand_index_of_table, canonical_labels
from ..evaluate.transitions import Transitions, count_transitions
from ..exceptions import (
    DpgpError,
    InvalidInputError,
    MemoryBudgetError,
    ModelFileError,
    NotFittedError,
    UnorderedFramesError,
)
from ..gp.defaults import NOISE_PRIOR
from ..gp.draws import MAX_DRAWS, Draws
from ..gp.exact import GPParams, _pair, check_scales
from ..gp.fitted import FittedPatterns
from ..gp.hsgp import _basis_counts, basis_for
from ..io import checkpoint as ckpt

if TYPE_CHECKING:
    from ..io.modelfile import ModelState

_DYNAMICS = (None, "sticky")
_SAMPLERS = ("auto", "subcluster", "collapsed")
_INPUTS = ("position", "position+heading", "auto")
#: Gamma(shape, scale) prior of a pattern's heading length scale w_h (radians): mean 1.2, 5% and
#: 95% quantiles 0.52 and 2.1. Headings π apart then correlate at exp(-2/w_h²) ≈ 0.25 at the
#: mean (opposite lanes are told apart), π/2 apart (a turn) at 0.5.
HEADING_PRIOR = (6.0, 0.2)
#: Most heading harmonics of a reduced-rank basis: 2J heading functions beside the constant.
MAX_HEADING_HARMONICS = 3
#: A reduced-rank basis's heading functions multiply the lowest ``m' = min(m, max(ceil(m / stride),
#: min_count))`` position functions per axis, not all ``m``: the field's dependence on heading
#: (which lane's direction, which turn) varies over longer distances than the field, and every
#: factorisation is ``M x M`` (issue 34: with all of them a sweep over heading cost 32 times one
#: over position at J = 1 on the SUMO junction, 22 x 22 functions). The floor keeps small bases
#: whole: Peachtree's 10 x 11 on 3 x 3 heading blocks lost its turns (realism 0.77 against 0.93
#: whole). docs/heading.md has the measurements.
HEADING_BASIS_STRIDE = 4
HEADING_BASIS_MIN_COUNT = 10
#: The evidence ``inputs="auto"`` decides by (issue 34: the heading form where the data have tracks
#: only if the held-out comparison shows it better on every shared vehicle set): held-out log
#: density of the velocities given the positions, nats per vehicle, of ``inputs="position+heading"``
#: less ``inputs="position"``, the posterior predictive of each fit (``python benches/heading.py
#: --seeds 5 --average``: 20 sweeps, exact engine, collapsed sampler, the same seed for both; one
#: margin per seed; the three frame files linked by ``dpgp.link_tracks``). Auto takes the heading
#: form only when every margin is positive. The frame files (US-101, Lankershim, the left turn)
#: gain on every seed; Peachtree is split and the SUMO junction (2 s frames) loses on 4 of 5, so
#: today auto fits fields over position. The pedestrian sets are judged on their own and are not
#: in this table: ETH +1.28 ± 0.03, Zara 01 +1.98 ± 0.03 on every seed (every 2nd training frame,
#: docs/heading.md), but auto does not yet fit pedestrians over heading (10-330 times the sweep;
#: generation over heading on them unmeasured).
#: Measure again and update this table when the model changes.
HEADING_EVIDENCE: dict[str, tuple[float, ...]] = {
    "peachtree": (-0.188, -0.088, 1.555, -0.641, -2.235),
    "sumo_grid": (-1.405, -0.543, -1.167, -1.139, 0.352),  # the SUMO junction at 2 s frames
    "us101": (0.121, 0.018, 0.221, 0.164, 0.266),
    "lankershim": (0.061, 0.036, 0.065, 0.092, 0.004),
    "left_turn": (0.232, 0.075, 0.005, 0.064, 0.201),
}
_INITS = ("sequential", "one", "many")
#: Why ``sampler="auto"`` runs the sub-cluster sampler where it can (engine_choice_["sampler"]).
SUBCLUSTER_REASON = (
    "hsgp: the sub-cluster sampler sweeps every frame in parallel at O(N K M), where the collapsed "
    "sampler's split-merge moves walk patterns frame by frame (100k frames: 0.25 s a sweep against "
    "3 sweeps unfinished in 600 s); on 1,000 US-101 frames its chains mix no worse "
    "(docs/subcluster.md#measured)"
)


def choose_inputs(
    has_tracks: bool, evidence: dict[str, tuple[float, ...]] | None = None, blocked: str | None = None
) -> dict[str, Any]:
    """``inputs="auto"``'s rule (issue 34), as ``engine_choice_["inputs"]`` records it:
    ``{"inputs", "why", "evidence"}``. Frames without previous headings (no tracks):
    ``"position"``. Else ``"position+heading"`` only if every held-out margin of ``evidence``
    (default :data:`HEADING_EVIDENCE`: set -> heading minus position, nats per vehicle, one per
    seed) is positive and nothing in the settings (``blocked``: why not) keeps the heading form
    from running; otherwise ``"position"``, saying which sets it lost on."""
    evidence = HEADING_EVIDENCE if evidence is None else evidence
    figures = {name: [float(m) for m in margins] for name, margins in evidence.items()}
    if not has_tracks:
        return {"inputs": "position", "why": "auto: the frames carry no previous headings (no tracks)"}
    shown = "; ".join(f"{name} {', '.join(f'{m:+.2f}' for m in margins)}" for name, margins in figures.items())
    losing = [name for name, margins in figures.items() if not margins or min(margins) <= 0]
    if losing or not figures:
        why = (
            "auto: the held-out comparison (benches/heading.py; heading minus position, nats per vehicle: "
            f"{shown or 'none measured'}) does not show fields over heading better on every set "
            f"(not on {', '.join(losing) or 'any'})"
        )
        return {"inputs": "position", "why": why, "evidence": figures}
    if blocked is not None:
        why = f"auto: the held-out comparison favours fields over heading on every set ({shown}), but {blocked}"
        return {"inputs": "position", "why": why, "evidence": figures}
    why = f"auto: the frames have tracks and fields over heading were better held out on every set ({shown})"
    return {"inputs": "position+heading", "why": why, "evidence": figures}


# ρ ~ Beta(1, 1) under dynamics="sticky": uniform, so the recording decides how sticky its scene is
# (thousands of links outweigh it); a prior favouring stickiness would hide a scene that flickers.
STICKINESS_PRIOR = (1.0, 1.0)

#: Times a fit sets its shards' labels again and redoes its sweeps (a worker replaced) before it
#: gives up and raises :class:`dpgp.model.sharded.LabelsLost`.
_MAX_REDOS = 3


def _heading_counts(counts: tuple[int, int]) -> tuple[int, int]:
    """The heading blocks' position functions per axis for position counts ``counts``
    (:data:`HEADING_BASIS_STRIDE`, :data:`HEADING_BASIS_MIN_COUNT`)."""
    coarse = [max(-(-m // HEADING_BASIS_STRIDE), HEADING_BASIS_MIN_COUNT) for m in counts]
    return (min(counts[0], coarse[0]), min(counts[1], coarse[1]))


def _heading_size(counts: tuple[int, int]) -> int:
    """``m'_x m'_y`` of :func:`_heading_counts`."""
    hx, hy = _heading_counts(counts)
    return hx * hy


class DPGP:
    """Dirichlet-process mixture of GP motion patterns.

    Parameters
    ----------
    iterations : Gibbs sweeps after the sequential initialisation.
    assignment : ``"gibbs"`` draws each frame's pattern from its conditional (a true collapsed
        Gibbs sampler); ``"map"`` takes the most probable one (the paper's Algorithm 1).
    likelihood : ``"exact"``: the full GP, whose cost grows with the cube of a pattern's size;
        ``"hsgp"``: the Hilbert-space reduced-rank GP (Solin & Särkkä 2020) on a basis over a box
        around the data, whose moves, scores and length-scale steps cost the same whatever the
        pattern's size (memory ``K · M²``); ``"auto"`` (default): the engine whose sweep a cost
        model calibrated on both predicts to be faster, decided before the chain starts (from
        the worst case, else from hsgp's initialisation) and never switched mid-fit
        (:mod:`dpgp.engine_cost`). Which one ran: ``likelihood_``; why: ``engine_choice_``. For
        fields over heading the same rule with hsgp's basis ``2J + 1`` times the position one
        (``engine_choice_["heading_functions"]``) and an accuracy probe that uses the headings
        (:mod:`dpgp.model.engine_cost`).
    n_basis : ``(m_x, m_y)`` basis functions per axis for hsgp; ``None`` sizes them from the data's
        extent and the lower tail of the length-scale prior (:func:`dpgp.hsgp.basis_for`).
    proposal : ``"informed"`` (default): Metropolis-within-Gibbs; each frame proposes a pattern
        by a cheap score over all patterns (cell means of their velocities) and accepts by the
        exact ratio of the proposed and current patterns, so the chain targets the same
        posterior at a fraction of the cost. ``"full"``: draw from the full conditional (every
        pattern scored exactly). Informed is the default because it gives the most effective
        samples per second (README, "How it is fast"). Frames without a pattern (the sequential
        initialisation) are placed by the full conditional; past 1,000 frames the rest join
        patterns by cheap score. With ``assignment="map"``, "informed" takes the exact argmax
        over the frame's own pattern, the two patterns the cheap score ranks highest, and a new
        one.
    memory_budget : bytes the patterns may hold (an int, or a string such as ``"4GB"``); a fit
        that would grow past it stops with :class:`~dpgp.MemoryBudgetError` before allocating,
        keeping the state reached. ``None`` (default): half of the memory available at the
        start of the fit.
    length_scale_prior : ``(shape, scale)`` of the Gamma prior of each length scale, in data
        units; ``"auto"`` (default): shape 10 with the mean at twice the data's spacing, the
        median distance between nearest vehicles of a frame (:mod:`dpgp.defaults`). Resolved value in
        ``length_scale_prior_``.
    length_scales : ``None`` samples ``(w_x, w_y)`` per pattern; a pair fixes them for all patterns.
    noise_var : observation noise variance σ_n² (velocity units squared), one number for both
        velocity components or a pair ``(x, y)``, fixed; ``"auto"`` (default, also
        ``"per_pattern"``): sampled inside the chain each sweep under a prior relative to each
        component's velocity variance (docs/inference.md), each pattern its own pair
        (``pattern_noise_var_``, (K, 2)); ``"global"``: one pair sampled for all patterns; ``"pilot"``: chosen
        before sampling by the held-out score of short pilot fits (:mod:`dpgp.defaults`). The
        pair the fit ends at is ``noise_var_`` (per pattern: the frame-weighted median of the
        patterns' pairs, per component), each sweep's in ``history_["noise_var_x"]``,
        ``history_["noise_var_y"]``.
    split_merge : split–merge moves (docs/inference.md) after each sweep's frame updates; 0
        turns them off; ``"auto"`` (default): :data:`dpgp.defaults.SPLIT_MERGE_MOVES`. Their
        proposals and acceptances per sweep are in ``history_`` (``split_proposed``, ...).
    split_merge_pairs : ``"informed"`` (default) or ``"uniform"``: how the second frame of a
        move's pair is drawn (half the time by similar mean velocity when informed).
    sampler : ``"subcluster"``: the parallel sub-cluster sampler (hsgp only; docs/inference.md,
        "The sub-cluster sampler"): each sweep draws every pattern's field and mixture weight, then
        every frame's pattern in parallel given them, and splits and merges whole patterns by
        Metropolis–Hastings moves built from two sub-patterns; exact, like the collapsed sampler,
        and its sweep costs ``O(frames · K · M)`` instead of ``O(frames · K · M²)``.
        ``"collapsed"``: the paper's collapsed Gibbs sampler, one frame at a time (the only one
        for ``likelihood="exact"``, ``dynamics="sticky"`` and ``pattern_moments``). ``"auto"``
        (default): the sub-cluster sampler wherever it can run, since it reached convergence
        sooner on every benchmark (docs/performance); with ``likelihood="auto"`` the engine is
        chosen for it (:mod:`dpgp.engine_cost`). Which ran: ``sampler_``; why:
        ``engine_choice_["sampler"]``.
    init : where the chain starts: ``"sequential"`` (default): frames placed one by one by the
        conditional (then, past 1,000 frames, by cheap score; on the sub-cluster sampler, pairs
        of the patterns found are then merged while a merge raises the log joint, because its
        moves rarely undo a pattern the start divided); ``"one"``: every frame in one
        pattern; ``"many"``: every frame its own pattern, or 256 contiguous blocks of frames on
        larger data. ``fit_chains(init="dispersed")`` starts chains from one and from many.
    inputs : ``"position"`` (default): each pattern's field maps a position to a velocity, the
        paper's model. ``"position+heading"``: the field also takes each vehicle's previous
        heading (docs/heading.md), so opposite lanes and turning movements at one place no longer
        average; the kernel is the squared exponential times a periodic kernel in heading, whose
        length scale each pattern samples (``heading_scales_``, prior :data:`HEADING_PRIOR`).
        Needs frames made by :func:`dpgp.make_frames` from tracks (they carry ``prev_heading``);
        runs with either engine or ``likelihood="auto"``, on the collapsed sampler or (hsgp) the
        sub-cluster one, which ``sampler="auto"`` picks for hsgp as over position. Model files,
        checkpoints and posterior draws keep each pattern's heading length scale. Not yet:
        ``dynamics``, ``fit_chains``, frames in shards. ``"auto"``: fields over position for
        frames without previous headings (no tracks); for frames with them, the heading form
        only if the held-out comparison :data:`HEADING_EVIDENCE` favours it on every set (today
        it does not: ``"position"``), and only where the other settings can run it. The input
        that ran: ``inputs_``; why: ``engine_choice_["inputs"]``.
    dynamics : ``None`` (default): frames are exchangeable, the paper's independent DP.
        ``"sticky"``: a Markov prior on consecutive frames' labels (docs/dynamics.md): each
        frame stays in its predecessor's pattern with probability ρ (``stickiness_``, sampled
        under a Beta(1, 1) prior; per sweep in ``history_["stickiness"]``), else draws afresh
        from the DP. Needs frames with times (:class:`~dpgp.exceptions.UnorderedFramesError`
        otherwise); not with ``checkpoint`` yet.
    preset : ``"paper"``: the paper's settings wherever ``"auto"`` is left — Gamma(10, 1)
        length scales (feet), σ_n² = 1 ((ft/s)²) — and map assignment. :meth:`paper` builds one.
    signal_var, mean : per-output signal variance and mean; ``None`` takes the variance and mean
        of the training velocities.
    alpha : DP concentration; ``None`` samples it (starting from a draw of its prior).
    new_pattern_samples : auxiliary patterns of Neal's Algorithm 8 for the new-pattern term.
    length_scale_fraction : share of the patterns whose length scales are slice-sampled each
        sweep, drawn at random per pattern and sweep (1.0: all, every sweep). Lower values keep
        the cached scores of the others and make sweeps much cheaper; the chain still targets
        the same posterior.
    pattern_moments : set each pattern's signal variances and means to those of its own
        velocities at every parameter step (as the paper's code does; never during the
        assignment sweep). Off by default: the chain then no longer targets a fixed model.
    seed : the run is a function of (data, settings, seed), whatever ``n_threads``.
    n_threads : worker threads (``None``: all cores).
    progress : show a progress bar.
    n_iter_no_change : stop early once K is unchanged and the adjusted Rand index between
        consecutive sweeps is at least ``ari_tol`` for this many sweeps (``None``: run all sweeps).
    store_labels : keep the labels after every sweep in ``label_trace_``.
    checkpoint : a file path: ``fit`` writes the chain's complete state there after the
        initialisation and every ``checkpoint_every`` sweeps, atomically (a temporary file, then a
        rename), and the final model when it ends; :meth:`resume` continues the chain from it. A
        checkpoint is a model file (:meth:`load` reads it). A fit killed at any point and resumed
        gives bitwise the labels, length scales, α and history (but the seconds) of the same fit
        run without interruption. At each checkpoint the fit rebuilds its sampler from the state
        it wrote, as resuming does (:mod:`dpgp.checkpoint` says why); a fit without checkpoints
        rebuilds at the same cadence, so both give bitwise the same result.
        ``checkpoint_seconds_`` records each rebuild's ``"reset"`` and each write's ``"write"``
        seconds.
    checkpoint_every : sweeps between checkpoints, and between the sampler's canonical rebuilds
        (after the initialisation and every ``checkpoint_every`` sweeps, with or without a file).
    posterior_draws : the most posterior states (labels, length scales, α of a sweep) the fit
        keeps, thinned evenly over the chain, for posterior-averaged scores (``average=True`` of
        :meth:`score_samples` and :meth:`predict_proba`; :meth:`evaluate` by default). Memory:
        ``posterior_draws · (b N + 16 K + 16)`` bytes, ``b = 1`` below 256 patterns
        (:mod:`dpgp.posterior`); a fit over shards keeps the ``b N`` in a temporary directory on
        disk instead. 0 keeps none.
    """

    def __init__(
        self,
        iterations: int = 100,
        assignment: str = "gibbs",
        likelihood: str = "auto",
        length_scale_prior: tuple[float, float] | str = "auto",
        length_scales: tuple[float, float] | None = None,
        noise_var: float | tuple[float, float] | str = "auto",
        signal_var: float | tuple[float, float] | None = None,
        mean: float | tuple[float, float] | None = None,
        alpha: float | None = None,
        new_pattern_samples: int = 100,
        length_scale_fraction: float = 1.0,
        pattern_moments: bool = False,
        seed: int = 0,
        n_threads: int | None = None,
        progress: bool = True,
        n_iter_no_change: int | None = None,
        ari_tol: float = 0.99,
        store_labels: bool = False,
        preset: str | None = None,
        proposal: str = "informed",
        n_basis: tuple[int, int] | None = None,
        memory_budget: int | str | None = None,
        checkpoint: str | os.PathLike | None = None,
        checkpoint_every: int = 10,
        posterior_draws: int = MAX_DRAWS,
        split_merge: int | str = "auto",
        split_merge_pairs: str = "informed",
        dynamics: str | None = None,
        sampler: str = "auto",
        init: str = "sequential",
        inputs: str = "position",
    ) -> None:
        self.iterations = iterations
        self.assignment = assignment
        self.likelihood = likelihood
        self.length_scale_prior = length_scale_prior
        self.length_scales = length_scales
        self.noise_var = noise_var
        self.signal_var = signal_var
        self.mean = mean
        self.alpha = alpha
        self.new_pattern_samples = new_pattern_samples
        self.length_scale_fraction = length_scale_fraction
        self.pattern_moments = pattern_moments
        self.seed = seed
        self.n_threads = n_threads
        self.progress = progress
        self.n_iter_no_change = n_iter_no_change
        self.ari_tol = ari_tol
        self.store_labels = store_labels
        self.preset = preset
        self.proposal = proposal
        self.n_basis = n_basis
        self.memory_budget = memory_budget
        self.checkpoint = checkpoint
        self.checkpoint_every = checkpoint_every
        self.posterior_draws = posterior_draws
        self.split_merge = split_merge
        self.split_merge_pairs = split_merge_pairs
        self.dynamics = dynamics
        self.sampler = sampler
        self.init = init
        self.inputs = inputs

    # Set outside __init__ (not settings): a resumed chain's start, the generation cache, and
    # whether Ctrl-C keeps the state reached (a pilot fit's does not).
    resumed_from_: int
    _cache: dict[str, Any]
    _keep_state_on_interrupt: bool
    _resume_point: ckpt.ResumePoint  # the last checkpoint's state (with checkpoint=)
    _heading_stored: dict[str, Any]  # a loaded model's w_h prior and heading harmonics (fields over heading)

    # --- scikit-learn conventions ---------------------------------------------------------------
    def get_params(self, deep: bool = True) -> dict[str, Any]:
        import inspect

        return {
            name: getattr(self, name) for name in inspect.signature(type(self).__init__).parameters if name != "self"
        }

    def set_params(self, **params: Any) -> DPGP:
        valid = self.get_params()
        for key, value in params.items():
            if key not in valid:
                raise InvalidInputError(f"unknown parameter {key!r}; valid: {sorted(valid)}")
            setattr(self, key, value)
        return self

    def __repr__(self) -> str:
        defaults = type(self)().get_params()
        changed = {k: v for k, v in self.get_params().items() if not _same(v, defaults[k])}
        return f"DPGP({', '.join(f'{k}={v!r}' for k, v in changed.items())})"

    @classmethod
    def paper(cls, **params: Any) -> DPGP:
        """The paper's settings: Gamma(10, 1) length-scale prior, σ_n² = 1 and map assignment
        (``preset="paper"``); other settings as keyword arguments."""
        return cls(preset="paper", **params)

    def _resolve_defaults(self, frames: Frames) -> None:
        """Resolve the ``"auto"`` settings and the preset against the training frames
        (:mod:`dpgp.defaults`) into ``assignment_``, ``noise_var_``, ``length_scale_prior_``."""
        from ..gp.defaults import resolve

        r = resolve(
            frames, preset=self.preset, assignment=self.assignment, noise_var=self.noise_var,
            length_scale_prior=self.length_scale_prior, signal_var=self.signal_var, mean=self.mean,
            pilot=self._pilot_fit,
        )  # fmt: skip
        self.assignment_ = r.assignment
        self.noise_var_ = r.noise_var
        self.length_scale_prior_ = r.length_scale_prior
        self.defaults_ = r

    def _pilot_fit(
        self, train: Frames, test: Frames, noise_var: tuple[float, float], length_scale_prior: tuple[float, float]
    ) -> float:
        """Held-out log density of ``test`` under a short map fit to ``train`` with these
        settings: the pilot of ``noise_var="auto"``."""
        from ..gp.defaults import PILOT_SWEEPS

        # proposal "full": the exact argmax, unit-free whatever the main fit's proposal
        # Pilots are small: with likelihood="auto" they keep the previous rule (exact up to 3,000
        # points) rather than pay auto's hsgp probe 24 times (dpgp.engine_cost).
        likelihood = self.likelihood if self.likelihood != "auto" else ("exact" if train.n_points <= 3000 else "hsgp")
        settings = {**self.get_params(), "inputs": self.__dict__.get("inputs_", self.inputs), "likelihood": likelihood, "iterations": PILOT_SWEEPS, "assignment": "map", "noise_var": noise_var,
                    "length_scale_prior": length_scale_prior, "preset": None, "progress": False,
                    "n_iter_no_change": None, "store_labels": False, "proposal": "full", "checkpoint": None, "split_merge": 0}  # fmt: skip
        pilot = type(self)(**settings)
        pilot._keep_state_on_interrupt = False  # Ctrl-C in a pilot stops the whole fit
        pilot.fit(train)
        return float(pilot.score_samples(test, positions=False).sum())

    # --- fitting ----------------------------------------------------------------------------------
    def _check_settings(self) -> None:
        """Check the settings before any work. The sampler's settings are the core's to check
        (``_core.check_settings``: names, ranges and limits, one place for each rule,
        docs/engine-layout.md); here only the estimator's own and the ``"auto"`` resolutions."""
        if self.n_basis is not None:
            _basis_counts(self.n_basis)
        parse_bytes("memory_budget", self.memory_budget)
        if not (isinstance(self.iterations, (int, np.integer)) and self.iterations >= 0):
            raise InvalidInputError(f"iterations must be a non-negative integer, got {self.iterations!r}")
        if self.n_iter_no_change is not None and not (_is_int(self.n_iter_no_change) and self.n_iter_no_change >= 1):
            raise InvalidInputError(
                f"n_iter_no_change must be a positive integer or None, got {self.n_iter_no_change!r}"
            )
        t = self.ari_tol
        if isinstance(t, bool) or not isinstance(t, (int, float, np.integer, np.floating)) or not 0 <= t <= 1:
            raise InvalidInputError(f"ari_tol must be a number in [0, 1], got {t!r}")
        ckpt.check_settings(self.checkpoint, self.checkpoint_every)
        if not (_is_int(self.posterior_draws) and 0 <= self.posterior_draws <= 100_000):
            raise InvalidInputError(f"posterior_draws must be an integer in [0, 100000], got {self.posterior_draws!r}")
        if self.dynamics not in _DYNAMICS:  # the estimator's own: it decides what the core is given
            raise InvalidInputError(f"dynamics must be None or 'sticky', got {self.dynamics!r}")
        if self.sampler not in _SAMPLERS:
            raise InvalidInputError(f"sampler must be one of {_SAMPLERS}, got {self.sampler!r}")
        if self.init not in _INITS:
            raise InvalidInputError(f"init must be one of {_INITS}, got {self.init!r}")
        if self.inputs not in _INPUTS:
            raise InvalidInputError(f"inputs must be one of {_INPUTS}, got {self.inputs!r}")
        if self.inputs == "position+heading":  # as given: "auto" only picks it where it can run
            if self.dynamics is not None:
                raise InvalidInputError("inputs='position+heading' runs without dynamics for now: use dynamics=None")
        if self.dynamics is not None and self.checkpoint is not None:
            raise InvalidInputError("dynamics='sticky' cannot write checkpoints yet (its links are not stored in them)")
        _core.check_settings(self._sampler_settings())

    def _headed(self) -> bool:
        """Whether the fields take the vehicles' previous headings as input: the input the fit
        resolved (``inputs_``), else the setting (``"auto"`` before a fit: not yet)."""
        return self.__dict__.get("inputs_", self.inputs) == "position+heading"

    def _resolve_inputs(self, frames: Frames, manifest: Any = None) -> None:
        """``inputs_`` for the training ``frames`` (or the shards of ``manifest``), and why
        (``engine_choice_["inputs"]``, added once the engine is resolved): ``inputs="auto"``
        decided by :func:`choose_inputs`, else as given."""
        tracks = frames.prev_heading is not None if manifest is None else manifest.has_headings
        if self.inputs != "auto":
            self.inputs_, self._inputs_choice = self.inputs, {"inputs": self.inputs, "why": "given"}
            return
        blocked = None
        if self.dynamics is not None:
            blocked = "dynamics='sticky': fields over heading run without dynamics, for now"
        choice = choose_inputs(tracks, blocked=blocked)
        self.inputs_, self._inputs_choice = choice["inputs"], choice

    def _sampler_settings(self) -> _core._SamplerSettings:
        """The settings of the core sampler as the user gave them (``"auto"`` resolved where no
        data is needed), unchecked: the core validates them. ``_new_sampler`` adds what the
        data decide."""
        settings: _core._SamplerSettings = {
            "assignment": self.assignment,
            "proposal": self.proposal,
            "split_merge_pairs": self.split_merge_pairs,
            "fixed_length_scales": self.length_scales is not None,
            "alpha": self.alpha,
            "new_pattern_samples": self.new_pattern_samples,
            "seed": self.seed,
            "n_threads": self.n_threads,
            "length_scale_fraction": self.length_scale_fraction,
            "pattern_moments": self.pattern_moments,
            "split_merge": _split_merge_moves(self.split_merge),
        }
        if not _is_auto(self.likelihood):  # "auto" is decided from the data (_resolve_engine)
            settings["likelihood"] = self.likelihood
        if not _is_auto(self.sampler):
            settings["sampler"] = self.sampler
        return settings

    def fit(self, frames: Frames | Any, y: None = None, *, warm_start: bool = False, client: Any = None) -> DPGP:
        """Fit the mixture to training frames (a :class:`~dpgp.Frames`, a framed DataFrame, or a directory
        of frame shards written by :meth:`~dpgp.Frames.to_parquet`).

        **Shards.** A directory is fitted as its shards by one sub-cluster chain (the reduced-rank
        engine), in this process or, with ``client`` (a ``dask.distributed.Client``), with each
        shard read and served by a worker, so that no process holds all frames. The same seed and
        shards give the same chain either way (:mod:`dpgp.model.sharded`). The data-dependent
        settings then come from a sample of the frames
        (:data:`~dpgp.model.sharded.SAMPLE_FRAMES`) and the positions' extent. Settings that need
        every frame in one process (``likelihood="exact"``, ``sampler="collapsed"``, ``dynamics``,
        ``pattern_moments``) read the directory into memory, and refuse a ``client``.

        ``warm_start=True`` continues this fitted model's chain on the same frames for
        ``iterations`` more sweeps instead of starting afresh: the sampler, its random stream,
        ``history_``, ``label_trace_`` and the kept draws carry on, and the canonical rebuilds keep
        their cadence (``checkpoint_every`` sweeps counted from the chain's start), so ``fit`` of
        10 sweeps continued by 10 is bitwise a fit of 20. The stopping rule
        (``n_iter_no_change``) counts afresh from the continuation. A model never fitted starts
        afresh, as scikit-learn's ``warm_start`` does."""
        from .sharded import ShardSource, check_client, manifest_of

        manifest = manifest_of(frames)
        check_client(client, manifest)
        given = frames if isinstance(frames, ShardSource) else None  # shared by fit_chains' chains
        if given is not None:
            client = given.client
        if warm_start and hasattr(self, "_sampler"):
            return self._continue(frames)
        self.__dict__.pop("inputs_", None)  # a fresh chain resolves its inputs afresh
        self._check_settings()
        self.__dict__.pop("_heading_stored", None)  # a fresh chain runs with this dpgp's heading prior
        sharded = manifest is not None and self._runs_on_shards(client)
        if sharded and manifest is not None and self.inputs == "position+heading" and not manifest.has_headings:
            raise InvalidInputError(
                f"inputs='position+heading' needs previous headings, and the shards in {manifest.directory} carry "
                "none: write them from frames made by make_frames from tracks, or fit with inputs='position'"
            )
        if self.checkpoint is not None:
            ckpt.check_path(self.checkpoint)  # before the work, not after the initialisation
        extent, data_sha256, source = None, None, None
        if sharded:
            assert manifest is not None
            source = given or ShardSource(manifest, client)
            frames, extent, data_sha256 = source.sample(fingerprint=self.checkpoint is not None)
            _check_magnitudes(
                Frames.from_arrays([0, 0], extent[:, 0], extent[:, 1], [0, 0], [0, 0]), "the training data"
            )
        else:
            frames = as_frames(frames if given is None else given.directory)
        _check_magnitudes(frames, "the training data")
        self._resolve_inputs(frames, manifest if sharded else None)
        self._resolve_defaults(frames)
        signal_var = frames.v.var(axis=0) if self.signal_var is None else _pair("signal_var", self.signal_var)
        mean = frames.v.mean(axis=0) if self.mean is None else _pair("mean", self.mean)
        if np.any(np.asarray(signal_var) <= 0):
            raise InvalidInputError(
                f"the training velocities have zero variance in an output ({tuple(signal_var)}); pass signal_var="
            )
        if np.max(np.abs(mean)) > _MAX_MAGNITUDE or np.max(signal_var) > _MAX_MAGNITUDE**2:
            raise InvalidInputError(
                f"mean {tuple(map(float, mean))} or signal_var {tuple(map(float, signal_var))} is too large to compute with; "
                "convert the velocities to sensible units first"
            )
        _check_noise(self.noise_var_, signal_var)
        a, b = self.length_scale_prior_
        ls0 = (a * b, a * b) if self.length_scales is None else _pair("length_scales", self.length_scales)
        self.params_ = GPParams(ls0, tuple(signal_var), self.noise_var_, tuple(mean))
        check_scales(frames.v, self.params_, "the training data")
        if sharded:
            assert source is not None and extent is not None
            self._resolve_sharded_engine(frames, extent)
            self._sampler = self._new_sharded_sampler(source, owned=given is None)
        else:
            self._resolve_engine(frames)
            self._sampler = self._new_sampler(frames)
            self.frames_ = frames
        self.history_: dict[str, list] = {k: [] for k in ckpt.HISTORY_KEYS}
        if self.dynamics is not None:
            self.history_["stickiness"] = []
        self.draws_ = self._new_draws()
        self.__dict__.pop("label_trace_", None)
        self.converged_ = False
        self.n_iter_ = 0
        t = time.perf_counter()
        try:
            self._sampler.initialize(self.init)
            if self._auto_pending:
                self._settle_auto(frames)
        except KeyboardInterrupt:
            # Some frames have no pattern yet: there is no state to keep.
            self.__dict__.pop("labels_", None)
            raise
        except MemoryBudgetError:
            self.__dict__.pop("labels_", None)
            raise
        self.init_seconds_ = time.perf_counter() - t
        self.checkpoint_seconds_: dict[str, list[float]] = {"reset": [], "write": []}
        if self.checkpoint is not None:
            self._data_sha256 = (
                ckpt.fingerprint(frames) if data_sha256 is None else data_sha256
            )  # over shards: from the sample pass
        self._sweeps(stable=0, traces=[], checkpoint_now=True)
        return self

    # --- frames held in shards ----------------------------------------------------------------------
    @property
    def frames_(self) -> Frames:
        """The training frames. After a fit over shards they are read from the directory on first
        use (the fit itself never holds them all)."""
        f = self.__dict__.get("_frames")
        if f is None and self.__dict__.get("_frames_dir") is not None:
            f = self.__dict__["_frames"] = as_frames(self._frames_dir)
        if f is None:
            raise AttributeError("frames_")
        return f

    @frames_.setter
    def frames_(self, frames: Frames) -> None:
        self.__dict__["_frames"], self.__dict__["_frames_dir"] = frames, None
        self.__dict__["_n_train"] = len(frames)

    def _n_training(self) -> int:
        """The number of training frames (without reading shards)."""
        n = self.__dict__.get("_n_train")
        return int(n) if n is not None else len(self.frames_)

    def _fingerprint(self) -> str:
        """The training data's fingerprint as a checkpoint records it (frames in shards: each
        shard read and hashed alone, :func:`dpgp.model.sharded.shards_fingerprint`)."""
        directory = self.__dict__.get("_frames_dir")
        if directory is None:
            return ckpt.fingerprint(self.frames_)
        from ..data._shardfile import read_manifest
        from .sharded import shards_fingerprint

        return shards_fingerprint(read_manifest(directory))

    def _over_shards_of(self, file: Any, client: Any, source: Any = None) -> None:
        """The sampler over the shards a file of frames left in shards names (``_from_file``),
        after checking that they hold the frames it was written for."""
        from ..data._shardfile import read_manifest
        from .sharded import ShardSource, shards_fingerprint

        directory, sizes, sha = file.shards["directory"], file.shards["sizes"], file.shards["data_sha256"]
        if source is None:  # else fit_chains' own chains, whose file names the source's shards
            try:
                manifest = read_manifest(directory)
            except (OSError, DpgpError) as e:
                raise ModelFileError(
                    f"{file.path} needs the shards in {directory}, which cannot be read: {e}"
                ) from None
            if [s.n_frames for s in manifest.shards] != sizes or shards_fingerprint(manifest, client) != sha:
                raise ModelFileError(
                    f"the shards in {directory} are not the frames {file.path} was written for (their frames per shard "
                    "or fingerprint differ); the chain cannot continue on them"
                )
        self._sampler = self._new_sharded_sampler(source or ShardSource(manifest, client), owned=source is None)
        self._data_sha256 = sha

    def _runs_on_shards(self, client: Any) -> bool:
        """Whether a directory of shards is fitted as shards (else read into memory); with a
        ``client`` settings that cannot are refused."""
        ok = (
            self.likelihood in ("auto", "hsgp")
            and self.sampler in ("auto", "subcluster")
            and self.dynamics is None
            and not self.pattern_moments
        )
        if client is not None and not ok:
            raise InvalidInputError(
                "a fit with client= runs the sub-cluster sampler on the reduced-rank engine over the shards; "
                "likelihood must be 'auto' or 'hsgp', sampler 'auto' or 'subcluster', with no dynamics or "
                "pattern_moments"
            )
        return ok

    def _continue(self, frames: Frames | Any) -> DPGP:
        """``fit(frames, warm_start=True)`` of a fitted model: ``iterations`` more sweeps of its chain."""
        self._check_settings()
        from .sharded import ShardSource

        directory = self.__dict__.get("_frames_dir")
        if isinstance(frames, ShardSource):
            frames = frames.directory
        if directory is not None and isinstance(frames, (str, os.PathLike)):
            same = os.path.abspath(frames) == os.path.abspath(directory)
        else:
            frames = as_frames(frames)
            same = frames is self.frames_ or _same_frames(frames, self.frames_)
        if not same:
            raise InvalidInputError(
                "warm_start continues the chain on the frames the model was fitted to; these frames differ "
                "(fit without warm_start to start a chain on new data)"
            )
        if self.checkpoint is not None:
            ckpt.check_path(self.checkpoint)
            self._data_sha256 = getattr(self, "_data_sha256", None) or self._fingerprint()
        history = self.__dict__.setdefault("history_", {})
        for key in ckpt.HISTORY_KEYS:
            history.setdefault(key, [])
        self.n_iter_ = int(self.n_iter_ or 0)
        self.converged_ = False
        self.__dict__.setdefault("checkpoint_seconds_", {"reset": [], "write": []})
        traces = list(self.__dict__.get("label_trace_", [])) if self.store_labels else []
        self._sweeps(stable=0, traces=traces, until=self.n_iter_ + int(self.iterations))
        return self

    def _sweeps(
        self, stable: int, traces: list[np.ndarray], checkpoint_now: bool = False, until: int | None = None
    ) -> None:
        """Sweep until ``until`` sweeps are done (default ``iterations``; a resumed chain's
        included) or the stopping rule holds (``stable`` sweeps so far), checkpointing on the way;
        end in the canonical state."""
        from .sharded import LabelsLost

        interrupted, bar = False, None
        total = self.iterations if until is None else until
        # Labels held by the shards: each sweep's ARI from the counts the shards return (no label
        # crosses), the labels gathered at each rebuild alone, and a lost shard's labels set again
        # from that copy, the sweeps since redone (the same chain).
        held = self._sampler.labels_held()
        redos = 0
        try:
            previous = self._save_checkpoint(stable, traces) if checkpoint_now else self._mark_labels()
            self._keep_rebuild_copy(stable, len(traces))
            bar = _progress(total, self.progress, initial=self.n_iter_)
            while self.n_iter_ < total and not self.converged_:
                try:
                    source = self.__dict__.get("_shard_source")
                    if source is not None and source.stopping.is_set():  # fit_chains stops its chains' threads
                        raise KeyboardInterrupt
                    t = time.perf_counter()
                    counts = self._sampler.split_merge_counts()
                    moves, k, alpha, log_joint = self._sampler.sweep()
                    table = self._sampler.label_table() if held else None
                    seconds = time.perf_counter() - t
                    if table is not None:
                        labels = compact_labels(self._sampler.labels()) if self.store_labels else None
                        ari = adjusted_rand_index_of_table(table)
                    else:
                        labels = compact_labels(self._sampler.labels())  # 1 byte a frame: N can be 10M
                        ari = adjusted_rand_index(previous, labels)
                    extra: tuple[float, ...] = tuple(b - a for a, b in zip(counts, self._sampler.split_merge_counts()))
                    extra += _noise_summary(self._sampler, self._per_pattern_noise())
                    for key, val in zip(ckpt.HISTORY_KEYS, (k, alpha, log_joint, moves, ari, seconds, *extra)):
                        self.history_[key].append(val)
                    rho = self._sampler.stickiness()
                    if rho is not None:
                        self.history_.setdefault("stickiness", []).append(rho)
                    if self.store_labels:
                        traces.append(canonical_labels(labels))
                    self.n_iter_ += 1
                    self._keep_draw()
                    if bar is not None:
                        bar.update(1)
                        bar.set_postfix(K=k, alpha=f"{alpha:.3g}", moved=moves)
                    same_k = len(self.history_["n_patterns"]) > 1 and self.history_["n_patterns"][-2] == k
                    stable = stable + 1 if (same_k and ari >= self.ari_tol) else 0
                    previous = labels
                    self.converged_ = self.n_iter_no_change is not None and stable >= self.n_iter_no_change
                    if self.n_iter_ % self.checkpoint_every == 0:  # with or without a file: one result
                        previous = self._save_checkpoint(stable, traces)
                        self._keep_rebuild_copy(stable, len(traces))
                except LabelsLost:
                    # Anywhere in the sweep, its ARI, draw or rebuild: back to the last rebuild.
                    redos += 1
                    if not held or redos > _MAX_REDOS:
                        raise
                    stable, previous = self._redo_from_rebuild(traces, bar)
        except KeyboardInterrupt:
            if not getattr(self, "_keep_state_on_interrupt", True):
                raise
            # Mid-sweep: the checkpoint keeps the last complete state, this model the state reached.
            interrupted = True
            warnings.warn(
                f"fit interrupted after {self.n_iter_} sweeps; the model keeps the state reached", stacklevel=3
            )
        except MemoryBudgetError:
            # Nothing was allocated: keep the state reached, as Ctrl-C does, then say why.
            if bar is not None:
                bar.close()
            self._sync()
            raise
        finally:
            if bar is not None:
                bar.close()
        if self.store_labels:
            self.label_trace_ = _trace_array(traces, self._n_training())
        # Refactor every pattern in canonical order (patterns by size, frames by index), which is
        # also what loading a saved model does: both then compute with identical factors.
        self._rebuild()
        if self.checkpoint is not None and not interrupted and self._resume_point.sweeps_done != self.n_iter_:
            self._write_checkpoint(traces)  # the finished model, with the last resume point

    def _rebuild(self) -> None:
        """The canonical rebuild: every pattern refactored in canonical order (patterns by size,
        frames by index), then the public state read. Labels held by shards are relabelled there
        (``regroup``: none crosses), then gathered once into ``labels_``."""
        if self._sampler.labels_held():
            self._sync(labels=False)
            wh = [float(x) for x in self.heading_scales_] if self._headed() else None
            noise = None
            if self._per_pattern_noise():
                noise = np.asarray(self.pattern_noise_var_, dtype=np.float64).reshape(-1, 2)
            self._sampler.regroup(self._slot_to_label, self.length_scales_, self.alpha_, noise, heading_scales=wh)
        else:
            self._sync()
            self._set_state(self.labels_, self.length_scales_, self.alpha_, self.pattern_noise_var_)
        self._sync()

    def _mark_labels(self) -> np.ndarray | None:
        """The labels the next sweep's ARI compares with: this process's copy, or (labels held by
        the shards) ``None``, the shards marking theirs."""
        if self._sampler.labels_held():
            self._sampler.label_table()
            return None
        return compact_labels(self._sampler.labels())

    def _keep_rebuild_copy(self, stable: int, n_traces: int) -> None:
        """Remember the state of the last rebuild (``labels_`` and the rest, just read), from
        which a chain whose shards lost their labels redoes its sweeps."""
        nx, ny = self.params_.noise_var
        self._rebuilt = (self.n_iter_, stable, n_traces, (float(nx), float(ny)), self.converged_)

    def _redo_from_rebuild(self, traces: list[np.ndarray], bar: Any) -> tuple[int, np.ndarray | None]:
        """A shard lost the chain's labels (its worker was replaced): set the state of the last
        rebuild again (every shard gets its labels under a fresh chain number) and go back to its
        sweep; the sweeps since are redone, with the same result (the chain after a rebuild is a
        function of its state). Returns the stable count and the ARI's reference then."""
        n_iter, stable, n_traces, noise, converged = self._rebuilt
        redone = self.n_iter_ - n_iter
        warnings.warn(
            f"a shard's worker was replaced: the chain's labels are set again from sweep {n_iter} "
            f"and {redone} sweep(s) redone",
            stacklevel=4,
        )
        for values in self.history_.values():
            if redone:
                del values[len(values) - redone :]
        del traces[n_traces:]
        self.draws_ = self.draws_.up_to(n_iter)
        self.n_iter_, self.converged_ = n_iter, converged
        self._sampler.set_noise_var(noise)
        self._set_state(self.labels_, self.length_scales_, self.alpha_, self.pattern_noise_var_)
        self._sampler.set_sweeps_done(n_iter)
        if bar is not None:
            bar.n = n_iter
            bar.refresh()
        return stable, self._mark_labels()

    def _keep_draw(self) -> None:
        """Keep the state after this sweep if the thinning asks for it (:mod:`dpgp.posterior`)."""
        from ..gp.draws import state_of

        draws = self.__dict__.get("draws_")
        if draws is None:
            draws = self.draws_ = self._new_draws()
        per = self._per_pattern_noise()
        headed = self._headed()
        draws.record(self.n_iter_, lambda: state_of(self._sampler, per, headed), int(self.posterior_draws))

    def _new_draws(self) -> Draws:
        """No draws yet; their labels spilled to disk when the shards hold the chain's labels
        (:mod:`dpgp.gp.draws`)."""
        return Draws(self._n_training(), spill=bool(self._sampler.labels_held()))

    def _per_pattern_noise(self) -> bool:
        """Whether each pattern samples its own noise pair (``noise_var="per_pattern"``)."""
        return getattr(getattr(self, "defaults_", None), "noise_var_source", None) == "per_pattern"

    def _set_state(self, labels: Any, length_scales: Any, alpha: float, noise: Any = None) -> None:
        """``set_state`` of the sampler; per-pattern noise: with each pattern's pair ``noise``."""
        wh = [float(x) for x in self.heading_scales_] if self._headed() else None
        if self._per_pattern_noise() and noise is not None:
            noise = np.asarray(noise, dtype=np.float64).reshape(-1, 2)
            self._sampler.set_state(labels, length_scales, alpha, noise, heading_scales=wh)
        else:
            self._sampler.set_state(labels, length_scales, alpha, heading_scales=wh)

    def _save_checkpoint(self, stable: int, traces: list[np.ndarray]) -> np.ndarray | None:
        """Rebuild the sampler from its own state in canonical order, as a resumed chain does
        (:mod:`dpgp.checkpoint` says why), and with ``checkpoint`` set write that state there.
        Every fit rebuilds at this cadence whether or not it writes a file, so that writing
        checkpoints never changes the result. Returns the sampler's labels after the rebuild."""
        t = time.perf_counter()
        self._rebuild()
        reset = time.perf_counter()
        self.checkpoint_seconds_["reset"].append(reset - t)
        if self.checkpoint is None:
            return self._mark_labels()
        self._resume_point = ckpt.ResumePoint(
            self.n_iter_,
            self.labels_,
            self.length_scales_,
            self.alpha_,
            stable,
            self._data_sha256,
            self.pattern_noise_var_.copy() if self._per_pattern_noise() else None,
            self.heading_scales_.copy() if self._headed() else None,
        )
        self._write_checkpoint(traces)
        self.checkpoint_seconds_["write"].append(time.perf_counter() - reset)
        return self._mark_labels()

    def _write_checkpoint(self, traces: list[np.ndarray]) -> None:
        from ..io.modelfile import save

        if self.store_labels:
            self.label_trace_ = _trace_array(traces, self._n_training())
        # Uncompressed: zlib would be most of a checkpoint's cost (the file is read once, if at all).
        assert self.checkpoint is not None
        # A fit over shards checkpoints its state and a reference to the shards (format version
        # 3); gathering every frame into this process at each checkpoint is what it avoids.
        by_reference = self.__dict__.get("_frames_dir") is not None
        save(self._file_state(by_reference), self.checkpoint, resume=self._resume_point, compress=False)

    def _resolve_engine(self, frames: Frames) -> None:
        """Choose the likelihood (``likelihood_``), its basis (``basis_``) and the memory budget
        (``memory_budget_``) for ``frames``."""
        budget = parse_bytes("memory_budget", self.memory_budget)
        check_thread_reservations(self.n_threads)
        self.memory_budget_ = budget if budget is not None else default_memory_budget(self.n_threads)
        likelihood = self.likelihood
        self.engine_choice_, self._auto_pending = None, False
        basis = None
        if likelihood == "auto" and self.sampler == "subcluster":
            likelihood = "hsgp"  # the sub-cluster sampler needs it
        if likelihood == "auto":  # by predicted cost (dpgp.engine_cost)
            from .engine_cost import choose_upfront

            basis = self._basis(frames)
            choice = choose_upfront(
                frames.sizes,
                basis.size,
                self.memory_budget_,
                self._subcluster_possible(),
                self._auto_harmonics(),
                _heading_size(basis.counts),
            )
            if choice is None:  # fit predicts the pattern sizes by hsgp's initialisation
                likelihood, self._auto_pending = "hsgp", True
            else:
                likelihood, self.engine_choice_ = choice.engine, choice.to_dict()
        self.likelihood_ = likelihood
        self.basis_ = None
        if likelihood == "hsgp":
            self.basis_ = basis or self._basis(frames)
        self._resolve_sampler()

    def _resolve_sharded_engine(self, sample: Frames, extent: np.ndarray) -> None:
        """``likelihood_``, ``basis_`` (over the sample and the positions' whole extent),
        ``memory_budget_`` and ``sampler_`` of a fit over shards."""
        budget = parse_bytes("memory_budget", self.memory_budget)
        check_thread_reservations(self.n_threads)
        self.memory_budget_ = budget if budget is not None else default_memory_budget(self.n_threads)
        self._auto_pending = False
        self.likelihood_ = "hsgp"
        self.engine_choice_ = {
            "engine": "hsgp",
            "why": "frames in shards: the chain runs over them with the sub-cluster sampler on the reduced-rank engine",
        }
        self.basis_ = basis_for(
            np.vstack([sample.xy, extent]),
            self.length_scale_prior_,
            None if self.length_scales is None else _pair("length_scales", self.length_scales),
            None if self.n_basis is None else _basis_counts(self.n_basis),
        )
        self._resolve_sampler()

    def _new_sharded_sampler(self, source: Any, owned: bool) -> _core.Sampler:
        """A sub-cluster chain over the shards of ``source`` (:class:`dpgp.model.sharded.ShardSource`:
        read into this process, or served by a client's workers); this model's training frames
        are then those shards. ``owned``: the model made the source and lets its workers drop the
        shards when it fits again (fit_chains' chains share one it keeps)."""
        manifest = source.manifest
        settings = self._core_settings(manifest.n_frames, None)
        previous = self.__dict__.get("_shard_source")
        if previous is not None and previous is not source and self.__dict__.get("_owns_source"):
            previous.close()  # a fit again: the last fit's shards are no longer needed
        sampler = source.sampler(settings)
        self._shard_source, self._owns_source, self._shard_link = source, owned, source.link
        self._frames, self._frames_dir, self._n_train = None, manifest.directory, manifest.n_frames
        self._shard_sizes = source.sizes
        return sampler

    def _subcluster_possible(self) -> bool:
        """Whether settings other than the likelihood let the sub-cluster sampler run."""
        return self.sampler != "collapsed" and self.dynamics is None and not self.pattern_moments

    def _auto_harmonics(self) -> int:
        """The heading harmonics ``J`` hsgp would run with, for ``likelihood="auto"``'s cost model
        (0 for fields over position): the basis is the position basis times ``2J + 1``."""
        return self._heading_harmonics() if self._headed() else 0

    def _resolve_sampler(self) -> None:
        """``sampler_`` for ``likelihood_``, and why in ``engine_choice_["sampler"]``."""
        if self.sampler != "auto":
            sampler, why = self.sampler, "given"
        elif self.likelihood_ != "hsgp":
            sampler, why = "collapsed", "the exact likelihood has no finite weights to draw"
        elif self.dynamics is not None:
            sampler, why = "collapsed", "the sticky prior runs on the collapsed sampler"
        elif self.pattern_moments:
            sampler, why = "collapsed", "pattern_moments runs on the collapsed sampler"
        else:
            sampler, why = "subcluster", SUBCLUSTER_REASON
        self.sampler_ = sampler
        choice = dict(self.engine_choice_ or {})
        choice["sampler"] = {"sampler": sampler, "why": why}
        inputs = self.__dict__.get("_inputs_choice")
        if inputs is not None:  # what inputs ran and why (inputs="auto": choose_inputs)
            choice["inputs"] = dict(inputs)
        self.engine_choice_ = choice

    def _basis(self, frames: Frames) -> Any:
        return basis_for(
            frames.xy,
            self.length_scale_prior_,
            None if self.length_scales is None else _pair("length_scales", self.length_scales),
            None if self.n_basis is None else _basis_counts(self.n_basis),
        )

    def _settle_auto(self, frames: Frames) -> None:
        """Step 2 of ``likelihood="auto"`` (:mod:`dpgp.engine_cost`), once hsgp has initialised:
        predict both engines' sweeps from its pattern sizes; if exact is faster, start the exact
        sampler afresh (its own initialisation: the chain is then ``likelihood="exact"``'s)."""
        from .engine_cost import (
            PROBE_HEADING_SCALES,
            PROBE_SEEDS,
            PROBE_TOLERANCE,
            check_accuracy,
            choose,
            exact_peak_bytes,
            partition_gap,
            pattern_points,
        )

        self._auto_pending = False
        labels = np.asarray(self._sampler.labels(), dtype=np.int64)
        points = pattern_points(labels, frames.sizes)
        assert self.basis_ is not None  # hsgp ran the initialisation
        harmonics = self._auto_harmonics()
        choice = choose(
            points[points > 0],
            frames.sizes,
            self.basis_.size,
            self.memory_budget_,
            self.sampler_ == "subcluster",
            harmonics,
            _heading_size(self.basis_.counts),
        )
        # Fields over heading: the probe runs with the frames' headings, over heading length scales
        # about the w_h prior's (dpgp.model.engine_cost says why), on the basis with its harmonics.
        probe_basis = self.basis_
        heading_scales: tuple[float, ...] = ()
        if harmonics:
            heading = self._heading_engine()
            assert heading is not None
            mean = float(heading["prior"][0] * heading["prior"][1])
            probe_basis = dataclasses.replace(
                self.basis_, harmonics=harmonics, heading_counts=heading.get("heading_counts")
            )
            heading_scales = tuple(share * mean for share in PROBE_HEADING_SCALES)
        if choice.engine == "hsgp":  # faster, or exact over budget: is hsgp accurate on these data?
            # Where exact fits: on the initialisations of fixed seeds, not this fit's, a decision
            # about the data. Over budget the probe only informs a warning: this fit's own
            # partition alone (more initialisations of data that large cost more than the fit).
            seeds = PROBE_SEEDS if choice.exact_fits else (self.seed,)
            cache: dict[bytes, float] = {}  # a pattern several initialisations share is probed once
            gaps = [
                partition_gap(
                    labels if s == self.seed else self._probe_labels(frames, s),
                    frames,
                    self.params_,
                    probe_basis,
                    cache=cache,
                    heading_scales=heading_scales,
                )
                for s in seeds
            ]
            choice = check_accuracy(choice, float(np.median(gaps)), gaps)
            gap, budget = choice.resolution_gap or 0.0, self.memory_budget_ or 0
            if choice.engine == "hsgp" and not choice.exact_fits and gap > PROBE_TOLERANCE:
                warnings.warn(
                    f"the hsgp basis ({choice.basis} functions) cannot hold these data's length scales "
                    f"(accuracy probe {gap:.2f} nats/point > {PROBE_TOLERANCE}), and exact's worst "
                    f"case ({exact_peak_bytes(int(points.sum())) / 1e9:.1f} GB) is over the memory budget "
                    f"({budget / 1e9:.1f} GB): held-out densities may be well below exact's. Pass "
                    "likelihood='exact' with a larger memory_budget, or fit fewer frames",
                    stacklevel=3,
                )
        # The sampler's and inputs' entries stay (hsgp kept) or are rewritten for exact below.
        kept = {k: v for k, v in (self.engine_choice_ or {}).items() if k in ("sampler", "inputs")}
        self.engine_choice_ = {**choice.to_dict(), "sampler": kept.get("sampler"), **kept}
        if choice.engine == "exact":
            self.likelihood_, self.basis_ = "exact", None
            self._resolve_sampler()
            del self._sampler  # free hsgp's before the exact one allocates
            self._sampler = self._new_sampler(frames)
            self._sampler.initialize()

    def _probe_labels(self, frames: Frames, seed: int) -> np.ndarray:
        """The labels of this fit's sequential initialisation (its engine, basis and settings) had
        it been started with ``seed``: the partitions auto's accuracy probe reads."""
        sampler = self._new_sampler(frames, seed=seed, collapsed=True)
        sampler.initialize()
        return np.asarray(sampler.labels(), dtype=np.int64)

    def _new_sampler(self, frames: Frames, seed: int | None = None, collapsed: bool = False) -> _core.Sampler:
        """A core sampler over ``frames`` with this model's settings and ``params_`` (and the
        given ``seed`` instead of ``self.seed``, for auto's probe; ``collapsed``: the collapsed
        sampler whatever ``sampler_``); shared by ``fit`` and by loading a model file, so that
        both compute identically."""
        settings = self._core_settings(len(frames), frames, seed=seed, collapsed=collapsed)
        return _core.Sampler(frames.xy, frames.v, frames.offsets, settings, self._headings(frames, "training"))

    def _headings(self, frames: Frames, what: str) -> np.ndarray | None:
        """The frames' previous headings for fields over heading (``None`` for fields over
        position); frames without them are an error that says how to get them."""
        if not self._headed():
            return None
        if frames.prev_heading is None:
            raise InvalidInputError(
                f"inputs='position+heading' needs each vehicle's previous heading in the {what} frames: frame the "
                "tracks with dpgp.make_frames (frames read without track ids carry none)"
            )
        return frames.prev_heading

    def _core_settings(
        self, n_frames: int, frames: Frames | None, seed: int | None = None, collapsed: bool = False
    ) -> Any:
        """The core sampler's settings for ``n_frames`` training frames (``frames``, when in this
        process: the sticky prior's transitions)."""
        a, b = self.length_scale_prior_
        settings = self._sampler_settings()
        if seed is not None:
            settings["seed"] = seed
        sampler = "collapsed" if collapsed else getattr(self, "sampler_", "collapsed")
        settings["sampler"] = sampler
        if sampler == "subcluster" and _is_auto(self.split_merge):
            from .engine_cost import subcluster_moves

            settings["split_merge"] = subcluster_moves(n_frames)
        heading = self._heading_engine()
        settings.update(
            {
                "assignment": self.assignment_,
                "likelihood": self.likelihood_,
                "basis": None if self.basis_ is None else self.basis_.as_tuple(),
                "params": self.params_.as_tuple(),
                "length_scale_prior": (a, b),
                "memory_budget": self.memory_budget_,
                "noise_prior": NOISE_PRIOR
                if getattr(self.defaults_, "noise_var_source", None) in ("sampled", "per_pattern")
                else None,
                "noise_scope": "per_pattern" if self._per_pattern_noise() else "global",
                "dynamics": _sticky_prior(frames) if self.dynamics == "sticky" and frames is not None else None,
                "heading_prior": heading["prior"] if heading else None,
                "heading_harmonics": heading["harmonics"] if heading else None,
                "heading_counts": heading.get("heading_counts") if heading else None,
            }
        )
        return settings

    def _heading_engine(self) -> dict[str, Any] | None:
        """Fields over heading: the Gamma prior of ``w_h``, the reduced-rank basis's heading
        harmonics and its heading blocks' position counts (None for the exact likelihood) the chain
        runs with: those a loaded model file recorded (a file without the counts ran with all of
        them: None), else :data:`HEADING_PRIOR` and the harmonics and stride rules. None over
        position."""
        if not self._headed():
            return None
        stored = self.__dict__.get("_heading_stored")
        if stored is not None:
            return {"heading_counts": None, **stored}
        hsgp = self.likelihood_ == "hsgp"
        basis = self.__dict__.get("basis_")
        return {
            "prior": HEADING_PRIOR,
            "harmonics": self._heading_harmonics() if hsgp else None,
            "heading_counts": _heading_counts(basis.counts) if hsgp and basis is not None else None,
        }

    @staticmethod
    def _heading_harmonics() -> int:
        """Harmonics for the heading prior's 5% quantile, at most :data:`MAX_HEADING_HARMONICS` (the
        cut makes the heading kernel smoother, still a valid kernel: resolution, not correctness)."""
        return min(_core.heading_harmonics(HEADING_PRIOR), MAX_HEADING_HARMONICS)

    def _sync(self, labels: bool = True) -> None:
        """Read the sampler's state into the public attributes, patterns by decreasing size
        (``labels``: with ``labels_``, which a chain whose shards hold its labels gathers)."""
        patterns = self._sampler.patterns()  # (slot, id, n_frames, wx, wy)
        order = sorted(range(len(patterns)), key=lambda j: (-patterns[j][2], patterns[j][0]))
        self._slots = np.array([patterns[j][0] for j in order], dtype=np.int64)
        self._slot_order = np.array(order, dtype=np.int64)  # core slot-order index of each pattern
        slot_to_label = np.full(int(self._slots.max(initial=-1)) + 1, -1, dtype=np.int64)
        slot_to_label[self._slots] = np.arange(len(self._slots))
        self._slot_to_label = slot_to_label
        if labels:
            # Indexed by the core's own unsigned labels (no int64 copy: at 10M frames each is 80 MB).
            self.labels_ = slot_to_label[np.asarray(self._sampler.labels())]
        self.n_patterns_ = len(self._slots)
        counts = np.array([patterns[j][2] for j in order], dtype=np.float64)
        self.weights_ = counts / counts.sum()
        self.length_scales_ = np.array([[patterns[j][3], patterns[j][4]] for j in order]).reshape(-1, 2)
        if self._headed():
            self.heading_scales_ = np.asarray(self._sampler.heading_scales(), dtype=np.float64)[order]
        self.pattern_ids_ = np.array([patterns[j][1] for j in order], dtype=np.uint64)
        self.alpha_ = float(self._sampler.alpha())
        per_slot = np.asarray(self._sampler.pattern_noise(), dtype=np.float64).reshape(-1, 2)
        self.pattern_noise_var_ = per_slot[order]  # each pattern's pair (the chain's pair unless per pattern)
        if self._per_pattern_noise():
            # params_ keeps the pair the chain started at (the sampler's base: a resumed or loaded
            # chain is rebuilt with it); noise_var_ summarises the patterns' own pairs.
            self.noise_var_ = _weighted_median_pair(self.pattern_noise_var_, counts)
        else:
            nx, ny = self._sampler.noise_var()
            noise = (float(nx), float(ny))
            if noise != tuple(self.params_.noise_var):  # sampled inside the chain
                self.params_ = dataclasses.replace(self.params_, noise_var=noise)
            self.noise_var_ = noise
        self.log_joint_ = float(self._sampler.log_joint())
        rho = self._sampler.stickiness()
        self.stickiness_ = None if rho is None else float(rho)
        self.timings_ = dict(self._sampler.timings())

    # --- using the fit ----------------------------------------------------------------------------
    def _check_fitted(self) -> None:
        if not hasattr(self, "labels_"):
            raise NotFittedError("this DPGP is not fitted yet; call fit(frames) first")

    def _fitted(self) -> FittedPatterns:
        """The fitted state the lower modules (simulation, scenarios) work on: they take this,
        never the estimator, so that dependencies run one way."""
        self._check_fitted()
        cache = self.__dict__.setdefault("_cache", {})
        return FittedPatterns(
            self._sampler,
            self._slots,
            self._slot_order,
            self.frames_,
            self.labels_,
            self.weights_,
            self.alpha_,
            cache,
            lambda frames: self._new_sampler(frames, collapsed=True),  # scores other frames only
            self._headed(),
        )

    @property
    def transitions_(self) -> Transitions:
        """Pattern transitions between consecutive training frames, scene entries and exits, and
        dwell times (:class:`dpgp.evaluate.transitions.Transitions`); needs frames with times
        (:class:`~dpgp.exceptions.UnorderedFramesError` otherwise)."""
        self._check_fitted()
        cache = self.__dict__.setdefault("_cache", {})
        held = cache.get("transitions")
        if held is None or held[0] is not self.labels_:
            held = (self.labels_, count_transitions(self.labels_, self.frames_, self.n_patterns_))
            cache["transitions"] = held
        return held[1]

    def phases(
        self,
        n_phases: int | str = 2,
        seed: int | None = 0,
        durations: bool = False,
        evidence: str = "labels",
        cycle: bool = False,
    ) -> Any:
        """Phases of the training frames: persistent regimes above the patterns, a hidden Markov
        model over the patterns of consecutive frames with ``n_phases`` states (or ``"auto"``, by
        BIC). Returns :class:`dpgp.evaluate.phases.Phases` (labels, each phase's patterns,
        transitions and dwell times); ``sample_scenarios(duration=..., phases=...)`` switches
        pattern by them. ``durations``: a semi-Markov model (each phase's duration a log-normal)
        instead of the HMM's geometric durations: cleaner phases of fixed-time signals, slower.
        ``evidence``: ``"labels"`` fits the phases to each frame's pattern label;
        ``"likelihood"`` to each frame's likelihood under every pattern (its own without it), so
        that a frame two patterns explain about equally well counts for both (a pass over the
        training frames first). ``cycle``: the phases follow one another in a fixed order (the
        stages of a fixed-time signal), so that a brief return to the phase before is not a
        phase of its own. Needs frames with times."""
        from ..evaluate.phases import fit_phases

        self._check_fitted()
        if evidence not in ("labels", "likelihood"):
            raise InvalidInputError(f"evidence must be 'labels' or 'likelihood', got {evidence!r}")
        key = ("phases", n_phases, seed, bool(durations), evidence, bool(cycle))
        cache = self.__dict__.setdefault("_cache", {})
        held = cache.get(key)
        if held is None or held[0] is not self.labels_:
            ev = None
            if evidence == "likelihood":  # one pass over the frames for every phase model of these labels
                held_ev = cache.get("training_log_likelihoods")
                if held_ev is None or held_ev[0] is not self.labels_:
                    held_ev = (self.labels_, self.training_log_likelihoods())
                    cache["training_log_likelihoods"] = held_ev
                ev = held_ev[1]
            ph = fit_phases(
                self.labels_,
                self.frames_,
                n_phases,
                n_patterns=self.n_patterns_,
                seed=seed,
                durations=durations,
                evidence=ev,
                cycle=bool(cycle),
            )
            held = (self.labels_, ph)
            cache[key] = held
        return held[1]

    def stop_lines(self, phases: Any = 2) -> Any:
        """The red signals' stop lines that long scenarios by ``phases`` (a
        :class:`dpgp.evaluate.phases.Phases`, or what :meth:`phases` takes) stop vehicles at:
        where the recorded queues' front vehicles stood, and in which phases vehicles reaching
        each line mostly stopped there. Returns
        :class:`dpgp.generate.stop_lines.StopLines` (``at``, ``heading``, ``red`` by phase, the
        evidence; ``summary()``); none for pedestrians. Needs frames made from tracks."""
        from ..generate.motion import motion_model
        from ..generate.stop_lines import learn_stop_lines

        ph = self._phases_of(phases)
        fit = self._fitted()
        return learn_stop_lines(fit, ph.labels, ph.n_phases, motion_model(fit))

    def signal_phases(self, phases: Any = 2) -> Any:
        """The signal phases of ``phases`` (as :meth:`stop_lines` takes them): the phases with the
        same red stop lines merged into one (:meth:`dpgp.generate.stop_lines.StopLines.signal_groups`),
        and their transitions and dwell times over the training frames, as
        :func:`dpgp.evaluate.transitions.count_transitions` returns them (``mean_dwell()``,
        ``dwell(k)``). Where no line is red, every phase is one signal phase."""
        from ..evaluate.transitions import count_transitions

        ph = self._phases_of(phases)
        groups = self.stop_lines(ph).signal_groups()
        return count_transitions(groups[ph.labels], self.frames_, int(groups.max()) + 1)

    def _phases_of(self, phases: Any) -> Any:
        """Phases given as fitted, or as :meth:`phases` takes them (a number, or ``"auto"``)."""
        if isinstance(phases, str):
            return self.phases(phases)
        return self.phases(int(phases)) if isinstance(phases, (int, np.integer)) else phases

    def training_log_likelihoods(self) -> np.ma.MaskedArray:
        """(N, K): ``log p(V_i | X_i, D_k)`` of each training frame's velocities under each pattern
        (``labels_`` order), its own pattern's without the frame (the sweep's leave-one-out
        score). No prior weights: what each frame says about each pattern.

        A numpy masked array: an entry is masked where there is no likelihood to give, a frame
        alone in its pattern (without the frame the pattern holds no data). Sums, maxima and
        ``np.exp`` skip masked entries; ``.filled()`` gives -inf there (a pattern that cannot
        have the frame), ``.mask`` says where."""
        self._check_fitted()
        rows = np.asarray(self._sampler.training_log_likelihoods(), dtype=np.float64)
        return _masked_where_impossible(rows.reshape(len(self.labels_), -1)[:, self._slot_order])

    def _log_joint_terms(self, frames: Frames) -> np.ndarray:
        """(N, K+1): log [prior weight × likelihood] of each pattern, then of a new pattern."""
        frames = as_frames(frames)
        _check_magnitudes(frames, "the frames to score")
        fitted = self._fitted()  # NotFittedError before anything reads the fitted parameters
        check_scales(frames.v, self.params_, "the frames to score")
        return fitted.log_joint_terms(frames)

    def _averaged(self, frames: Frames | Any) -> tuple[np.ndarray, np.ndarray]:
        """Posterior-averaged log density (positions left out) and pattern probabilities of
        ``frames`` over the kept draws after burn-in and the final state (:mod:`dpgp.posterior`)."""
        from ..gp.draws import averaged, used

        frames = as_frames(frames)
        terms = self._log_joint_terms(frames)
        draws: Any = getattr(self, "draws_", None)  # used() gives no index without draws
        own = (float(self.noise_var_[0]), float(self.noise_var_[1]))  # for draws from files without their noise
        states = [
            (
                draws.labels[i],
                draws.length_scales[i],
                draws.alpha[i],
                own if draws.noise_var[i] is None else draws.noise_var[i],
                draws.heading_scales[i],  # each draw's own w_h (fields over heading), else None
            )
            for i in used(draws, self.n_iter_)
        ]
        h = self._headings(frames, "scored")
        return averaged(terms, self.labels_, states, lambda: self._new_sampler(self.frames_, collapsed=True), frames, h)

    def predict_proba(self, frames: Frames | Any, average: bool = False) -> np.ndarray:
        """Posterior probability of each pattern for each frame: shape (N, K+1), the last column
        being "a new pattern". ``average=True``: averaged over the kept posterior draws, their
        patterns matched to this model's through the training frames they share
        (:mod:`dpgp.posterior`)."""
        if average:
            return self._averaged(frames)[1]
        t = self._log_joint_terms(frames)
        t -= t.max(axis=1, keepdims=True)
        p = np.exp(t)
        return p / p.sum(axis=1, keepdims=True)

    def predict(self, frames: Frames | Any) -> np.ndarray:
        """The most probable existing pattern (index into ``weights_``) of each frame."""
        return np.argmax(self._log_joint_terms(frames)[:, :-1], axis=1)

    def score_samples(self, frames: Frames | Any, positions: bool = True, average: bool = False) -> np.ndarray:
        """log p(frame | model) per frame, the paper's frame likelihood under the fitted mixture:
        ``log φ̃(l) + Σ_j log ψ̃(x_j, y_j) + log Σ_k π_k p(V | X, D_k)`` with π the DP's predictive
        weights (a new pattern included). φ̃ and ψ̃ are the paper's φ and ψ smoothed by
        pseudo-counts set from the training frames (:class:`~dpgp.EmpiricalDistributions`,
        :meth:`~dpgp.EmpiricalDistributions.for_scoring`), so every frame scores finitely: one
        with a count or a position bin never seen in training, and one with a vehicle outside
        the training ROI (a documented penalty that grows with the distance).
        ``positions=False`` leaves out the φ̃ and ψ̃ terms (the density of the velocities given
        the positions). ``average=True``: the posterior
        predictive, the mixture density averaged over the kept posterior draws after burn-in and
        the final state (:mod:`dpgp.posterior`); ``False``: the final state only."""
        frames = as_frames(frames)
        if average:
            out = self._averaged(frames)[0]
        else:
            t = self._log_joint_terms(frames)
            m = t.max(axis=1, keepdims=True)
            out = (m + np.log(np.exp(t - m).sum(axis=1, keepdims=True)))[:, 0]
        if positions:
            from ..generate.scenarios import distributions

            out = out + distributions(self._fitted()).for_scoring().log_frame_densities(frames)
        return out

    def velocity_field(self, k: int, xy: object, heading: object = None) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean and variance (each (n, 2)) of pattern ``k``'s velocity field at ``xy``.

        ``heading`` (a fit over heading): the previous heading of a vehicle there, radians, one
        for every point or one per point; ``None`` or ``NaN``: the field averaged over heading
        (what it says of a vehicle seen for the first time). A field over position ignores it."""
        self._check_fitted()
        from .._arrays import as_pairs

        if not (_is_int(k) and 0 <= k < self.n_patterns_):
            raise InvalidInputError(
                f"pattern {k!r} does not exist; the model has {self.n_patterns_} (0..{self.n_patterns_ - 1})"
            )
        q = as_pairs("xy", xy)
        h = None
        if heading is not None and self._headed():
            try:
                h = np.ascontiguousarray(np.broadcast_to(np.asarray(heading, dtype=np.float64), (len(q),)))
            except (TypeError, ValueError) as e:
                raise InvalidInputError(
                    f"heading must be one angle in radians or one per point ({len(q)}), got {heading!r}"
                ) from e
            if np.isinf(h).any():
                raise InvalidInputError("heading must be finite radians, or NaN for a heading not known")
        return self._sampler.posterior(int(self._slots[k]), q, h)

    def conditional_log_probs(self, i: int) -> np.ma.MaskedArray:
        """Normalised log conditional of training frame ``i`` given every other frame's pattern:
        (K+1,), patterns in ``labels_`` order (its own scored without it) and then "new".

        A numpy masked array: an entry is masked where the conditional probability is exactly
        zero, because the pattern's prior weight is: the frame's own pattern when the frame is
        alone in it (without it the pattern is empty, ``n_k = 0``), and under
        ``dynamics="sticky"`` a pattern that neither a link to a neighbour nor a fresh draw can
        reach. ``np.exp(lp)`` then sums to 1 over the entries left, and ``lp.max()``,
        ``lp.argmax()`` and ``lp.sum()`` skip the masked ones; ``.filled()`` gives -inf there
        (log 0, the exact answer), ``.mask`` says where."""
        self._check_fitted()
        if not (_is_int(i) and 0 <= i < len(self.labels_)):
            raise InvalidInputError(f"frame {i!r} is not a training frame index (0..{len(self.labels_) - 1})")
        lp = np.asarray(self._sampler.conditional_log_probs(int(i)))
        return _masked_where_impossible(np.r_[lp[:-1][self._slot_order], lp[-1]])

    # --- simulation, scenarios and model files (dpgp/simulation.py, scenarios.py, io.py) ----------
    def simulate(
        self,
        frame: Any,
        pattern: int | None = None,
        steps: int = 100,
        dt: float | None = None,
        method: str = "euler",
        stochastic: bool = False,
        seed: int | None = None,
        *,
        roi: tuple[float, float, float, float] | None = None,
        low_data_threshold: float | None = LOW_DATA_THRESHOLD,
        dynamics: str | None = None,
        max_curvature: float | str | None = None,
    ) -> Any:
        """Roll the vehicles of ``frame`` (a training frame's index, a :class:`Frame`, or an
        ``(l, 2)``/``(l, 4)`` array) forward through pattern ``pattern`` (default: a training
        frame's own, else the frame's MAP pattern) by ``method`` ``"euler"`` or ``"rk4"``; with
        ``stochastic``, velocities are drawn jointly from the posterior at every step (seeded
        by ``seed``). ``dt`` defaults to the frames' time step (else 0.5 s), ``roi`` to the
        training ROI; vehicles stop when they leave it. Steps where a vehicle's posterior
        variance exceeds ``low_data_threshold`` times the prior's are flagged in ``low_data``.
        ``dynamics`` (:data:`dpgp.simulation.DYNAMICS`): ``"interactive"`` (default) starts each
        vehicle from its own velocity and relaxes it toward the field by the learned residual
        model, vehicles keeping their gaps; ``"relaxed"`` without interaction; ``"field"`` the
        paper's rollout (the mean field itself; ``method="rk4"`` needs it, and ``None``, the
        default, means ``"interactive"``, or ``"field"`` with ``method="rk4"``).
        ``max_curvature`` (the pure field over heading): a vehicle turns by at most this many
        radians per unit of the path the field asks it to drive, and never drives backward
        (``"recorded"``: the 99th percentile of the training frames' curvature; ``None``: the pure
        field; docs/heading.md). Returns a :class:`dpgp.simulation.Simulation`."""
        from ..generate.simulation import simulate

        return simulate(
            self._fitted(), frame, pattern, steps, dt, method, stochastic, seed, roi, low_data_threshold, dynamics,
            max_curvature,
        )  # fmt: skip

    def sample_critical(self, n: int, event: Any, *, steps: int = 16, seed: int | None = None, **options: Any) -> Any:
        """``n`` scenarios of ``steps`` steps drawn toward ``event`` (e.g. ``"ttc<1.0"``,
        ``"collision"``; :class:`dpgp.generate.criticality.Event`): their starting frames from a tilt
        learned by the cross-entropy method, each with its likelihood ratio against the natural
        generator (``Scenarios.weights``), so that ``Scenarios.estimate(event)`` gives the event's
        natural rate without bias. ``options``: ``per_round``, ``rounds`` (the tilt's learning),
        ``size`` (vehicles' length and width), ``ego`` (as in :meth:`sample_scenarios`; the event
        is then measured against it). See :mod:`dpgp.generate.critical`."""
        from ..generate.critical import sample_critical

        return sample_critical(self._fitted(), n, event, steps=steps, seed=seed, **options)

    def sample_scenarios(
        self, n: int, steps: int = 100, pattern: int | None = None, seed: int | None = None, **options: Any
    ) -> Any:
        """Generate ``n`` scenarios: a pattern by weight (or ``pattern``), a vehicle count from the
        pattern's own frames, positions drawn jointly from its position histogram with its
        recorded spacing, velocities drawn jointly from its GP, then a rollout of ``steps`` steps
        by the learned residual model with interaction. ``options``: ``dt``, ``method``,
        ``stochastic``, ``roi``, ``low_data_threshold``, ``dynamics`` (``"field"``: the earlier
        generator — counts from φ, independent positions, the paper's rollout), ``max_curvature``
        (its turning limit over heading, as in :meth:`simulate`), ``ego`` (``(x, y)`` or ``(x, y,
        heading in degrees)``: each scenario's vehicle nearest that point at the start, heading
        that way, becomes its ego vehicle, named ``Ego`` on export; or
        :class:`~dpgp.generate.scenarios.Ego` ``(x, y, heading, placed=True)``: a vehicle placed
        there in every scenario). Returns :class:`dpgp.scenarios.Scenarios`
        (``to_pandas``, ``to_csv``, ``to_sumo``).

        ``duration`` (seconds; issue 20): long scenarios that switch pattern by the learned
        :attr:`transitions_` and dwell times, vehicles entering where each pattern's enter
        (:mod:`dpgp.generate.long`); ``dynamics=True`` there means the default interactive motion.
        ``phases``: switch pattern by phase (:meth:`phases`; a number of phases, ``"auto"``, or a
        :class:`dpgp.evaluate.phases.Phases`), else pattern by pattern; by phase, vehicles stop at
        the red signals' stop lines (:meth:`stop_lines`; ``stop_lines=False``: not) and drive at
        the recorded free speeds where the fields are slower (``free_speeds=False``: not;
        :mod:`dpgp.generate.free_speeds`). ``ego`` ``(x, y)`` or ``(x, y, heading)`` there: each
        scenario's ego is the first vehicle to come to that point, along that heading.
        Returns a list of :class:`dpgp.generate.long.LongScenario`."""
        if options.get("duration") is not None:
            from ..generate.long import sample_long_scenarios

            duration = options.pop("duration")
            if options.get("dynamics") in (True, None):
                options["dynamics"] = "interactive"
            ph = options.get("phases")
            if isinstance(ph, str) or (isinstance(ph, (int, np.integer)) and not isinstance(ph, bool)):
                options["phases"] = self.phases(ph if isinstance(ph, str) else int(ph))
            return sample_long_scenarios(self._fitted(), self.transitions_, n, duration, seed, **options)
        options.pop("duration", None)
        from ..generate.scenarios import sample_scenarios

        for name in ("phases", "phase_fields", "cycle_splits", "stop_lines", "free_speeds"):
            if options.pop(name, None) is not None:
                raise InvalidInputError(f"{name}= applies to long scenarios (duration=...)")
        return sample_scenarios(self._fitted(), n, steps, pattern, seed, **options)

    def summary(self, top: int = 10) -> str:
        """What the fitted model holds, as text: data, ROI and time step, patterns (the ``top``
        largest with their frames, weights and length scales), GP parameters, what the "auto"
        settings resolved to, the settings, and a chains model's convergence (``dpgp info``)."""
        from .summary import summary

        self._check_fitted()
        return summary(self, top)

    def save(self, path: Any) -> None:
        """Write the fitted model to ``path`` (a versioned ``.npz``, no pickle; see :mod:`dpgp.io`)."""
        from ..io.modelfile import save

        self._check_fitted()
        save(self._file_state(), path)

    def _file_state(self, by_reference: bool = False) -> ModelState:
        """What a model file stores of this fitted model, as plain values (:mod:`dpgp.io` takes
        nothing else from the estimator). ``by_reference`` (a fit over shards): the frames stay
        in their shards, and what is learned from them (φ, ψ, motion, transitions) is left out."""
        from ..generate.motion import motion_model
        from ..generate.scenarios import distributions
        from ..io.modelfile import ModelState

        common: dict[str, Any] = dict(
            settings=self.get_params(), params=self.params_, alpha=self.alpha_, n_patterns=self.n_patterns_,
            labels=self.labels_, length_scales=self.length_scales_,
            pattern_noise_var=self.pattern_noise_var_ if self._per_pattern_noise() else None,
            heading_scales=self.heading_scales_ if self._headed() else None,
            pattern_ids=self.pattern_ids_, resolved=self._resolved_dict(),
            engine=self.engine_info(), history=getattr(self, "history_", {}), n_iter=getattr(self, "n_iter_", None),
            converged=getattr(self, "converged_", None), init_seconds=getattr(self, "init_seconds_", None),
            timings=getattr(self, "timings_", {}), log_joint=getattr(self, "log_joint_", None),
            chain_summary=getattr(self, "chain_summary_", None), label_trace=getattr(self, "label_trace_", None),
            draws=getattr(self, "draws_", None),
        )  # fmt: skip
        if by_reference:
            shards = {"directory": os.path.abspath(self._frames_dir), "sizes": list(self._shard_sizes),
                      "data_sha256": self._data_sha256}  # fmt: skip
            return ModelState(**common, frames=None, distributions=None, motion=None, shards=shards)
        return ModelState(
            **common, frames=self.frames_, distributions=distributions(self).to_dict(),
            motion=motion_model(self._fitted()).to_dict(), transitions=self._transitions_dict(),
            sticky=self._sticky_dict(),
        )  # fmt: skip

    def _sticky_dict(self) -> dict[str, Any] | None:
        """ρ and the links of the sticky prior, as a model file stores them (None without it)."""
        links, rho = self._sampler.links(), self._sampler.stickiness()
        if links is None or rho is None:
            return None
        return {"rho": float(rho), "links": np.flatnonzero(links).tolist()}

    def _transitions_dict(self) -> dict[str, Any] | None:
        """The transitions a model file stores (None for frames without time order)."""
        try:
            return self.transitions_.to_dict()
        except UnorderedFramesError:
            return None

    def _resolved_dict(self) -> dict[str, Any]:
        """What the "auto" settings and the preset resolved to, as a model file stores it."""
        r = getattr(self, "defaults_", None)
        if r is not None:
            return r.to_dict()
        return {  # a model assembled without fit (for example from chains) still has the values
            "assignment": self.assignment_, "noise_var": [float(x) for x in self.noise_var_],
            "length_scale_prior": list(self.length_scale_prior_), "noise_var_source": "user",
            "length_scale_prior_source": "user",
        }  # fmt: skip

    def engine_info(self) -> dict[str, Any]:
        """The likelihood that ran (``"exact"`` or ``"hsgp"``), its basis, the memory budget and
        ``likelihood="auto"``'s decision, as plain values (what a model file stores)."""
        basis = getattr(self, "basis_", None)
        info: dict[str, Any] = {
            "likelihood": getattr(self, "likelihood_", "exact"),
            "basis": None if basis is None else basis.to_dict(),
            "memory_budget": getattr(self, "memory_budget_", None),
            "choice": getattr(self, "engine_choice_", None),  # likelihood="auto"'s decision (dpgp.model.engine_cost)
            "sampler": getattr(self, "sampler_", "collapsed"),
            "inputs": self.__dict__.get("inputs_", self.inputs),  # what ran (inputs="auto": resolved)
        }
        heading = self._heading_engine() if hasattr(self, "likelihood_") else None
        if heading is not None:  # fields over heading: the w_h prior and heading harmonics
            counts = heading.get("heading_counts")
            info["heading"] = {
                "prior": list(heading["prior"]),
                "harmonics": heading["harmonics"],
                "heading_counts": None if counts is None else list(counts),
            }
        return info

    @classmethod
    def load(cls, path: Any) -> DPGP:
        """Read a model written by :meth:`save`; :class:`~dpgp.ModelFileError` if the file is
        truncated, corrupted, not a model file or from a newer dpgp."""
        from ..io.modelfile import read_model_file

        return cls._checked_from_file(read_model_file(path))

    @classmethod
    def resume(
        cls, path: Any, iterations: int | None = None, progress: bool | None = None, *, client: Any = None
    ) -> DPGP:
        """Continue the chain of a checkpoint that ``fit`` wrote with ``checkpoint=path``, and keep
        checkpointing to ``path``. The result is bitwise the model of the same fit run without
        interruption (but the seconds of its sweeps and timings).

        ``iterations`` is the chain's total length in sweeps, as in ``DPGP(iterations=...)``:
        ``None`` finishes the original fit's; a larger number extends the chain (the result
        equals a fit with that ``iterations``). A fit that has finished or stopped early
        (``n_iter_no_change``) comes back as it is. ``progress``: show a progress bar (``None``: as
        the fit did). ``resumed_from_`` is the sweep the chain continued from.

        The checkpoint of a fit over a directory of shards names the directory: the chain
        continues over its shards, in this process or, with ``client``, on that Dask cluster's
        workers (the same chain either way, as for ``fit``).
        :class:`~dpgp.ModelFileError` if ``path`` is not a checkpoint, is damaged, or its data do not
        match the fingerprint it was written with."""
        from ..io.modelfile import read_model_file

        file = read_model_file(path)
        if file.resume is None:
            raise ModelFileError(
                f"{file.path} is a model file without a resume point, not a checkpoint; checkpoints are written by "
                "DPGP(checkpoint=PATH).fit or 'dpgp fit --checkpoint PATH'"
            )
        if client is not None and file.shards is None:
            raise InvalidInputError(f"{file.path} holds its frames; client= resumes a checkpoint of a fit over shards")
        target = _resume_target(file, iterations)
        finished = file.state["converged_"] or target == file.state["n_iter_"]
        ckpt.check_path(file.path)
        model = cls._checked_from_file(file if finished else ckpt.at_resume_point(file), client)
        model.checkpoint, model.iterations = file.path, target
        if progress is not None:
            model.progress = bool(progress)
        model.resumed_from_ = model.n_iter_
        if finished:
            return model
        model._sampler.set_sweeps_done(model.n_iter_)
        model._resume_point, model._data_sha256 = file.resume, file.resume.data_sha256
        model.checkpoint_seconds_ = {"reset": [], "write": []}
        model._sweeps(file.resume.stable, list(model.__dict__.get("label_trace_", [])))
        return model

    @classmethod
    def from_model_file(cls, file: Any, source: Any = None) -> DPGP:
        """The fitted estimator a :class:`dpgp.io.ModelFile` describes (what :meth:`load` returns
        for a file; :mod:`dpgp.chains` builds a chain's state this way, over the chains' shared
        ``source`` of shards when the frames are in shards). Every inconsistency is a
        :class:`~dpgp.ModelFileError`."""
        return cls._checked_from_file(file, source=source)

    @classmethod
    def _checked_from_file(cls, file: Any, client: Any = None, source: Any = None) -> DPGP:
        """:meth:`_from_file`, with every inconsistency it meets a :class:`~dpgp.ModelFileError`."""
        try:
            return cls._from_file(file, client, source)
        except ModelFileError:
            raise
        except (DpgpError, KeyError, TypeError, ValueError, IndexError) as e:
            raise ModelFileError(f"{file.path}: inconsistent model file ({type(e).__name__}: {e})") from None

    @classmethod
    def _from_file(cls, file: Any, client: Any = None, source: Any = None) -> DPGP:
        """The estimator a :class:`dpgp.io.ModelFile` describes: the sampler ``fit`` builds, then
        ``set_state`` factors every pattern in the canonical order ``fit`` ends with, so every
        later computation is bitwise the same as the saved model's. Frames left in shards: the
        chain over them (served by ``client``'s workers when given), once their fingerprint
        matches the file's."""
        model = cls(**file.settings)
        model._check_settings()
        model.params_ = file.params
        r = file.resolved
        model.assignment_, model.noise_var_, model.length_scale_prior_, model.defaults_ = (
            r.assignment, r.noise_var, r.length_scale_prior, r,
        )  # fmt: skip
        model.likelihood_, model.basis_ = file.likelihood, file.basis
        model.sampler_ = file.sampler
        model.inputs_ = file.inputs  # the input the fit ran with (its settings may say "auto")
        if model._headed():  # the file's w_h per pattern, and the prior and harmonics the fit ran with
            if file.heading_scales is None:
                raise ModelFileError("a model of fields over heading needs each pattern's heading length scale")
            model.heading_scales_ = np.asarray(file.heading_scales, dtype=np.float64)
            if file.heading is not None:
                model._heading_stored = dict(file.heading)
        budget = parse_bytes("memory_budget", model.memory_budget)  # this machine's budget
        model.memory_budget_ = budget if budget is not None else default_memory_budget(model.n_threads)
        if file.shards is None:
            model._sampler = model._new_sampler(file.frames)
            model.frames_ = file.frames
        else:
            model._over_shards_of(file, client, source)
        model._set_state(file.labels, file.length_scales, file.alpha, file.pattern_noise_var)
        if file.sticky is not None and model.dynamics == "sticky":
            links = np.zeros(len(file.frames), dtype=bool)
            links[np.asarray(file.sticky["links"], dtype=np.int64)] = True
            model._sampler.set_links(links, float(file.sticky["rho"]))
        model._sync()
        if not np.array_equal(model.labels_, file.labels):
            raise ModelFileError(
                "the patterns are not stored in decreasing order of size; the file was not written by dpgp"
            )
        for name, value in file.state.items():
            if name != "timings_" or value:
                setattr(model, name, value)
        if file.distributions is not None:
            model._cache = {"distributions": (file.frames, file.distributions)}
        if file.motion is not None:
            model.__dict__.setdefault("_cache", {})["motion"] = (file.frames, file.motion)
        if file.transitions is not None:
            model.__dict__.setdefault("_cache", {})["transitions"] = (model.labels_, file.transitions)
        return model

    def evaluate(
        self,
        test_frames: Frames | Any,
        tracks: Any = None,
        horizons: Any = (1, 2, 4),
        average: bool = True,
        *,
        agent: str | None = None,
        seed: int | None = 0,
    ) -> Any:
        """Held-out evaluation against baselines (:mod:`dpgp.evaluate`): log density of the test
        velocities per vehicle for this model, a single GP, a position-blind Gaussian and a
        constant-velocity Gaussian around each vehicle's previous velocity (when the frames carry
        ``prev_v``), with the model's margins over the last two (``.margins``), and, given the raw
        ``tracks``, rollout ADE/FDE at ``horizons`` (seconds) against constant
        velocity and the realism of generated scenarios (``.realism``, :mod:`dpgp.realism`;
        ``agent`` and ``seed`` its collision rule and scenarios). ``average`` (default True): the
        model's density is the posterior predictive over the kept draws
        (``score_samples(average=True)``). Returns :class:`dpgp.evaluate.Evaluation`
        (``.table``, ``.plot()``)."""
        from ..evaluate.scores import evaluate

        return evaluate(self, as_frames(test_frames), tracks, horizons, average, agent=agent, seed=seed)


def _resume_target(file: Any, iterations: Any) -> int:
    """The total sweeps a resumed chain runs to: ``iterations``, else the original fit's."""
    done, original = file.state["n_iter_"], file.settings.get("iterations")
    if not (_is_int(original) and original >= done):
        raise ModelFileError(
            f"{file.path}: the fit's iterations {original!r} are not a count of at least its {done} sweeps"
        )
    if iterations is None:
        return int(original)
    if not (_is_int(iterations) and iterations >= done):
        raise InvalidInputError(
            f"iterations is the chain's total length in sweeps: an integer of at least the {done} sweeps the "
            f"checkpoint holds (None finishes the original {original}), got {iterations!r}"
        )
    return int(iterations)


def _sticky_prior(frames: Frames) -> tuple[list[int], tuple[float, float], None]:
    """The core's sticky prior: each frame's predecessor (-1: a run's first frame) and ρ's prior."""
    from ..data.timeorder import time_order

    try:
        prev = time_order(frames).prev
    except UnorderedFramesError as e:
        raise UnorderedFramesError(f"dynamics='sticky' needs frames in time order: {e}") from None
    return np.asarray(prev, dtype=np.int64).tolist(), STICKINESS_PRIOR, None


def _masked_where_impossible(log_values: np.ndarray) -> np.ma.MaskedArray:
    """``log_values`` with its -inf entries (probability exactly 0) masked; ``.filled()`` gives
    them back as -inf."""
    return np.ma.masked_array(log_values, mask=np.isneginf(log_values), fill_value=-np.inf)


def _is_int(x: object) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def _check_magnitudes(frames: Frames, what: str) -> None:
    """Refuse values whose squares would overflow the GP's sums (a silent -inf or NaN)."""
    for name, a in (("velocities", frames.v), ("positions", frames.xy - frames.xy.mean(axis=0))):
        if len(a) and np.max(np.abs(a)) > _MAX_MAGNITUDE:
            raise InvalidInputError(
                f"{what} has {name} of magnitude {np.max(np.abs(a)):.3g}, beyond {_MAX_MAGNITUDE:g}; "
                "convert them to sensible units first"
            )


#: Least noise variance, as a share of the signal variance, that a fit accepts. A position seen
#: twice (a stopped vehicle, a repeated frame) makes the correlation matrix R singular, and only
#: the noise keeps σ² R + σ_n² I positive definite; factors start failing near 1e-14 (a frame
#: repeated 150 times), so this leaves four orders of magnitude of room.
MIN_NOISE_RATIO = 1e-10


def _split_merge_moves(value: Any) -> Any:
    """Split–merge moves per sweep: ``"auto"`` resolved, anything else as given (the core checks it)."""
    from ..gp.defaults import SPLIT_MERGE_MOVES

    return SPLIT_MERGE_MOVES if _is_auto(value) else value


def _is_auto(value: Any) -> bool:
    return isinstance(value, str) and value == "auto"


def _weighted_median_pair(noise: np.ndarray, counts: np.ndarray) -> tuple[float, float]:
    """Per component, the median of the patterns' noise variances weighted by their frames (the
    lower weighted median: the least value with at least half the frames at or below it)."""
    out = []
    for d in range(2):
        order = np.argsort(noise[:, d], kind="stable")
        cum = np.cumsum(counts[order])
        j = int(np.searchsorted(cum, 0.5 * cum[-1])) if len(cum) else 0
        out.append(float(noise[order[j], d]) if len(cum) else float("nan"))
    return out[0], out[1]


def _noise_summary(sampler: Any, per_pattern: bool) -> tuple[float, float]:
    """The noise pair a sweep records in ``history_``: the chain's, or per pattern the
    frame-weighted median of the patterns' pairs."""
    if not per_pattern:
        nx, ny = sampler.noise_var()
        return float(nx), float(ny)
    counts = np.array([p[2] for p in sampler.patterns()], dtype=np.float64)
    return _weighted_median_pair(np.asarray(sampler.pattern_noise(), dtype=np.float64).reshape(-1, 2), counts)


def _check_noise(noise_var: Any, signal_var: Any) -> None:
    """Refuse a noise variance too small to factor duplicated positions with (mid-fit, a
    NotPositiveDefiniteError)."""
    noise, signal = np.broadcast_arrays(np.asarray(noise_var, dtype=float), np.asarray(signal_var, dtype=float))
    if np.any(noise < MIN_NOISE_RATIO * signal):
        raise InvalidInputError(
            f"noise_var {_short(noise)} is below {MIN_NOISE_RATIO:g} times the signal variance {_short(signal)}: a "
            "position seen twice (a stopped vehicle, a repeated frame) would make the GP covariance singular in "
            f"double precision; pass noise_var of at least {_short(MIN_NOISE_RATIO * signal)}"
        )


def _short(values: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:.3g}" for x in values) + ")"


def _same(a: object, b: object) -> bool:
    try:
        return bool(np.all(a == b)) if not (a is None) ^ (b is None) else False
    except Exception:
        return False


def _progress(total: int, enabled: bool, initial: int = 0):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc="dpgp sweeps", unit="sweep")


def _same_frames(a: Frames, b: Frames) -> bool:
    """The same training frames (equal arrays), whether or not the same object."""
    return (
        len(a) == len(b)
        and a.n_points == b.n_points
        and all(np.array_equal(x, y) for x, y in ((a.offsets, b.offsets), (a.xy, b.xy), (a.v, b.v)))
    )


def _trace_array(traces: list[np.ndarray], n_frames: int) -> np.ndarray:
    return np.array(traces, dtype=np.int64).reshape(len(traces), n_frames)
