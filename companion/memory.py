"""Giving memory back: what a large input (a map of tens of megabytes, or an
oversized message refused after Zenoh reassembled it) leaves in glibc's
allocator would otherwise stay in the service's resident memory for good.

* :func:`fix_mmap_threshold`: glibc raises its mmap threshold after each large
  block it frees (up to 32 MB), so the next large blocks come from the heap and
  stay there; fixed at 128 KiB, every large block is mapped and unmapped.
* :func:`trim`: ``malloc_trim(0)`` returns the free pages of every arena (Zenoh's
  receiving threads each have one) to the system. It takes each arena's lock in
  turn, so the service calls it from a thread, at most every few seconds, and
  only after a large input (:class:`companion.network.inputs.Inputs`).

Measured with ``/proc`` (``sitl.footprint``): see ``docs/service.md``.
On a C library without these calls (musl, macOS) both do nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util

#: glibc's ``M_MMAP_THRESHOLD`` (malloc.h).
_M_MMAP_THRESHOLD = -3
#: Blocks this large or larger are mapped, and unmapped when freed.
MMAP_THRESHOLD = 128 * 1024

try:
    _libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    _mallopt = _libc.mallopt
    _malloc_trim = _libc.malloc_trim
except (OSError, AttributeError):  # not glibc
    _mallopt = _malloc_trim = None


def fix_mmap_threshold() -> bool:
    """Fix glibc's mmap threshold (the whole process, its threads too)."""
    return bool(_mallopt is not None and _mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD))


def trim() -> bool:
    """Return free heap pages to the system; True if any were."""
    return bool(_malloc_trim is not None and _malloc_trim(0))
