# Type stubs of the native module dpgp._core (rust/py). Users import dpgp, not this.
from collections.abc import Callable
from typing import Any, TypedDict, final

import numpy as np
from numpy.typing import NDArray
from typing_extensions import NotRequired, Self

__all__ = [
    "check_params",
    "criticality",
    "heading_harmonics",
    "check_length_scale_prior",
    "log_marginal_likelihood",
    "nearest_neighbour_sq",
    "log_predictive",
    "log_predictive_frames",
    "posterior",
    "hsgp_basis",
    "hsgp_log_marginal_likelihood",
    "hsgp_log_predictive",
    "hsgp_posterior",
    "Sampler",
    "Shard",
    "check_settings",
    "MAX_THREADS",
    "MAX_NEW_PATTERN_SAMPLES",
    "MAX_SPLIT_MERGE_MOVES",
    "ALPHA_RANGE",
    "LENGTH_SCALE_MEAN_RANGE",
    "field_means",
    "integrate_affine",
    "motion_rollouts",
    "rollouts",
    "scene_rollouts",
    "__version__",
]

__version__: str

# The settings' limits (rust/core/src/gibbs.rs); the core checks them, Python only shows them.
MAX_THREADS: int
MAX_NEW_PATTERN_SAMPLES: int
MAX_SPLIT_MERGE_MOVES: int
ALPHA_RANGE: tuple[float, float]
LENGTH_SCALE_MEAN_RANGE: tuple[float, float]

_ParamTuple = tuple[float, float, float, float, float, float, float, float]

def check_params(p: _ParamTuple) -> None: ...

# Headings (radians, NaN: unknown) are optional; wh is the heading length scale (inf: position only).
def log_marginal_likelihood(
    xy: NDArray[np.float64],
    v: NDArray[np.float64],
    p: _ParamTuple,
    h: NDArray[np.float64] | None = None,
    wh: float = ...,
) -> float: ...
def log_predictive(
    train_xy: NDArray[np.float64],
    train_v: NDArray[np.float64],
    test_xy: NDArray[np.float64],
    test_v: NDArray[np.float64],
    p: _ParamTuple,
    train_h: NDArray[np.float64] | None = None,
    test_h: NDArray[np.float64] | None = None,
    wh: float = ...,
) -> float: ...
def log_predictive_frames(
    train_xy: NDArray[np.float64],
    train_v: NDArray[np.float64],
    test_xy: NDArray[np.float64],
    test_v: NDArray[np.float64],
    offsets: NDArray[np.int64],
    p: _ParamTuple,
) -> NDArray[np.float64]: ...
def posterior(
    train_xy: NDArray[np.float64],
    train_v: NDArray[np.float64],
    query_xy: NDArray[np.float64],
    p: _ParamTuple,
    train_h: NDArray[np.float64] | None = None,
    query_h: NDArray[np.float64] | None = None,
    wh: float = ...,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...

# Rollouts (rust/py/src/simulate.rs). Each returns (positions (R, 2), velocities (R, 2),
# in_roi (R,), low_data (R,)), rows grouped by rollout, then time, then vehicle.
_RolloutArrays = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]
# Start headings of a fit over heading: one per start row (NaN: unknown), and the speed from
# which a velocity gives a heading.
_Headings = tuple[NDArray[np.float64], float]

def rollouts(
    sampler: Sampler,
    slots: list[int],
    start: NDArray[np.float64],
    offsets: NDArray[np.int64],
    dt: float,
    steps: int,
    method: str,
    roi: tuple[float, float, float, float] | None = None,
    seeds: list[int] | None = None,
    low_data: float | None = None,
    headings: _Headings | None = None,
    max_curvature: float | None = None,
) -> _RolloutArrays: ...
def motion_rollouts(
    sampler: Sampler,
    slots: list[int],
    start: NDArray[np.float64],
    velocities: NDArray[np.float64],
    offsets: NDArray[np.int64],
    motion: NDArray[np.float64],
    dt: float,
    steps: int,
    roi: tuple[float, float, float, float] | None = None,
    seeds: list[int] | None = None,
    low_data: float | None = None,
    drivers: NDArray[np.float64] | None = None,
    support: bool = False,
    mixtures: list[list[tuple[int, float]]] | None = None,
    renew: bool = False,
    stops: list[list[tuple[float, float, float, float]]] | None = None,
    free_speeds: tuple[float, float, float, NDArray[np.float64]] | None = None,
    headings: _Headings | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_], NDArray[np.float64]]: ...
def scene_rollouts(
    sampler: Sampler,
    slots: list[int],
    counts: list[int],
    grid: list[int],
    grids: NDArray[np.float64],
    bins: tuple[int, int],
    grid_roi: tuple[float, float, float, float],
    spacing: list[float],
    motion: NDArray[np.float64],
    seeds: list[int],
    stochastic: bool,
    dt: float,
    steps: int,
    roi: tuple[float, float, float, float] | None = None,
    low_data: float | None = None,
    starts: NDArray[np.float64] | None = None,
    start_offsets: NDArray[np.int64] | None = None,
    headings: _Headings | None = None,
    shift: tuple[float, float] | None = None,
) -> tuple[
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.bool_],
    NDArray[np.bool_],
    list[int],
    list[float],
    NDArray[np.float64],
    NDArray[np.float64],
]: ...
def field_means(
    sampler: Sampler,
    slots: list[int],
    xy: NDArray[np.float64],
    offsets: NDArray[np.int64],
    h: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]: ...
def integrate_affine(
    start: NDArray[np.float64],
    a: tuple[tuple[float, float], tuple[float, float]],
    b: tuple[float, float],
    dt: float,
    steps: int,
    method: str,
    roi: tuple[float, float, float, float] | None = None,
) -> _RolloutArrays: ...
def criticality(
    positions: NDArray[np.float64],
    velocities: NDArray[np.float64],
    present: NDArray[np.bool_],
    offsets: NDArray[np.int64],
    vehicles: list[int],
    sizes: NDArray[np.float64],
    dt: float,
    min_speed: float,
    headings: NDArray[np.float64] | None = None,
) -> tuple[
    NDArray[np.int64],
    NDArray[np.int64],
    NDArray[np.int64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.bool_],
    NDArray[np.float64],
]: ...

_BasisTuple = tuple[tuple[float, float], tuple[float, float], tuple[int, int]]

def hsgp_basis(
    xy: NDArray[np.float64],
    length_scale_prior: tuple[float, float],
    length_scales: tuple[float, float] | None = None,
    n_basis: tuple[int, int] | None = None,
) -> _BasisTuple: ...
def heading_harmonics(prior: tuple[float, float]) -> int: ...
def hsgp_log_marginal_likelihood(
    xy: NDArray[np.float64],
    v: NDArray[np.float64],
    p: _ParamTuple,
    b: _BasisTuple,
    h: NDArray[np.float64] | None = None,
    wh: float = ...,
    harmonics: int = 0,
    heading_counts: tuple[int, int] | None = None,
) -> float: ...
def hsgp_log_predictive(
    train_xy: NDArray[np.float64],
    train_v: NDArray[np.float64],
    test_xy: NDArray[np.float64],
    test_v: NDArray[np.float64],
    p: _ParamTuple,
    b: _BasisTuple,
    train_h: NDArray[np.float64] | None = None,
    test_h: NDArray[np.float64] | None = None,
    wh: float = ...,
    harmonics: int = 0,
    heading_counts: tuple[int, int] | None = None,
) -> float: ...
def hsgp_posterior(
    train_xy: NDArray[np.float64],
    train_v: NDArray[np.float64],
    query_xy: NDArray[np.float64],
    p: _ParamTuple,
    b: _BasisTuple,
    train_h: NDArray[np.float64] | None = None,
    query_h: NDArray[np.float64] | None = None,
    wh: float = ...,
    harmonics: int = 0,
    heading_counts: tuple[int, int] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...

class _SamplerSettings(TypedDict):
    """The sampler's settings, one dict (rust/py/src/settings.rs). Values are passed as given:
    the core parses the names and checks every rule; a bad one raises InvalidInputError. The
    keys the data decide may be left out (check_settings, before they are known)."""

    assignment: Any  # "gibbs" | "map"
    proposal: Any  # "full" | "informed"
    split_merge_pairs: Any  # "uniform" | "informed"
    fixed_length_scales: Any  # bool
    alpha: Any  # float | None (sampled)
    new_pattern_samples: Any  # int
    seed: Any  # int (its low 64 bits)
    n_threads: Any  # int | None (one per core)
    length_scale_fraction: Any  # float
    pattern_moments: Any  # bool
    split_merge: Any  # int: moves per sweep
    likelihood: NotRequired[str]  # "exact" | "hsgp"
    basis: NotRequired[_BasisTuple | None]
    params: NotRequired[_ParamTuple]
    length_scale_prior: NotRequired[tuple[float, float]]
    memory_budget: NotRequired[int | None]
    noise_prior: NotRequired[tuple[float, float] | None]
    noise_scope: NotRequired[str | None]  # "global" or "per_pattern"
    # the sticky prior: each frame's predecessor (-1: a run's first frame), ρ's Beta prior, a fixed ρ or None
    dynamics: NotRequired[tuple[list[int], tuple[float, float], float | None] | None]
    sampler: NotRequired[str]  # "collapsed" | "subcluster"
    heading_prior: NotRequired[tuple[float, float] | None]  # Gamma of w_h (radians); None: position only
    heading_harmonics: NotRequired[int | None]  # heading harmonics of an hsgp basis
    heading_counts: NotRequired[tuple[int, int] | None]  # position functions per axis of its heading blocks

def nearest_neighbour_sq(xy: NDArray[np.float64], offsets: NDArray[np.int64]) -> NDArray[np.float64]: ...
def check_settings(settings: _SamplerSettings) -> None: ...
def check_length_scale_prior(prior: tuple[float, float]) -> None: ...

@final
class Shard:
    """Consecutive frames of a data set (``first``: the number of the first among all frames),
    which answer a sharded chain's requests (rust/py/src/shard.rs)."""

    def __new__(
        cls,
        xy: NDArray[np.float64],
        v: NDArray[np.float64],
        offsets: NDArray[np.int64],
        first: int,
        h: NDArray[np.float64] | None = None,
    ) -> Self: ...
    def __len__(self) -> int: ...
    def handle(self, request: bytes) -> bytes: ...

@final
class Sampler:
    """A DP-GP chain, the collapsed Gibbs sampler or the sub-cluster sampler (settings key
    "sampler"; rust/py/src/sampler.rs); dpgp.DPGP wraps it."""

    def __new__(
        cls,
        xy: NDArray[np.float64],
        v: NDArray[np.float64],
        offsets: NDArray[np.int64],
        settings: _SamplerSettings,
        h: NDArray[np.float64] | None = None,
    ) -> Self: ...
    @staticmethod
    def over_shards(shards: list[Shard], settings: _SamplerSettings) -> Sampler: ...
    @staticmethod
    def over_link(
        sizes: list[int], serve: Callable[[list[tuple[int, bytes]]], list[bytes]], settings: _SamplerSettings
    ) -> Sampler: ...
    def n_shards(self) -> int: ...
    def initialize(self, init: str | None = None) -> None: ...
    def kind(self) -> str: ...
    def sweep(self) -> tuple[int, int, float, float]: ...
    def labels(self) -> NDArray[np.uintp]: ...
    def labels_held(self) -> bool: ...
    def label_table(self) -> NDArray[np.uint64] | None: ...
    def patterns(self) -> list[tuple[int, int, int, float, float]]: ...
    def heading_scales(self) -> list[float]: ...
    def alpha(self) -> float: ...
    def log_joint(self) -> float: ...
    def timings(self) -> dict[str, float]: ...
    def memory_bytes(self) -> int: ...
    def proposal_counts(self) -> tuple[int, int]: ...
    def split_merge_counts(self) -> tuple[int, int, int, int]: ...
    def noise_var(self) -> tuple[float, float]: ...
    def set_noise_var(self, noise_var: tuple[float, float]) -> None: ...
    def pattern_noise(self) -> list[tuple[float, float]]: ...
    def stickiness(self) -> float | None: ...
    def links(self) -> NDArray[np.bool_] | None: ...
    def set_links(self, links: NDArray[np.bool_], rho: float) -> None: ...
    def conditional_log_probs(self, i: int) -> list[float]: ...
    def training_log_likelihoods(self) -> list[list[float]]: ...
    def score_frames(
        self,
        xy: NDArray[np.float64],
        v: NDArray[np.float64],
        offsets: NDArray[np.int64],
        h: NDArray[np.float64] | None = None,
    ) -> tuple[list[list[float]], list[float]]: ...
    def posterior(
        self, slot: int, query_xy: NDArray[np.float64], h: NDArray[np.float64] | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
    def sweeps_done(self) -> int: ...
    def set_sweeps_done(self, sweeps: int) -> None: ...
    def set_state(
        self,
        labels: NDArray[np.int64],
        length_scales: NDArray[np.float64],
        alpha: float,
        noise_var: NDArray[np.float64] | None = None,
        heading_scales: list[float] | None = None,
    ) -> None: ...
    def regroup(
        self,
        group: NDArray[np.int64],
        length_scales: NDArray[np.float64],
        alpha: float,
        noise_var: NDArray[np.float64] | None = None,
        heading_scales: list[float] | None = None,
    ) -> None: ...
