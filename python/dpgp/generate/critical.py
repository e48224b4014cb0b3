"""Critical scenarios by importance sampling (issue 35): scenes drawn from a tilted version of the
generator, each with its exact likelihood ratio against the natural one, so that the natural rate
of a rare event is still estimated without bias (:meth:`Scenarios.estimate`).

What is tilted, so far: which training frame a scene starts from. Naturally a scene draws a
pattern by its weight and one of the pattern's frames uniformly, so frame ``f`` of pattern ``k``
has probability ``p_f = w_k / n_k``. A tilt draws ``f`` from ``q`` instead; the scene's ratio is
``p_f / q_f``, exact, and everything after the start (thinning, the GP draw, the residual, the
interaction) stays natural.

Given its frame a scene is natural, so the estimator's variance depends on the tilt only through
``r_f``, the chance of the event from frame ``f``: ``Σ p_f² r_f / q_f − rate²``, least at ``q_f ∝
p_f √r_f``. :func:`learn_tilt` estimates ``r_f`` in multilevel cross-entropy rounds (Rubinstein;
Zhao et al. 2016 for automated vehicles): draw scenes, raise the level to the most critical tenth's
(until the event's own), and estimate each frame's chance of reaching it from every scene drawn
so far from that frame, shrunk toward the overall chance (a frame seen once with a hit is not
taken as certain; a frame never drawn keeps the overall chance). ``q`` keeps a share of ``p`` so
that every frame the event can start from stays possible, which is what makes the estimate
unbiased. The gain is bounded by the frames: where the event comes from anywhere (noise along the
way), no starting frame is much better than another and the tilt gives about crude Monte Carlo's
variance; the natural generator (no tilt) is unchanged.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..exceptions import InvalidInputError
from .criticality import Event, criticality
from .scenarios import natural_frames, sample_scenarios, tilted_frames

#: Share of the natural frame probabilities every tilt keeps (its support: unbiased estimates).
NATURAL_SHARE = 0.1
#: Share of a round's scenes kept as its elite (the most critical).
ELITE = 0.1
#: How many scenes' worth of the overall chance a frame's own estimate is shrunk toward.
PRIOR_SCENES = 2.0


def learn_tilt(
    model: Any,
    event: Any,
    *,
    per_round: int = 500,
    rounds: int = 6,
    steps: int = 16,
    seed: int = 0,
    size: Any = None,
    ego: Any = None,
) -> tuple[np.ndarray, list[float]]:
    """The cross-entropy tilt toward ``event`` (:class:`~dpgp.generate.criticality.Event` or its
    text): ``rounds`` of ``per_round`` scenes of ``steps`` steps. Returns the tilt (one probability per
    training frame) and each round's level (the elite's least score; the event's is
    ``Event.level``)."""
    ev = Event.parse(event, ego=ego is not None)
    for name, value in (("per_round", per_round), ("rounds", rounds)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise InvalidInputError(f"{name} must be a whole number >= 1, got {value!r}")
    p = natural_frames(model)
    q = p.copy()
    levels: list[float] = []
    rng = np.random.default_rng(seed)
    sources: list[np.ndarray] = []
    scores: list[np.ndarray] = []
    weights: list[np.ndarray] = []
    for _ in range(int(rounds)):
        scenes = sample_scenarios(model, per_round, steps=steps, seed=int(rng.integers(2**62)), tilt=q, ego=ego)
        c = criticality(scenes, size=size, ego=True if ev.ego else None)
        score = ev.score(c.per_scene())
        keep = max(1, math.ceil(ELITE * per_round))
        level = min(float(np.sort(score)[::-1][keep - 1]), ev.level)
        if not np.isfinite(level):  # fewer finite scores than the elite: every finite one
            finite = score[np.isfinite(score)]
            level = float(finite.min()) if len(finite) else -math.inf
        level = max(level, levels[-1]) if levels else level  # the levels only rise
        levels.append(level)
        sources.append(np.asarray(scenes.sources))
        scores.append(score)
        weights.append(np.asarray(scenes.weights))
        q = _tilt_at(level, p, np.concatenate(sources), np.concatenate(scores), np.concatenate(weights))
        if level >= ev.level:
            break
    return q, levels


def _tilt_at(level: float, p: np.ndarray, source: np.ndarray, score: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The tilt toward scores at or above ``level`` from the scenes drawn so far (``source`` frame,
    ``score``, likelihood-ratio ``weight`` each): ``q_f ∝ p_f √r_f`` with ``r_f`` each frame's share
    of scenes reaching the level, shrunk by :data:`PRIOR_SCENES` scenes toward the overall natural
    chance; mixed with :data:`NATURAL_SHARE` of ``p``."""
    hit = score >= level
    overall = float(np.sum(weight * hit) / np.sum(weight))  # the natural chance, importance-weighted
    if overall <= 0:
        return p.copy()
    n = np.bincount(source, minlength=len(p))
    hits = np.bincount(source, weights=hit.astype(np.float64), minlength=len(p))
    r = (hits + PRIOR_SCENES * overall) / (n + PRIOR_SCENES)
    best = p * r
    return (1 - NATURAL_SHARE) * best / best.sum() + NATURAL_SHARE * p


def sample_critical(model: Any, n: int, event: Any, *, seed: int | None = None, steps: int = 16, **options: Any) -> Any:
    """``n`` scenes of ``steps`` steps tilted toward ``event`` by :func:`learn_tilt` (its
    ``options``: ``per_round``, ``rounds``, ``size``, ``ego``; the rounds' scenes are not returned), each with its
    likelihood ratio (:attr:`Scenarios.weights`) for :meth:`Scenarios.estimate`."""
    ego = options.get("ego")
    q, _ = learn_tilt(model, event, steps=steps, seed=0 if seed is None else seed, **options)
    return sample_scenarios(model, n, steps=steps, seed=seed, tilt=q, ego=ego)


__all__ = ["natural_frames", "tilted_frames", "learn_tilt", "sample_critical", "NATURAL_SHARE", "ELITE", "PRIOR_SCENES"]
