"""The memory a build may take, checked before it starts.

A build that needs more memory than the machine has free would be killed by
the operating system part way, taking the interpreter with it; estimating it
first turns that into a ``MemoryError`` naming the sizes. The estimate is a
per-method upper bound in bytes per primitive (the structure it keeps plus the
build's scratch), from the resident memory measured while building a 203k
triangle mesh with each method: kept 10 (grid) to 330 (kd-tree) bytes per
triangle, scratch up to 230 more.
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["available_bytes", "require_memory", "cache_line_aligned"]

CACHE_LINE = 64


def available_bytes() -> int:
    """Memory the system can give this process without swapping (``MemAvailable`` on Linux,
    the free physical pages elsewhere)."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def require_memory(what: str, needed: float) -> None:
    """Raise ``MemoryError`` when ``what`` needs more than the available memory."""
    free = available_bytes()
    if needed > free:
        raise MemoryError(f"{what} needs about {needed / 2**30:,.1f} GiB of memory, and "
                          f"{free / 2**30:,.1f} GiB are available")


def cache_line_aligned(shape: tuple[int, int], dtype) -> np.ndarray:
    """A zeroed C-contiguous array whose first byte starts a 64-byte cache line, so that
    records of 32 or 64 bytes never straddle two lines."""
    dtype = np.dtype(dtype)
    size = int(np.prod(shape)) * dtype.itemsize
    raw = np.zeros(size + CACHE_LINE, dtype=np.uint8)
    offset = (-raw.ctypes.data) % CACHE_LINE
    return raw[offset:offset + size].view(dtype).reshape(shape)
