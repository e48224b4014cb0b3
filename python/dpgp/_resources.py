"""The machine's memory, for the fit's memory budget."""

from __future__ import annotations

import functools
import os
import re

from .exceptions import InvalidInputError

#: Largest budget (bytes) the core takes; larger ones limit nothing and are taken as this.
MAX_BUDGET = 2**63 - 1
#: Share of the memory available at the start of a fit that its patterns may hold by default.
DEFAULT_MEMORY_SHARE = 0.5

_UNITS = {
    "": 1,
    "b": 1,
    "kb": 10**3,
    "mb": 10**6,
    "gb": 10**9,
    "tb": 10**12,
    "kib": 2**10,
    "mib": 2**20,
    "gib": 2**30,
    "tib": 2**40,
}


def available_memory(n_threads: int | None = 1) -> int | None:
    """Bytes of memory this process can still allocate: the least of what the system has
    available (Linux ``MemAvailable``), what its cgroup allows (a container's memory limit,
    which ``MemAvailable`` does not show) and what its address-space limit (``ulimit -v``)
    leaves once the ``n_threads`` worker threads hold their reservations
    (:func:`thread_reservation`); ``None`` where none of them is known."""
    space = _address_space_available()
    if space is not None:
        space = max(space - threads_reservation(n_threads), 0)
    known = [b for b in (_system_available(), _cgroup_available(), space) if b is not None]
    return min(known) if known else None


# --- what every worker thread reserves --------------------------------------------------------
# faer 0.24's matrix products above 16³ flops run private-gemm-x86, which keeps a thread-local
# packing arena of 2 × L3 bytes (one L3 for each packed operand), allocated on a thread's first
# product and kept for its life. L3 there is the per-core share of the L3 (its size over the CPUs
# sharing it), times the CPUs sharing an L1, times the physical cores: about the machine's whole
# L3, at least 2 MiB and 4 × L2 (private-gemm-x86 0.1, cache.rs and lib.rs). Most of it is never
# touched, so it costs address space, not memory: an address-space limit (``ulimit -v``) counts
# all of it. glibc also reserves a malloc arena of 64 MiB of address space for a thread that
# allocates, and each thread has its stack.
_MALLOC_ARENA = 64 * 2**20
_STACK = 8 * 2**20
_PAGE = 4096
_GEMM_MIN = (32 * 2**10, 256 * 2**10, 2 * 2**20)  # private-gemm-x86's x86 defaults (L1, L2, L3)


def gemm_arena_bytes() -> int:
    """Bytes of address space faer's x86 GEMM reserves per thread that runs a product, derived
    from ``/sys/devices/system/cpu`` as private-gemm-x86 derives it (its defaults elsewhere)."""
    l1, l2, l3 = _cache_sizes()
    l1 = max(l1, _GEMM_MIN[0])
    l2 = max(l2, _GEMM_MIN[1], 4 * l1)
    l3 = max(l3, _GEMM_MIN[2], 4 * l2)
    return 2 * (-(-l3 // _PAGE) * _PAGE)


@functools.lru_cache(maxsize=8)
def _cache_sizes(root: str = "/sys/devices/system/cpu") -> tuple[int, int, int]:
    """(L1 data, L2, L3) bytes as private-gemm-x86 reads them: each level's size over the CPUs
    sharing it, L1-sharing CPUs counted in, L3 times the physical cores; 0 where unknown."""
    import glob

    sizes, l1_shared = [0, 0, 0], 1
    for index in sorted(glob.glob(os.path.join(root, "cpu[0-9]*", "cache", "index[0-9]*"))):
        try:
            kind = _read_text(os.path.join(index, "type"))
            level = int(_read_text(os.path.join(index, "level")))
            size = _parse_cache_size(_read_text(os.path.join(index, "size")))
            shared = _count_cpus(_read_text(os.path.join(index, "shared_cpu_list")))
        except (OSError, ValueError):
            continue
        if kind not in ("Data", "Unified") or not 1 <= level <= 3 or shared < 1:
            continue
        if level == 1:
            l1_shared = shared
        sizes[level - 1] = max(sizes[level - 1], size // shared)
    sizes = [s * l1_shared for s in sizes]
    sizes[2] *= _physical_cores()
    return sizes[0], sizes[1], sizes[2]


def _read_text(path: str) -> str:
    with open(path) as fh:
        return fh.read().strip()


def _parse_cache_size(text: str) -> int:
    units = {"K": 2**10, "M": 2**20, "G": 2**30}
    return int(text[:-1]) * units[text[-1]] if text[-1:] in units else int(text)


def _count_cpus(cpu_list: str) -> int:
    n = 0
    for item in cpu_list.split(","):
        lo, _, hi = item.partition("-")
        n += int(hi) - int(lo) + 1 if hi else 1
    return n


@functools.lru_cache(maxsize=1)
def _physical_cores() -> int:
    """Distinct (physical id, core id) pairs of /proc/cpuinfo, as the num_cpus crate counts."""
    try:
        pairs, phys = set(), None
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                if key.strip() == "physical id":
                    phys = value.strip()
                elif key.strip() == "core id":
                    pairs.add((phys, value.strip()))
        return len(pairs) or (os.cpu_count() or 1)
    except OSError:
        return os.cpu_count() or 1


def worker_threads(n_threads: int | None) -> int:
    """The threads a fit's pool runs (``None``: one per CPU this process may use, as rayon)."""
    if n_threads is not None:
        return int(n_threads)
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def thread_reservation() -> int:
    """Address space one worker thread may reserve: faer's GEMM arena, a malloc arena, a stack."""
    return gemm_arena_bytes() + _MALLOC_ARENA + _STACK


def threads_reservation(n_threads: int | None) -> int:
    """What the pool's threads and the thread that drives them may reserve."""
    return (worker_threads(n_threads) + 1) * thread_reservation()


def check_thread_reservations(n_threads: int | None) -> None:
    """Refuse, before any work, a fit whose worker threads' reservations do not fit in the
    address space left (``ulimit -v``): otherwise the first large product aborts the interpreter
    ("memory allocation of ... bytes failed" inside faer's GEMM)."""
    from .exceptions import MemoryBudgetError

    space = _address_space_available()
    need = threads_reservation(n_threads)
    if space is not None and need > space:
        threads = worker_threads(n_threads)
        raise MemoryBudgetError(
            f"the address-space limit (ulimit -v) leaves {space / 2**20:.0f} MiB, but {threads} worker thread(s) and their "
            f"driver reserve {need / 2**20:.0f} MiB before any pattern exists ({thread_reservation() / 2**20:.0f} MiB each: "
            f"faer's matrix-product arena of twice the L3 cache, {gemm_arena_bytes() / 2**20:.0f} MiB, a malloc arena and a "
            "stack); pass n_threads=1 or raise the limit"
        )


def _system_available() -> int | None:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


#: (limit, usage) files of the cgroup memory controller, v2 then v1.
_CGROUP_FILES = (
    ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
    ("/sys/fs/cgroup/memory/memory.limit_in_bytes", "/sys/fs/cgroup/memory/memory.usage_in_bytes"),
)


def _cgroup_available() -> int | None:
    """The cgroup's memory limit less its usage; ``None`` without a limit ("max", or v1's huge
    sentinel) or a controller."""
    for limit_file, usage_file in _CGROUP_FILES:
        try:
            with open(limit_file) as fh:
                limit = fh.read().strip()
            if limit == "max" or int(limit) >= 1 << 60:
                return None
            with open(usage_file) as fh:
                return max(int(limit) - int(fh.read().strip()), 0)
        except (OSError, ValueError):
            continue
    return None


def _address_space_available() -> int | None:
    """The soft address-space limit (``RLIMIT_AS``) less the address space in use."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft == resource.RLIM_INFINITY:
            return None
        with open("/proc/self/status") as fh:
            used = next(int(line.split()[1]) * 1024 for line in fh if line.startswith("VmSize:"))
        return max(soft - used, 0)
    except (ImportError, OSError, ValueError, StopIteration):
        return None


def default_memory_budget(n_threads: int | None = 1) -> int | None:
    """Half of the memory available now to a fit on ``n_threads`` worker threads (their
    reservations taken out); ``None`` (no limit) where that is unknown."""
    avail = available_memory(n_threads)
    return None if avail is None else int(avail * DEFAULT_MEMORY_SHARE)


def parse_bytes(name: str, value: object) -> int | None:
    """``None``, a positive number of bytes, or a string such as ``"4GB"`` / ``"512 MiB"``."""
    if value is None:
        return None
    if isinstance(value, str):
        m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:e[0-9]+)?)\s*([a-zA-Z]*)\s*", value)
        unit = m.group(2).lower() if m else None
        if m is None or unit not in _UNITS:
            raise InvalidInputError(f"{name} must be a number of bytes or a size such as '4GB', got {value!r}")
        value = float(m.group(1)) * _UNITS[unit]
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not value >= 1
        or value != value
        or value == float("inf")
    ):
        raise InvalidInputError(f"{name} must be a positive number of bytes or a size such as '4GB', got {value!r}")
    # Past 2^63 - 1 bytes (8 EiB, more than any machine) a budget limits nothing: the core takes a u64.
    return int(min(value, MAX_BUDGET))
