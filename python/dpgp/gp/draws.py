"""Posterior draws a fit keeps, and scores averaged over them (the posterior predictive).

A fitted model's last state is one draw from the posterior over partitions and hyperparameters;
scoring only it ignores how uncertain the fit is. The fit therefore keeps a thinned set of its
states, a :class:`Draws`: per kept sweep, the labels (patterns by decreasing size), each
pattern's length scales (for fields over heading, ``DPGP(inputs="position+heading")``, its heading
length scale ``w_h`` too) and α. Those are all a state needs: the sampler refactors every pattern
from them (``Sampler.set_state``), as loading a model file does.

**Thinning under a memory bound.** At most ``max_draws`` states are held. After ``t`` sweeps the
kept sweeps are the multiples of ``thin(t)``, the least power of two with ``t // thin ≤ max_draws``;
as ``t`` grows past the bound, every other draw is dropped and the step doubles. What is kept is a
function of ``t`` alone, so a resumed chain keeps what the uninterrupted one would. Memory:
``max_draws · (b N + 16 K + 16)`` bytes for ``N`` frames and ``K`` patterns a draw (``24 K`` for
fields over heading), with each draw's labels in the smallest unsigned type that holds them
(``b = 1`` byte below 256 patterns; model files store them as int32).

**Spilled to disk.** A fit whose labels stay on the shards (``fit(directory)``) keeps its draws'
labels in files of a temporary directory, read back through memory maps (``Draws(spill=True)``):
at ten million frames the 40 draws' labels are 400 MB, more than the rest of what the chain's
leader holds. The directory goes with the draws.

**Averaging.** Scores use the kept draws after a burn-in of the first half of the sweeps, and
the final state (itself a draw); ``S`` states in all. For a test frame ``V`` and state ``s``,
``log p_s(V) = log Σ_j π_sj p(V | D_sj) `` (the DP's predictive weights, a new pattern included),
and the posterior predictive is the average of the densities::

    log p(V | D) = logsumexp_s log p_s(V) − log S.

``predict_proba`` reports probabilities over the *final* state's patterns (and "new"). Patterns of
other draws are matched to them softly through the training frames they share:
``P(k | V) = Σ_s Σ_j p(s, j | V) |D_sj ∩ D_k| / |D_sj|``, with ``p(s, j | V) ∝ π_sj p(V | D_sj)``
over all draws and patterns (each draw weighted by how well it explains ``V``, as the posterior
given ``V`` does), and the "new" column ``Σ_s p(s, new | V)``. With one draw this is the final
state's conditional exactly.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import uuid
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._arrays import compact_labels

#: Default bound on the states a fit keeps (``DPGP(posterior_draws=...)``).
MAX_DRAWS = 40


def thin_for(sweeps: int, max_draws: int) -> int:
    """The step between kept sweeps after ``sweeps`` sweeps: the least power of two ``p`` with
    ``sweeps // p <= max_draws`` (``max_draws = 0``: nothing is kept; returns 0)."""
    if max_draws <= 0:
        return 0
    p = 1
    while sweeps // p > max_draws:
        p *= 2
    return p


@dataclass
class Draws:
    """Kept states: ``sweeps`` (D,), ``labels`` (one (N,) array a draw, patterns by decreasing
    size, in the smallest unsigned type that holds them),
    ``length_scales`` (one (K_d, 2) array a draw), ``alpha`` (D,), ``noise_var`` (one
    ``(σ_n,x², σ_n,y²)`` a draw: the noise is sampled in the chain; ``None`` for draws read from a
    file written before it was, which are scored with the model's final noise) and
    ``heading_scales`` (one (K_d,) array of ``w_h`` a draw for fields over heading; ``None`` for
    fields over position)."""

    n_frames: int
    sweeps: list[int] = field(default_factory=list)
    labels: list[np.ndarray] = field(default_factory=list)
    length_scales: list[np.ndarray] = field(default_factory=list)
    alpha: list[float] = field(default_factory=list)
    noise_var: list[Any] = field(default_factory=list)  # a pair, a (K_d, 2) array per pattern, or None
    heading_scales: list[np.ndarray | None] = field(default_factory=list)  # (K_d,) w_h; None: over position
    spill: bool = False  # labels kept in files (module docstring), not in memory
    _files: _SpillDir | None = field(default=None, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.sweeps)

    @property
    def nbytes(self) -> int:
        per = sum(v.nbytes for v in self.noise_var if isinstance(v, np.ndarray))
        per += sum(w.nbytes for w in self.heading_scales if w is not None)
        return sum(a.nbytes for a in self.labels) + sum(a.nbytes for a in self.length_scales) + 16 * len(self) + per

    def record(self, sweep: int, state: Callable[[], State], max_draws: int) -> None:
        """After sweep ``sweep``: drop what the thinning no longer keeps, then keep this state
        (``state()``: labels, length scales, α, noise pair, heading length scales or None) if its
        sweep is a multiple of the step."""
        step = thin_for(sweep, max_draws)
        keep = [i for i, s in enumerate(self.sweeps) if step and s % step == 0]
        if len(keep) != len(self):
            if self._files is not None:  # the dropped draws' files go now, not with the directory
                self._files.remove([a for i, a in enumerate(self.labels) if i not in keep])
            self._select(keep)
        if step and sweep % step == 0 and (not self.sweeps or self.sweeps[-1] != sweep):
            labels, length_scales, alpha, noise, heading = state()
            self.sweeps.append(int(sweep))
            kept = compact_labels(labels)
            del labels
            if self.spill:
                if self._files is None:
                    self._files = _SpillDir()
                kept = self._files.keep(kept)
            self.labels.append(kept)
            self.length_scales.append(np.asarray(length_scales, dtype=np.float64).reshape(-1, 2).copy())
            self.alpha.append(float(alpha))
            self.noise_var.append(_noise_entry(noise))
            self.heading_scales.append(
                None if heading is None else np.asarray(heading, dtype=np.float64).ravel().copy()
            )

    def up_to(self, sweep: int) -> Draws:
        """The draws of sweeps ``<= sweep`` (a checkpoint's resume point)."""
        out = Draws(self.n_frames, list(self.sweeps), list(self.labels), list(self.length_scales), list(self.alpha),
                    list(self.noise_var), list(self.heading_scales), self.spill, self._files)  # fmt: skip
        out._select([i for i, s in enumerate(self.sweeps) if s <= sweep])
        return out

    def _select(self, idx: list[int]) -> None:
        self.sweeps = [self.sweeps[i] for i in idx]
        self.labels = [self.labels[i] for i in idx]
        self.length_scales = [self.length_scales[i] for i in idx]
        self.alpha = [self.alpha[i] for i in idx]
        self.noise_var = [self.noise_var[i] for i in idx]
        self.heading_scales = [self.heading_scales[i] for i in idx]

    # --- model-file members (dpgp.io) ----------------------------------------------------------
    def arrays(self) -> dict[str, np.ndarray]:
        d = len(self)
        return {
            "draw_sweeps": np.asarray(self.sweeps, dtype=np.int64),
            "draw_labels": np.asarray(self.labels, dtype=np.int32).reshape(d, self.n_frames),
            "draw_n_patterns": np.asarray([len(w) for w in self.length_scales], dtype=np.int64),
            "draw_length_scales": np.concatenate(self.length_scales) if d else np.zeros((0, 2)),
            "draw_alpha": np.asarray(self.alpha, dtype=np.float64),
            # NaN: a draw without its own noise (read from a file before the noise was sampled);
            # per-pattern noise: the first pattern's pair here, every pattern's in draw_pattern_noise_var
            "draw_noise_var": np.array(
                [
                    (np.nan, np.nan) if v is None else np.asarray(v, dtype=np.float64).reshape(-1, 2)[0]
                    for v in self.noise_var
                ],
                dtype=np.float64,
            ).reshape(d, 2),
            **self._pattern_noise_arrays(),
            **self._heading_arrays(),
        }

    def _pattern_noise_arrays(self) -> dict[str, np.ndarray]:
        """``draw_pattern_noise_var`` (ΣK, 2): each pattern's noise pair, draw by draw, when the
        draws hold per-pattern noise (then every draw does)."""
        if not self.noise_var or not all(isinstance(v, np.ndarray) for v in self.noise_var):
            return {}
        return {"draw_pattern_noise_var": np.concatenate(self.noise_var).reshape(-1, 2)}

    def _heading_arrays(self) -> dict[str, np.ndarray]:
        """``draw_heading_scales`` (ΣK,): each pattern's ``w_h``, draw by draw, when the draws are
        of fields over heading (then every draw has them)."""
        if not self.heading_scales or any(w is None for w in self.heading_scales):
            return {}
        return {"draw_heading_scales": np.concatenate([w for w in self.heading_scales if w is not None])}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], n_frames: int, min_ls: float, max_ls: float) -> Draws | None:
        """The draws a model file holds (None if it holds none: files before posterior draws);
        ``ValueError`` naming what is inconsistent."""
        names = ("draw_sweeps", "draw_labels", "draw_n_patterns", "draw_length_scales", "draw_alpha")
        present = [n for n in names if n in arrays]
        if not present:
            return None
        if len(present) != len(names):
            raise ValueError(f"the posterior draws need all of {names}, the file has {present}")
        sweeps, labels, counts, ls, alpha = (arrays[n] for n in names)
        d = len(sweeps)
        if (sweeps.dtype.kind not in "iu" or labels.dtype.kind not in "iu" or counts.dtype.kind not in "iu"
                or labels.shape != (d, n_frames) or counts.shape != (d,) or alpha.shape != (d,)
                or ls.ndim != 2 or ls.shape[1:] != (2,) or int(counts.sum()) != len(ls)):  # fmt: skip
            raise ValueError(f"the posterior draws' shapes do not fit {d} draws of {n_frames} frames")
        if d and (np.any(np.diff(sweeps) <= 0) or sweeps.min() < 1):
            raise ValueError("the posterior draws' sweeps must increase from 1")
        if not (np.all(np.isfinite(alpha)) and np.all(alpha > 0)):
            raise ValueError("the posterior draws' alpha must be positive")
        if not ((ls >= min_ls).all() and (ls <= max_ls).all()):
            raise ValueError(f"the posterior draws' length scales must lie in [{min_ls:g}, {max_ls:g}]")
        parts = np.split(ls.astype(np.float64), np.cumsum(counts)[:-1]) if d else []
        for lab, k in zip(labels, counts):
            if n_frames and (lab.min() < 0 or lab.max() >= k or len(np.unique(lab)) != k):
                raise ValueError("a posterior draw's labels do not name exactly its patterns")
        noise: list[Any] = [None] * d  # files before the noise was sampled
        if "draw_noise_var" in arrays:
            nv = arrays["draw_noise_var"]
            if nv.shape != (d, 2) or nv.dtype.kind != "f":
                raise ValueError(f"the posterior draws' noise variances must be a ({d}, 2) float array")
            known = ~np.isnan(nv).any(axis=1)
            if not (np.isfinite(nv[known]).all() and (nv[known] > 0).all() and (nv[known] <= max_ls).all()):
                raise ValueError(f"the posterior draws' noise variances must be positive and at most {max_ls:g}")
            noise = [(float(a), float(b)) if k else None for (a, b), k in zip(nv, known)]
        if "draw_pattern_noise_var" in arrays:
            pn = arrays["draw_pattern_noise_var"]
            if pn.shape != ls.shape or pn.dtype.kind != "f" or not (np.isfinite(pn).all() and (pn > 0).all()):
                raise ValueError("the posterior draws' per-pattern noise must be positive, one pair per pattern")
            noise = list(np.split(pn.astype(np.float64), np.cumsum(counts)[:-1])) if d else []
        heading: list[np.ndarray | None] = [None] * d  # fields over position
        if "draw_heading_scales" in arrays:
            wh = arrays["draw_heading_scales"]
            if wh.shape != (len(ls),) or wh.dtype.kind != "f":
                raise ValueError("the posterior draws' heading length scales must be one float per pattern (ΣK,)")
            if not ((wh >= min_ls).all() and (wh <= max_ls).all()):
                raise ValueError(f"the posterior draws' heading length scales must lie in [{min_ls:g}, {max_ls:g}]")
            heading = list(np.split(wh.astype(np.float64), np.cumsum(counts)[:-1])) if d else []
        return cls(n_frames, [int(s) for s in sweeps], [compact_labels(x) for x in labels], list(parts),
                   [float(a) for a in alpha], noise, heading)  # fmt: skip


class _SpillDir:
    """A temporary directory of draws' labels, removed with the last :class:`Draws` that uses it
    (or at exit). Each array is written to a file of its own and read back as a memory map, whose
    pages the system reads when they are used and may drop again."""

    def __init__(self) -> None:
        self.path = tempfile.mkdtemp(prefix="dpgp-draws-")
        self._finalizer = weakref.finalize(self, shutil.rmtree, self.path, True)

    def keep(self, labels: np.ndarray) -> np.ndarray:
        name = os.path.join(self.path, f"{uuid.uuid4().hex}.npy")
        np.save(name, labels)
        return np.load(name, mmap_mode="r")

    def remove(self, arrays: list[np.ndarray]) -> None:
        """Delete the files of ``arrays`` (their maps stay readable until dropped)."""
        for a in arrays:
            name = getattr(a, "filename", None)
            if name is not None and os.path.dirname(name) == self.path:
                try:
                    os.remove(name)
                except FileNotFoundError:
                    pass


#: One kept state: labels, length scales (K, 2), α, the noise: a pair, each pattern's pairs
#: ((K, 2) array, per-pattern noise), or None (the model's own), and the heading length scales
#: ((K,) array, fields over heading) or None (fields over position).
State = tuple[np.ndarray, np.ndarray, float, Any, np.ndarray | None]


def _noise_entry(noise: Any) -> Any:
    if noise is None:
        return None
    if isinstance(noise, np.ndarray) and noise.ndim == 2:
        return np.asarray(noise, dtype=np.float64).copy()
    return (float(noise[0]), float(noise[1]))


def state_of(sampler: Any, per_pattern: bool = False, headed: bool = False) -> State:
    """A sampler's state as a draw: labels with patterns by decreasing size (ties by slot), their
    length scales (K, 2), α, the noise pair (``per_pattern``: each pattern's, (K, 2)) and, for
    fields over heading (``headed``), their heading length scales (K,)."""
    patterns = sampler.patterns()  # (slot, id, n_frames, wx, wy)
    order = sorted(range(len(patterns)), key=lambda j: (-patterns[j][2], patterns[j][0]))
    slots = np.array([patterns[j][0] for j in order], dtype=np.int64)
    raw = np.asarray(sampler.labels())
    # Patterns numbered in the smallest type that holds them: at millions of frames the labels
    # are most of a draw's memory.
    lookup = np.zeros(int(slots.max()) + 1 if len(slots) else 1, dtype=np.min_scalar_type(max(len(slots) - 1, 0)))
    lookup[slots] = np.arange(len(slots))
    ls = np.array([[patterns[j][3], patterns[j][4]] for j in order], dtype=np.float64).reshape(-1, 2)
    wh = np.asarray(sampler.heading_scales(), dtype=np.float64)[order] if headed else None
    if per_pattern:
        per_slot = np.asarray(sampler.pattern_noise(), dtype=np.float64).reshape(-1, 2)
        return lookup[raw], ls, float(sampler.alpha()), per_slot[order], wh
    noise = tuple(float(x) for x in sampler.noise_var())
    return lookup[raw], ls, float(sampler.alpha()), (noise[0], noise[1]), wh


def used(draws: Draws | None, n_iter: int) -> list[int]:
    """Indices of the kept draws that scores average over: those after the burn-in (the first
    half of the ``n_iter`` sweeps), but not the final state's own sweep (the caller adds it)."""
    if draws is None:
        return []
    return [i for i, s in enumerate(draws.sweeps) if n_iter // 2 < s < n_iter]


def _draw_terms(sampler: Any, state: State, frames: Any, h: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """For one state: (n_test, K+1) log [DP weight × likelihood] per pattern (state label order)
    and a new one, and the (K,) training-frame counts per pattern. ``h``: the test frames'
    previous headings (fields over heading, whose states carry their heading length scales)."""
    labels, ls, alpha, noise, heading = state
    if (heading is None) != (h is None):
        raise ValueError("a state of fields over heading is scored with the frames' headings, and only such a state")
    wh = None if heading is None else [float(x) for x in heading]
    if isinstance(noise, np.ndarray) and noise.ndim == 2:  # each pattern's own pair
        sampler.set_state(np.asarray(labels, dtype=np.int64), ls, alpha, noise, heading_scales=wh)
    else:
        if noise is not None:
            sampler.set_noise_var(noise)
        sampler.set_state(np.asarray(labels, dtype=np.int64), ls, alpha, heading_scales=wh)
    cur = state_of(sampler)[0]
    if not np.array_equal(cur, labels):  # set_state keeps label k in slot order k
        raise RuntimeError("the sampler did not take the draw's labels")
    patterns = sampler.patterns()
    order = sorted(range(len(patterns)), key=lambda j: (-patterns[j][2], patterns[j][0]))
    per_slot, new = sampler.score_frames(frames.xy, frames.v, frames.offsets, h)
    scores = np.asarray(per_slot, dtype=np.float64).reshape(len(frames), -1)[:, order]
    counts = np.bincount(labels, minlength=len(ls)).astype(np.float64)
    n = counts.sum()
    log_prior = np.log(np.r_[counts, alpha]) - np.log(n + alpha)
    return np.column_stack([scores, np.asarray(new, dtype=np.float64)]) + log_prior, counts


def averaged(
    final_terms: np.ndarray,
    final_labels: np.ndarray,
    states: list[State],
    new_sampler: Callable[[], object],
    frames: object,
    h: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior-averaged ``(log density (n_test,), probabilities (n_test, K_final + 1))`` over the
    final state (its joint terms ``final_terms`` and labels) and the other kept ``states``
    (module docstring). ``new_sampler`` builds a sampler over the training frames to score a
    state with (called once, only if there are other states). ``h``: the previous headings of
    ``frames``' vehicles, for fields over heading (each state then carries its ``w_h``)."""
    k_final = final_terms.shape[1] - 1
    # One block per state: terms (n_test, K_s + 1) and the soft map of its patterns onto the final
    # ones ((K_s + 1, K_final + 1), "new" to "new").
    blocks = [(final_terms, np.eye(k_final + 1))]
    if states:
        sampler = new_sampler()
        for state in states:
            terms, counts = _draw_terms(sampler, state, frames, h)
            overlap = np.zeros((len(counts) + 1, k_final + 1))
            np.add.at(overlap, (np.asarray(state[0], dtype=np.int64), np.asarray(final_labels, dtype=np.int64)), 1.0)
            overlap[:-1] /= counts[:, None]
            overlap[-1, -1] = 1.0
            blocks.append((terms, overlap))
    top = np.max([t.max(axis=1) for t, _ in blocks], axis=0)[:, None]
    weights = [np.exp(t - top) for t, _ in blocks]
    per_state = np.column_stack([w.sum(axis=1) for w in weights])  # p_s(V) / e^top
    log_density = top[:, 0] + np.log(per_state.sum(axis=1)) - np.log(len(blocks))
    proba = sum(w @ o for w, (_, o) in zip(weights, blocks))
    return log_density, proba / proba.sum(axis=1, keepdims=True)


__all__ = ["Draws", "MAX_DRAWS", "averaged", "state_of", "thin_for", "used"]
