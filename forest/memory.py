"""Process-wide allocator tuning for processes that allocate hundreds of MB over and over."""

from __future__ import annotations

import ctypes
import sys
from functools import cache

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8
_KEEP = 1 << 30


@cache
def keep_freed_memory() -> bool:
    """Serve large numpy arrays from glibc's heap and keep freed memory there.

    By default glibc maps every block over 32 MB afresh and unmaps it on free, so each new
    forest-sized array is page-faulted in again: on the VMs this runs on that costs about
    2.5 ms per MB, more than the arithmetic that fills the array. Keeping freed memory makes
    the second and later forests in a process cost only their arithmetic; the price is that
    the process keeps its peak size. Returns whether the setting took (glibc only).

    One arena for every thread: generation's side threads (new ones for each forest) each
    kept their own arena's freed memory, which the next forest's threads did not reuse, so a
    tiled forest grew tile after tile (900 oaks in 9 tiles peaked 41 % over one tile; with
    one arena 14 %, the rest the CLI's loop holding the last tile). numpy's few large blocks
    make the shared lock's cost nothing.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:  # the process's own symbols: glibc's mallopt without find_library's ldconfig run
        libc = ctypes.CDLL(None)
        return (
            bool(libc.mallopt(_M_MMAP_THRESHOLD, _KEEP))
            and bool(libc.mallopt(_M_TRIM_THRESHOLD, _KEEP))
            and bool(libc.mallopt(_M_ARENA_MAX, 1))
        )
    except (OSError, AttributeError):  # not glibc
        return False
