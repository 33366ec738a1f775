"""Process-wide allocator tuning for processes that allocate hundreds of MB over and over."""

from __future__ import annotations

import ctypes
import sys
from functools import cache

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_KEEP = 1 << 30


@cache
def keep_freed_memory() -> bool:
    """Serve large numpy arrays from glibc's heap and keep freed memory there.

    By default glibc maps every block over 32 MB afresh and unmaps it on free, so each new
    forest-sized array is page-faulted in again: on the VMs this runs on that costs about
    2.5 ms per MB, more than the arithmetic that fills the array. Keeping freed memory makes
    the second and later forests in a process cost only their arithmetic; the price is that
    the process keeps its peak size. Returns whether the setting took (glibc only).
    """
    if not sys.platform.startswith("linux"):
        return False
    try:  # the process's own symbols: glibc's mallopt without find_library's ldconfig run
        libc = ctypes.CDLL(None)
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, _KEEP)) and bool(
            libc.mallopt(_M_TRIM_THRESHOLD, _KEEP)
        )
    except (OSError, AttributeError):  # not glibc
        return False
