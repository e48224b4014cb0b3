"""dpgp.partition against brute force: expected Binder and VI losses by their pairwise and
entropy definitions, the SALSO search against enumeration of every partition of a few items,
the similarity matrix against the N×N×draws comparison, and the credible ball's definition."""

import itertools

import numpy as np
import pytest

from dpgp import InvalidInputError, ShapeError, partition


def _partitions(n):
    """Every partition of n items as restricted growth strings (Bell(n) of them)."""

    def grow(prefix, top):
        if len(prefix) == n:
            yield np.array(prefix)
            return
        for k in range(top + 2):
            yield from grow(prefix + [k], max(top, k))

    yield from grow([0], 0)


def _binder_pairs(c, d):
    n = len(c)
    pairs = list(itertools.combinations(range(n), 2))
    return np.mean([sum((c[i] == c[j]) != (s[i] == s[j]) for i, j in pairs) / len(pairs) for s in d])


def _entropy(labels):
    _, counts = np.unique(labels, return_counts=True, axis=0)
    p = counts / counts.sum()
    return -(p * np.log2(p)).sum()


def _vi_entropies(c, d):
    return np.mean([2 * _entropy(np.column_stack([c, s])) - _entropy(c) - _entropy(s) for s in d])


def _noisy_draws(rng, n, s):
    base = rng.integers(0, 3, size=n)
    return np.where(rng.random((s, n)) < 0.3, rng.integers(0, 4, size=(s, n)), base)


def test_expected_losses_match_their_definitions():
    rng = np.random.default_rng(1)
    for _ in range(5):
        n = int(rng.integers(3, 7))
        d = _noisy_draws(rng, n, int(rng.integers(1, 9)))
        for c in itertools.islice(_partitions(n), 40):
            assert partition.expected_loss(c, d, "binder") == pytest.approx(_binder_pairs(c, d), abs=1e-12)
            assert partition.expected_loss(c, d, "vi") == pytest.approx(_vi_entropies(c, d), abs=1e-12)
    # labels are names: renaming clusters changes nothing
    assert partition.expected_loss([5, 5, 9], [[0, 1, 1]], "vi") == partition.expected_loss(
        [0, 0, 1], [[7, 3, 3]], "vi"
    )


@pytest.mark.parametrize("loss", ["binder", "vi"])
def test_salso_finds_the_minimum_found_by_enumeration(loss):
    rng = np.random.default_rng(7)
    for trial in range(12):
        n = int(rng.integers(4, 8))
        d = _noisy_draws(rng, n, int(rng.integers(2, 15)))
        values = [partition.expected_loss(c, d, loss) for c in _partitions(n)]
        est = partition.salso(d, loss, n_runs=4, seed=trial)
        assert est.expected_loss == pytest.approx(min(values), abs=1e-12)
        assert est.expected_loss == pytest.approx(partition.expected_loss(est.labels, d, loss), abs=1e-12)
        assert est.loss == loss and len(est) == n


def test_salso_recovers_a_clear_partition_and_numbers_clusters_by_size():
    rng = np.random.default_rng(3)
    truth = np.repeat([2, 0, 1], [50, 30, 20])
    draws = np.array([np.where(rng.random(100) < 0.05, rng.integers(0, 6, 100), truth) for _ in range(60)])
    for loss in partition.LOSSES:
        est = partition.salso(draws, loss, n_runs=3, seed=0)
        np.testing.assert_array_equal(est.labels, np.repeat([0, 1, 2], [50, 30, 20]))
        assert est.n_clusters == 3
    # deterministic given the seed
    a, b = (partition.salso(draws, "vi", n_runs=2, seed=5) for _ in range(2))
    np.testing.assert_array_equal(a.labels, b.labels)


def test_similarity_blockwise_equals_the_direct_computation():
    rng = np.random.default_rng(0)
    d = rng.integers(0, 4, size=(23, 130))
    direct = (d[:, :, None] == d[:, None, :]).mean(axis=0)
    for block in (1, 7, 64, 500):
        s = partition.similarity(d, block=block)
        assert s.dtype == np.float32 and s.shape == (130, 130)
        np.testing.assert_allclose(s, direct, atol=1e-6)
    np.testing.assert_allclose(partition.similarity(d, rows=[5, 0, 129], block=2), direct[[5, 0, 129]], atol=1e-6)
    np.testing.assert_allclose(np.diag(partition.similarity(d)), 1.0)


def test_credible_ball_holds_the_level_of_draws_and_its_bounds_lie_inside():
    rng = np.random.default_rng(4)
    d = _noisy_draws(rng, 12, 40)
    est = partition.salso(d, "vi", n_runs=2)
    ball = partition.credible_ball(est.labels, d, "vi", level=0.9)
    dist = partition.losses(est.labels, d, "vi")
    assert np.mean(dist <= ball.radius + 1e-12) >= 0.9
    assert np.mean(dist < ball.radius - 1e-12) < 0.9  # the smallest such radius
    for bound in (ball.horizontal, ball.upper_vertical, ball.lower_vertical):
        assert partition.expected_loss(est.labels, [bound], "vi") <= ball.radius + 1e-12
    k = lambda c: len(np.unique(c))  # noqa: E731
    assert k(ball.upper_vertical) <= k(ball.lower_vertical)
    assert partition.expected_loss(est.labels, [ball.horizontal], "vi") == pytest.approx(ball.radius)


def test_bad_input_raises_typed_errors():
    with pytest.raises(InvalidInputError, match="loss must be one of"):
        partition.salso([[0, 1]], "rand")
    with pytest.raises(ShapeError, match="draws, items"):
        partition.similarity([0, 1, 2])
    with pytest.raises(ShapeError, match="3 items"):
        partition.expected_loss([0, 1], [[0, 1, 1]])
    with pytest.raises(InvalidInputError, match="integers"):
        partition.salso([[0.5, 1.0]])
    with pytest.raises(InvalidInputError, match="level"):
        partition.credible_ball([0, 0], [[0, 1]], level=1.5)


_MEMORY = """
import resource, numpy as np
from dpgp import partition
rng = np.random.default_rng(0)
n, s = 10_000, 200
base = rng.integers(0, 100, size=n)
draws = np.where(rng.random((s, n)) < 0.1, rng.integers(0, 150, size=(s, n)), base).astype(np.int32)
sim = partition.similarity(draws)
i, j = 17, int(np.flatnonzero(base == base[17])[1])
assert abs(sim[i, j] - (draws[:, i] == draws[:, j]).mean()) < 1e-6 and sim[i, j] == sim[j, i]
# VmHWM is this program's own peak (KiB); ru_maxrss on Linux keeps the forking parent's across
# exec (a large pytest process would be counted), so it is the fallback (macOS: bytes).
try:
    print([l for l in open("/proc/self/status") if l.startswith("VmHWM")][0].split()[1])
except OSError:
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def test_similarity_of_10000_items_and_200_draws_fits_in_1_gb():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _MEMORY], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    peak_mb = int(out.stdout.split()[-1]) / (
        2**20 if sys.platform == "darwin" else 2**10
    )  # bytes on macOS, KiB elsewhere
    assert peak_mb <= 1024, f"peak RSS {peak_mb:.0f} MB"
