"""Heap settings for long replays (glibc; elsewhere nothing is done).

A replay allocates large arrays that live for the whole run (IMU columns, brackets, scoring)
between many chunk-sized temporaries. glibc raises its threshold for serving an allocation
from its own mapping each time a large block is freed, after which large arrays come from
the heap; those freed among live ones stay resident. A fixed threshold keeps every large
array in its own mapping, returned to the system when freed.
"""

from __future__ import annotations

import ctypes
import ctypes.util

MMAP_THRESHOLD_BYTES = 1 << 20
_M_MMAP_THRESHOLD = -3  # mallopt parameter numbers (malloc.h)


def _libc():
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
    except OSError:
        return None
    return libc if libc is not None and hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim") else None


def map_large_arrays(threshold_bytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Serve allocations from this size on from their own mappings (whether it could be set)."""
    libc = _libc()
    return bool(libc and libc.mallopt(_M_MMAP_THRESHOLD, int(threshold_bytes)))


def trim() -> None:
    """Give the heap's free memory back to the system (between a replay's modes)."""
    libc = _libc()
    if libc:
        libc.malloc_trim(0)
