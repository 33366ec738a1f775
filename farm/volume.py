"""The data volume (the artifacts folder's file system): how much room it has, and telling a
write that failed for want of room from any other failure.

A full volume is no fault of the job and no passing trouble that a retry a second later
cures: the job fails once with :data:`FULL` (no retries, nothing re-sent), and ``/readyz``
says so until room is made.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

FULL = "data volume full"
"""The error of a job (and the answer to an upload) whose write found no room."""
_NO_ROOM = (errno.ENOSPC, errno.EDQUOT)
# how the same failure reads when it comes through C++ (pxr's Tf errors) or a wrapped message
_NO_ROOM_TEXT = tuple(os.strerror(e) for e in _NO_ROOM)


def is_full(exc: BaseException) -> bool:
    """``exc``, or an exception it was raised from or while handling, is a write that found
    no room (ENOSPC, EDQUOT; also as the text pxr's C++ errors carry)."""
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        seen.add(id(cur))
        if isinstance(cur, OSError) and cur.errno in _NO_ROOM:
            return True
        text = str(cur)
        if any(t in text for t in _NO_ROOM_TEXT):
            return True
        cur = cur.__cause__ or cur.__context__
    return False


def free_bytes(folder: Path) -> int:
    """Bytes an unprivileged writer may still use on ``folder``'s file system (the nearest
    existing folder above it when it is not made yet)."""
    path = Path(folder)
    while not path.exists() and path != path.parent:
        path = path.parent
    st = os.statvfs(path)
    return st.f_bavail * st.f_frsize
