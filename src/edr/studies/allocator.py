"""Keep big freed buffers in the process, so tensors of tens of MB do not page-fault on every call.

glibc returns allocations above a (moving) threshold to the kernel when they are freed; the next
tensor of that size then pays a page fault per 4 KiB on first write, which can cost more than the
computation of a fast representation. Benchmarks opt in (``edr-bench`` does by default); it is
the same trade-off as running PyTorch with jemalloc or tcmalloc.
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameter numbers
M_MMAP_THRESHOLD = -3


def keep_freed_memory(limit_bytes: int = 1 << 30) -> bool:
    """Serve allocations below ``limit_bytes`` from the heap and never trim it; False if not glibc."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, limit_bytes)) and bool(
        mallopt(M_TRIM_THRESHOLD, 2**31 - 1)
    )
