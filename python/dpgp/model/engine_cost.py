"""``likelihood="auto"``: pick the engine (exact GP or hsgp) whose sweep is predicted to be faster.

**Cost model** (seconds per Gibbs sweep, default settings: gibbs assignment, informed proposals,
every pattern's length scales slice-sampled each sweep). With ``n_k`` the training points of
pattern ``k``, ``l_f`` the vehicles of frame ``f`` and ``M`` the hsgp basis size:

- exact: ``a1 Σ_f l_f² + a2 Σ n_k² + a3 Σ n_k³``. A pattern's moves are rank-``l`` updates of
  its ``n_k × n_k`` factor and its length-scale steps refactor it (``n_k³``); building its
  kernel matrix costs ``n_k²`` exponentials; each frame's new-pattern term (Algorithm 8's
  auxiliary patterns) builds ``l_f × l_f`` kernels.
- hsgp: ``b1 M Σ_f l_f² + b2 Σ n_k s_k² + b3 Σ s_k³ + b4 M Σ_{n_k ≤ M} n_k²`` with
  ``s_k = min(n_k, M)``: a move or score is ``O(l s_k²)`` (``Σ n_k s_k²`` over a sweep) and a
  length-scale step one ``s_k × s_k`` Cholesky; a pattern with fewer points than basis
  functions uses a dense ``n_k × n_k`` factor of the reduced-rank kernel, each of whose entries
  sums ``M`` terms (``b4``), as do the new-pattern term's kernels (``b1``).

The coefficients (:data:`COEFFICIENTS`) were fitted by non-negative least squares to timed
sweeps on this 2-core machine (``python benches/engine_cost.py calibrate``; docs/engines-and-scores.md
gives the design and the fit's errors). Other machines differ in scale, but the rule compares the
two engines on one machine, so what matters is their ratio.

**The rule** (:func:`choose`). The two engines target different models (hsgp's reduced-rank
kernel is a kernel of its own), so the engine is chosen once, before the chain starts, and never
switched mid-fit:

1. exact's worst case, every point in one pattern, is predicted at most ``HSGP_MARGIN`` (4) times
   slower than hsgp's best case
   (its per-frame term alone, a bound below any partition) and its peak fits the memory budget: exact,
   without further work;
2. otherwise the pattern sizes are predicted by the hsgp sampler's own sequential
   initialisation (cheap: ``O(l M²)`` a frame); hsgp runs if it is predicted at least
   ``HSGP_MARGIN`` times faster on those sizes, or exact's peak (:func:`exact_peak_bytes`: every
   point in one pattern, with the candidate copies of its steps) exceeds the memory budget; else
   exact. If hsgp wins,
   the fit continues from that initialisation (so ``auto`` is then bitwise ``likelihood="hsgp"``);
   if exact wins, the exact sampler starts afresh from its own initialisation (bitwise
   ``likelihood="exact"``).

3. **accuracy first**: before hsgp is kept, a probe checks that its basis can represent what
   the data ask of the kernel (:func:`partition_gap`, :func:`resolution_gap`): for each pattern of
   a sequential initialisation, on its frames at a common stride (about :data:`PROBE_POINTS`
   points in all), the best exact marginal likelihood over a grid of length scales and noise is
   compared with hsgp's best on the same grid; the per-point gaps are averaged weighted by the
   patterns' points. The initialisations are those of the seeds :data:`PROBE_SEEDS`, not the
   fit's: the decision is one about the data and must not change with the chain's seed (one
   initialisation's patterns are a crude, seed-dependent partition; the gap of its largest
   pattern alone ranged from −0.02 to 0.41 over seeds 0–4 on Peachtree). The median over them is
   the probe's gap; if it exceeds :data:`PROBE_TOLERANCE` nats per point, the data want length
   scales finer than the basis resolves (hsgp would fit and predict worse, not just differently),
   and exact runs when it fits the memory budget. So auto picks the faster engine *among those
   accurate on the data*.

**Fields over heading** (``inputs="position+heading"``, docs/heading.md). Same rule, same
coefficients, with these changes:

- hsgp's basis is the position basis and ``2J`` heading functions (``cos h, sin h, …, cos Jh,
  sin Jh``, ``J`` the estimator's harmonics rule) each times the lowest ``m'_x m'_y`` position
  functions (the estimator's stride rule), so ``M`` in every hsgp term is
  ``m_x m_y + 2J m'_x m'_y`` (:func:`heading_basis_size`): its factors grow to match, and so
  does its memory (``K M²``; the core's memory budget checks it as the chain runs, as for
  position fits). ``Choice.basis`` records that ``M`` and ``Choice.heading_functions`` the
  ``2J + 1``.
- exact's terms are unchanged: the product kernel is one fused exponential per entry
  (``exp(−r² + z (cos h cos h' + sin h sin h' − 1))`` with the cosines and sines computed once
  per point), about what the position kernel costs, and its factors are the same ``n_k × n_k``.
  Its memory is the same too.
- hsgp is costed on the sampler it would run on, the sub-cluster one by default: its ``K M³``
  factorisations grow ``(2J + 1)³``-fold and its per-point term ``(2J + 1)``-fold.
- the accuracy probe runs **with the headings**: both GPs of :func:`resolution_gap` get each
  point's previous heading (``NaN`` where a vehicle has none, as the fit treats it), hsgp's basis
  the fit's ``J`` harmonics, and the grid adds heading length scales :data:`PROBE_HEADING_SCALES`
  times the prior's mean. A probe over positions alone judges a different kernel from the one
  the fit runs: where opposite lanes lie closer than the basis resolves, the position GP must
  bend between opposite velocities within centimetres, which only exact can, so that probe sends
  the fit to exact for a structure the heading input separates at coarse length scales (a
  two-way road with lanes 0.2 m apart, 240 points, a 150-function position basis: 0.75 nats per
  point over positions, 0.002 with the headings; ``tests/model/test_heading_auto.py``). It also
  could not see what the heading cut costs (``J`` harmonics keep 99% of the periodic kernel's
  variance only down to the prior's 5% quantile, less with the cap of 3). The tolerance stays
  :data:`PROBE_TOLERANCE` nats per point, set on fields over position (the same units: exact's
  best fit less hsgp's); it has not been recalibrated on fits over heading. **Cost:** hsgp's
  marginal likelihoods of a probe sample sum ``M`` terms per kernel entry, so the probe costs
  about ``2 (2J + 1)`` times the position one (two heading scales, seven times the functions):
  on that road 11-13 s against 0.1-0.2 s. It runs only when auto gets to step 2 (exact's worst
  case predicted well over hsgp's best), on data whose sweeps cost seconds.

Accuracy: hsgp's kernel stays within its documented error of the squared exponential where the
basis resolves the data's length scales (README, "How it is fast": median 0.011 nats per frame on
US-101; ``tests/test_hsgp.py``); the probe is what checks "where".
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

ENGINES = ("exact", "hsgp", "subcluster")

#: hsgp runs only where it is predicted at least this many times faster than exact. Exact is the
#: model and hsgp its approximation, and each engine's prediction is off by up to about 2× on
#: typical scenes (docs/engines-and-scores.md), so a closer call is not evidence that hsgp is
#: faster; on such near-ties (Peachtree, Lankershim) hsgp's held-out density was also far below
#: exact's.
HSGP_MARGIN = 4.0

#: A predicted exact sweep at most this many seconds is fast enough whatever hsgp would take:
#: on tiny problems the predictions are microseconds (fixed overheads the model leaves out
#: dominate), and exact is the model itself, so speed gives no reason to approximate it.
EXACT_FAST_ENOUGH = 0.05

#: Seconds per sweep = coefficients · features (:func:`features`), in the features' order; fitted
#: on this machine by ``python benches/engine_cost.py calibrate`` then ``fit``.
COEFFICIENTS: dict[str, tuple[float, ...]] = {
    "exact": (2.02e-6, 7.19e-7, 8.09e-10),
    "hsgp": (3.31e-10, 0.0, 2.84e-9, 4.17e-9),
    "subcluster": (1.85e-10, 1.9e-10, 1.58e-10),
}


def features(engine: str, pattern_points: object, frame_sizes: object, basis_size: int | None = None) -> np.ndarray:
    """The cost model's features of one sweep (module docstring): ``[Σ l_f², Σ n_k², Σ n_k³]``
    for exact, ``[M Σ l_f², Σ n_k s_k², Σ s_k³, M Σ_{n_k ≤ M} n_k²]`` for hsgp on the collapsed
    sampler, ``[M K Σ l_f, K M³, moves (M Σ l_f / K + M³)]`` for hsgp on the sub-cluster sampler."""
    n = np.asarray(pattern_points, dtype=np.float64).ravel()
    frames_sq = float((np.asarray(frame_sizes, dtype=np.float64) ** 2).sum())
    if engine == "exact":
        return np.array([frames_sq, float((n**2).sum()), float((n**3).sum())])
    if engine == "subcluster":
        if basis_size is None or basis_size < 1:
            raise ValueError("the subcluster cost needs the basis size M")
        m, k = float(basis_size), max(len(n), 1)
        points = float(np.asarray(frame_sizes, dtype=np.float64).sum())
        moves = float(subcluster_moves(len(np.asarray(frame_sizes))))
        return np.array([points * m * k, k * m**3, moves * (points / k * m + m**3)])
    if engine == "hsgp":
        if basis_size is None or basis_size < 1:
            raise ValueError("the hsgp cost needs the basis size M")
        m = float(basis_size)
        s = np.minimum(n, m)
        return np.array(
            [m * frames_sq, float((n * s**2).sum()), float((s**3).sum()), m * float((n[n <= m] ** 2).sum())]
        )
    raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")


def subcluster_moves(n_frames: int) -> int:
    """The sub-cluster sampler's split–merge moves per sweep under ``split_merge="auto"``: about
    :data:`dpgp.defaults.SUBCLUSTER_MOVE_FRAMES` frames' work (at least one move, at most
    :data:`dpgp.defaults.SPLIT_MERGE_MOVES`), a function of the data's size only (a count that
    depended on the state would break the chain's balance)."""
    from ..gp.defaults import SPLIT_MERGE_MOVES, SUBCLUSTER_MOVE_FRAMES

    return int(np.clip(SUBCLUSTER_MOVE_FRAMES // max(int(n_frames), 1), 1, SPLIT_MERGE_MOVES))


def heading_basis_size(position_size: int, harmonics: int, heading_size: int | None = None) -> int:
    """hsgp's ``M`` for fields over heading: the position basis and ``2J`` heading functions
    (``J = harmonics``) times ``heading_size`` position functions each (None: the position basis;
    ``harmonics = 0``: the position basis itself)."""
    if harmonics < 0:
        raise ValueError(f"heading harmonics must be non-negative, got {harmonics}")
    block = int(position_size) if heading_size is None else int(heading_size)
    return int(position_size) + 2 * int(harmonics) * block


def sweep_seconds(engine: str, pattern_points: object, frame_sizes: object, basis_size: int | None = None) -> float:
    """Predicted seconds of one sweep of ``engine`` with patterns of these sizes (points) over
    frames of these sizes (vehicles)."""
    return float(np.dot(COEFFICIENTS[engine], features(engine, pattern_points, frame_sizes, basis_size)))


def exact_bytes(largest_pattern_points: int) -> int:
    """Memory exact needs at most for a pattern of this many points: one factor per output group,
    each in a buffer that grows by a quarter when full (the core's ``factor::capacity``: a quarter
    to spare, a multiple of 16, at least 16)."""
    n = int(largest_pattern_points)
    cap = -(-max(n + n // 4, 16) // 16) * 16
    return 8 * 2 * cap**2


def exact_peak_bytes(n_points: int) -> int:
    """About the most exact can come to hold on data of ``n_points`` points, whatever partition
    the chain reaches: the factors of every point in one pattern, plus the parallel steps' two
    candidate copies of the patterns being updated (of at most as many points in all; the core's
    ``candidate_bytes``). Auto chooses exact only within this, so that a default fit does not stop
    on the memory budget mid-chain: the partition an initialisation finds says little about the
    one the chain reaches (all 3,150 frames of the SUMO junction, 23,936 points: the initial
    patterns fitted the budget, and the exact chain stopped after about 20 minutes needing
    12.5 GB of a 12.3 GB budget)."""
    return 3 * exact_bytes(n_points)


@dataclass(frozen=True)
class Choice:
    """What :func:`choose` decided and why: ``engine``; ``basis`` (hsgp's M, heading functions
    included); ``sizes_from``
    (``"worst case"`` or ``"hsgp initialisation"``); the predicted seconds per sweep of both
    engines on those sizes; ``exact_fits`` (exact's peak, :func:`exact_peak_bytes`, within the
    memory budget)."""

    engine: str
    basis: int
    sizes_from: str
    exact_seconds: float
    hsgp_seconds: float
    exact_fits: bool
    #: :func:`resolution_gap` of the probe (nats per point), when it ran (hsgp predicted faster)
    resolution_gap: float | None = None
    #: the probe's gap on each initialisation of :data:`PROBE_SEEDS`; ``resolution_gap`` is their median
    probe_gaps: tuple[float, ...] | None = None
    #: heading functions per position function in hsgp's basis (``2J + 1`` for fields over
    #: heading, 1 over position): ``basis`` is the position basis times this
    heading_functions: int = 1

    def to_dict(self) -> dict:
        out = asdict(self)
        out["probe_gaps"] = None if self.probe_gaps is None else [float(g) for g in self.probe_gaps]
        return out


def choose_upfront(
    frame_sizes: object,
    basis_size: int,
    memory_budget: int | None,
    subcluster: bool = False,
    harmonics: int = 0,
    heading_size: int | None = None,
) -> Choice | None:
    """Step 1 of the rule: exact if its worst case (all points in one pattern) is predicted no
    slower than hsgp's least cost over all partitions (its per-frame term alone) and fits the
    budget; None when the pattern sizes must be predicted first. ``subcluster``: hsgp would run
    on the sub-cluster sampler, and its least cost is one pattern's sweep on that sampler.
    ``basis_size``: the position basis; ``harmonics``: the heading harmonics ``J`` of a field over
    heading, ``heading_size`` its heading blocks' position functions, whose hsgp ``M`` is
    :func:`heading_basis_size`."""
    functions = 2 * int(harmonics) + 1
    basis_size = heading_basis_size(basis_size, harmonics, heading_size)
    n_points = int(np.sum(np.asarray(frame_sizes)))
    exact = sweep_seconds("exact", [n_points], frame_sizes)
    hsgp = sweep_seconds(
        "subcluster" if subcluster else "hsgp", [n_points] if subcluster else [], frame_sizes, basis_size
    )
    fits = memory_budget is None or exact_peak_bytes(n_points) <= memory_budget
    if fits and (exact <= HSGP_MARGIN * hsgp or exact <= EXACT_FAST_ENOUGH):
        return Choice("exact", basis_size, "worst case", exact, hsgp, fits, heading_functions=functions)
    return None


def choose(
    pattern_points: object,
    frame_sizes: object,
    basis_size: int,
    memory_budget: int | None,
    subcluster: bool = False,
    harmonics: int = 0,
    heading_size: int | None = None,
) -> Choice:
    """Step 2 of the rule: hsgp if it is predicted :data:`HSGP_MARGIN` times faster on these
    pattern sizes (points) or exact's peak (:func:`exact_peak_bytes`) does not fit the memory
    budget; else exact. ``subcluster``: hsgp's sweep is the sub-cluster sampler's.
    ``basis_size``, ``harmonics`` and ``heading_size`` as in :func:`choose_upfront`."""
    functions = 2 * int(harmonics) + 1
    basis_size = heading_basis_size(basis_size, harmonics, heading_size)
    n = np.asarray(pattern_points, dtype=np.float64).ravel()
    exact = sweep_seconds("exact", n, frame_sizes)
    hsgp = sweep_seconds("subcluster" if subcluster else "hsgp", n, frame_sizes, basis_size)
    fits = memory_budget is None or exact_peak_bytes(int(n.sum())) <= memory_budget
    engine = "exact" if fits and (exact <= HSGP_MARGIN * hsgp or exact <= EXACT_FAST_ENOUGH) else "hsgp"
    return Choice(engine, basis_size, "hsgp initialisation", exact, hsgp, fits, heading_functions=functions)


#: Points of the accuracy probe (per initialisation): enough for the data's length scales to show,
#: few enough that its exact marginal likelihoods (40 per pattern) cost a second or two.
PROBE_POINTS = 800
#: Nats per point by which exact's best probe fit may beat hsgp's (:func:`partition_gap`, median
#: over :data:`PROBE_SEEDS`). Where hsgp's held-out density is within 0.02 nats of exact's (US-101)
#: the probe reads 0.14, on the SUMO left turn 0.03; on Peachtree, where hsgp is 0.2 to 3 nats per
#: vehicle worse held out, 0.66; on the SUMO grid junction, 4.2 nats worse, 0.57 (training 70%, seed
#: 0); the tolerance sits between them (docs/engines-and-scores.md).
PROBE_TOLERANCE = 0.22
#: Noise of the probe's grid, as shares of each component's signal variance. Down to 0.3%: a
#: simulated junction's velocities are nearly a function of place and lane, and exact's advantage
#: shows only at such noise (with 3% the lowest, the SUMO grid read 0.15-0.22 and kept hsgp).
PROBE_NOISE = (0.003, 0.01, 0.03, 0.1, 0.3)
#: Heading length scales of the probe's grid for fields over heading, as multiples of the ``w_h``
#: prior's mean: 0.6 and 1.2 rad under :data:`dpgp.model.estimator.HEADING_PRIOR` (about its 5%
#: quantile, 0.52, and its mean). The lower is where the heading harmonics' cut shows, if the data
#: want it; each scale adds a full grid of hsgp's costliest probe evaluations, so two, not more.
PROBE_HEADING_SCALES = (0.5, 1.0)
#: Seeds of the initialisations the probe reads: fixed, so that auto's engine is a function of the
#: data and the settings, never of the fit's seed.
PROBE_SEEDS = (0, 1, 2, 3, 4)


def probe_points(
    labels: np.ndarray, frames: Any, pattern: int, limit: int = PROBE_POINTS
) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities of ``pattern``'s frames (the largest), about ``limit`` points: every
    ``s``-th of its frames, ``s`` the stride that keeps the total under ``limit``. Spread over the
    pattern, not its first frames: consecutive frames repeat the same vehicles a step apart, and
    near-duplicates look like fine structure that only the exact GP can interpolate."""
    sizes = np.asarray(frames.sizes, dtype=np.int64)
    members = np.flatnonzero(np.asarray(labels, dtype=np.int64) == pattern)
    stride = max(1, int(np.ceil(sizes[members].sum() / limit)))
    chosen = [frames[int(i)] for i in members[::stride]]
    return np.concatenate([f.xy for f in chosen]), np.concatenate([f.v for f in chosen])


def resolution_gap(
    xy: np.ndarray,
    v: np.ndarray,
    params: Any,
    basis: Any,
    h: np.ndarray | None = None,
    heading_scales: tuple[float, ...] = (),
) -> float:
    """``(max exact − max hsgp) / points``: the best log marginal likelihood of ``(xy, v)`` under
    the exact GP over a grid of isotropic length scales and noise, less hsgp's best on the same
    grid, per point. The grid's length scales run from an eighth of the basis resolution (its
    shortest wavelength over π: ``2 L / m``) to four times it, so data that want shorter length
    scales than the basis holds show a gap; the noise takes :data:`PROBE_NOISE` of each
    component's signal variance; the means and signal variances are ``params``'.

    Fields over heading: ``h``, the points' previous headings (``NaN``: none), and
    ``heading_scales``, the grid's heading length scales ``w_h`` (radians); ``basis`` then carries
    the fit's heading harmonics (module docstring: why the probe runs with headings)."""
    from ..gp import exact, hsgp

    if (h is None) != (len(heading_scales) == 0):
        raise ValueError("give the headings h and the grid's heading_scales together")
    res = float(min(2.0 * half / m for half, m in zip(basis.half_widths, basis.counts)))
    best = {"exact": -np.inf, "hsgp": -np.inf}
    s2 = np.asarray(params.signal_var, dtype=np.float64)
    for wh in heading_scales or (float("inf"),):
        for share in PROBE_NOISE:
            for w in np.geomspace(res / 8.0, 4.0 * res, 8):
                p = dataclasses.replace(
                    params,
                    length_scales=(float(w), float(w)),
                    noise_var=tuple(map(float, share * s2)),
                    heading_scale=float(wh),
                )
                best["exact"] = max(best["exact"], exact.log_marginal_likelihood(xy, v, p, h))
                best["hsgp"] = max(best["hsgp"], hsgp.log_marginal_likelihood(xy, v, p, basis, h))
    return (best["exact"] - best["hsgp"]) / len(xy)


def partition_gap(
    labels: np.ndarray,
    frames: Any,
    params: Any,
    basis: Any,
    limit: int = PROBE_POINTS,
    cache: dict[bytes, float] | None = None,
    heading_scales: tuple[float, ...] = (),
) -> float:
    """The probe's gap on one partition: :func:`resolution_gap` of each pattern on its frames at
    the stride ``s`` that keeps the whole data under about ``limit`` points (every ``s``-th of the
    pattern's frames, from its first; a pattern of fewer than ``s`` frames keeps its first), averaged
    over the patterns weighted by their points (all of them, not the sample's): the per-point gap of
    the mixture's marginal likelihood, pattern by pattern. Every pattern counts, so a few small
    patterns that only the exact GP can fit (a queue at the scene's edge, a turn) weigh in, and
    no single pattern decides. ``cache`` (frames sampled -> gap) lets the initialisations of
    several seeds share the gaps of the patterns they have in common. ``heading_scales`` (fields
    over heading; ``basis`` with the fit's harmonics): probe with the frames' previous headings
    over these ``w_h`` (:func:`resolution_gap`)."""
    labels = np.asarray(labels, dtype=np.int64)
    sizes = np.asarray(frames.sizes, dtype=np.int64)
    points = pattern_points(labels, sizes)
    stride = max(1, int(np.ceil(sizes.sum() / limit)))
    cache = {} if cache is None else cache
    total = 0.0
    for k in np.flatnonzero(points > 0):
        rows = np.flatnonzero(labels == k)[::stride]
        key = rows.tobytes()
        if key not in cache:
            chosen = [frames[int(i)] for i in rows]
            xy, v = np.concatenate([f.xy for f in chosen]), np.concatenate([f.v for f in chosen])
            h = np.concatenate([f.prev_heading for f in chosen]) if heading_scales else None
            cache[key] = resolution_gap(xy, v, params, basis, h, heading_scales)
        total += points[k] * cache[key]
    return float(total / points.sum())


def check_accuracy(choice: Choice, gap: float, gaps: Any = None) -> Choice:
    """Step 3 of the rule: keep hsgp only if the probe's gap (the median of ``gaps``, one per
    initialisation, when given) is within :data:`PROBE_TOLERANCE` (or exact does not fit the memory
    budget); record the gap either way."""
    engine = "exact" if choice.engine == "hsgp" and gap > PROBE_TOLERANCE and choice.exact_fits else choice.engine
    kept = None if gaps is None else tuple(float(g) for g in gaps)
    return dataclasses.replace(choice, engine=engine, resolution_gap=float(gap), probe_gaps=kept)


def pattern_points(labels: np.ndarray, frame_sizes: np.ndarray) -> np.ndarray:
    """Training points per pattern, from per-frame labels and vehicle counts."""
    labels = np.asarray(labels, dtype=np.int64)
    return np.bincount(labels, weights=np.asarray(frame_sizes, dtype=np.float64)) if len(labels) else np.zeros(0)


__all__ = [
    "COEFFICIENTS",
    "PROBE_HEADING_SCALES",
    "PROBE_SEEDS",
    "PROBE_TOLERANCE",
    "Choice",
    "check_accuracy",
    "choose",
    "choose_upfront",
    "exact_bytes",
    "exact_peak_bytes",
    "features",
    "heading_basis_size",
    "partition_gap",
    "pattern_points",
    "probe_points",
    "resolution_gap",
    "sweep_seconds",
]
