"""The machine's memory, for the fit's memory budget."""

from __future__ import annotations

import os
import re

from .exceptions import InvalidInputError

#: Share of the memory available at the start of a fit that its patterns may hold by default.
DEFAULT_MEMORY_SHARE = 0.5

_UNITS = {"": 1, "b": 1, "kb": 10**3, "mb": 10**6, "gb": 10**9, "tb": 10**12, "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40}


def available_memory() -> int | None:
    """Bytes of memory this process can still allocate: the least of what the system has
    available (Linux ``MemAvailable``), what its cgroup allows (a container's memory limit,
    which ``MemAvailable`` does not show) and what its address-space limit (``ulimit -v``)
    leaves; ``None`` where none of them is known."""
    known = [b for b in (_system_available(), _cgroup_available(), _address_space_available()) if b is not None]
    return min(known) if known else None


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


def default_memory_budget() -> int | None:
    """Half of the memory available now; ``None`` (no limit) where that is unknown."""
    avail = available_memory()
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
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 1 or value != value or value == float("inf"):
        raise InvalidInputError(f"{name} must be a positive number of bytes or a size such as '4GB', got {value!r}")
    return int(value)
