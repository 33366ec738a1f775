"""Scratch folders of job attempts, named after the process that owns them, so that those a
killed process left behind (a worker killed mid-job never runs its clean-up) are removed.

A scratch folder is ``<artifacts>/.<job id>.<pid>@<host>~<pid namespace>.<random>``, beside
the job folders (one file system: a finished file is renamed into place). :func:`sweep`
removes a folder when

- its owner ran on this host (same host name and pid namespace, where its pid means the same
  process) and no process has that pid any more; or
- its job is finished (or gone) and the folder has not changed for ``grace_s``: the owner
  ran elsewhere (another pod, a host that died), or its pid was reused. A live worker removes
  its own scratch when an attempt ends, so a finished job's folder that lingers is left over.

A folder of a queued or running job whose owner may be alive is never touched.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import tempfile
import time
from collections.abc import Callable, Iterable
from pathlib import Path

NAME = re.compile(
    r"^\.(?P<job>[0-9a-f]{32})\.(?:(?P<pid>\d+)@(?P<host>[^~/]+)~(?P<ns>\w+)\.)?[^.]+$"
)


def _pid_namespace() -> str:
    """The pid namespace's inode (containers on one kernel each have their own)."""
    try:
        return re.sub(r"\D", "", os.readlink("/proc/self/ns/pid")) or "0"
    except OSError:
        return "0"


HOST = socket.gethostname()
PID_NS = _pid_namespace()


def owner() -> str:
    """This process, as scratch folder names write it (read at call time: forks differ)."""
    return f"{os.getpid()}@{HOST}~{PID_NS}"


def make(root: Path, job_id: str) -> Path:
    """A new scratch folder of ``job_id`` owned by this process."""
    root.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f".{job_id}.{owner()}.", dir=root))


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: it exists
        return True
    return True


def _owner_gone(match: re.Match[str]) -> bool:
    if match["pid"] is None or match["host"] != HOST or match["ns"] != PID_NS:
        return False  # cannot tell from here
    return not _alive(int(match["pid"]))


def sweep(
    root: Path,
    unfinished: Callable[[Iterable[str]], set[str]] | None = None,
    grace_s: float = 600.0,
) -> list[Path]:
    """Remove left-over scratch folders under ``root`` (see the module's rules); answers what
    was removed. ``unfinished(job ids)`` says which of those jobs are queued or running (the
    job store); without it only folders of dead local owners go."""
    if not root.is_dir():
        return []
    found: list[tuple[Path, re.Match[str]]] = []
    for entry in root.iterdir():
        match = NAME.match(entry.name)
        if match is not None and entry.is_dir() and not entry.is_symlink():
            found.append((entry, match))
    doomed = [path for path, match in found if _owner_gone(match)]
    rest = [(path, match) for path, match in found if path not in doomed]
    if unfinished is not None and rest:
        now = time.time()
        old = []
        for path, match in rest:
            try:
                if now - path.stat().st_mtime > grace_s:
                    old.append((path, match["job"]))
            except FileNotFoundError:  # its owner removed it meanwhile
                continue
        running = unfinished({job for _, job in old}) if old else set()
        doomed += [path for path, job in old if job not in running]
    for path in doomed:
        shutil.rmtree(path, ignore_errors=True)
    return doomed
