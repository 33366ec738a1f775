"""A process's peak resident memory over a stretch of its run: Linux's high-water mark
(``VmHWM``) reset by writing 5 to ``/proc/self/clear_refs``, so a bench can give the peak of
one step (a scene's write) apart from what ran before it in the same process."""

from __future__ import annotations

import resource
from pathlib import Path

_STATUS = Path("/proc/self/status")
_CLEAR_REFS = Path("/proc/self/clear_refs")


def reset_peak() -> bool:
    """Start a new high-water mark at the present RSS; False where the system has none to
    reset (then :func:`peak_bytes` is the process's peak since it started)."""
    try:
        _CLEAR_REFS.write_text("5")
        return True
    except OSError:
        return False


def peak_bytes() -> int:
    """The peak RSS in bytes since the last :func:`reset_peak` (or since the start)."""
    try:
        for line in _STATUS.read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # kB on Linux
