"""Critical scenarios by importance sampling (issue 35): scenes drawn from a tilted version of the
generator, each with its exact likelihood ratio against the natural one, so that the natural rate
of a rare event is still estimated without bias (:meth:`Scenarios.estimate`).

What is tilted, so far: which training frame a scene starts from. Naturally a scene draws a
pattern by its weight and one of the pattern's frames uniformly, so frame ``f`` of pattern ``k``
has probability ``p_f = w_k / n_k``. A tilt draws ``f`` from ``q`` instead; the scene's ratio is
``p_f / q_f``, exact, and everything after the start (thinning, the GP draw, the residual, the
interaction) stays natural. ``q`` is learned by the cross-entropy method (Rubinstein; Zhao et al.
2016 for automated vehicles): draw scenes, keep the most critical, move ``q`` toward the frames they
started from in proportion to their ratios, raise the level, repeat until the event itself is the
elite; ``q`` keeps a share of ``p`` so that every frame the event can start from stays possible,
which is what makes the estimate unbiased. The natural generator (no tilt) is unchanged.
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
    for _ in range(int(rounds)):
        scenes = sample_scenarios(model, per_round, steps=steps, seed=int(rng.integers(2**62)), tilt=q, ego=ego)
        c = criticality(scenes, size=size, ego=True if ev.ego else None)
        score = ev.score(c.per_scene())
        keep = max(1, math.ceil(ELITE * per_round))
        level = min(float(np.sort(score)[::-1][keep - 1]), ev.level)
        elite = score >= level
        if not np.isfinite(level):  # fewer finite scores than the elite: the finite ones
            elite = np.isfinite(score)
        levels.append(level)
        if not elite.any():
            break
        sources, weights = np.asarray(scenes.sources), np.asarray(scenes.weights)  # set by a tilt
        mass = np.bincount(sources[elite], weights=weights[elite], minlength=len(p))
        if mass.sum() > 0:
            q = (1 - NATURAL_SHARE) * mass / mass.sum() + NATURAL_SHARE * p
        if level >= ev.level:
            break
    return q, levels


def sample_critical(model: Any, n: int, event: Any, *, seed: int | None = None, steps: int = 16, **options: Any) -> Any:
    """``n`` scenes of ``steps`` steps tilted toward ``event`` by :func:`learn_tilt` (its
    ``options``: ``per_round``, ``rounds``, ``size``, ``ego``; the rounds' scenes are not returned), each with its
    likelihood ratio (:attr:`Scenarios.weights`) for :meth:`Scenarios.estimate`."""
    ego = options.get("ego")
    q, _ = learn_tilt(model, event, steps=steps, seed=0 if seed is None else seed, **options)
    return sample_scenarios(model, n, steps=steps, seed=seed, tilt=q, ego=ego)


__all__ = ["natural_frames", "tilted_frames", "learn_tilt", "sample_critical", "NATURAL_SHARE", "ELITE"]
