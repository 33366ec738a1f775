"""The artifact store: one folder per job under the (shared) artifacts folder; files appear
under their final name only once complete (temporary name, then rename)."""

from __future__ import annotations

import re
import shutil
from collections.abc import Callable, Iterable
from pathlib import Path

from farm import scratch as scratch_folders
from forest.atomic import replaced_when_written

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
JOB_ID = re.compile(r"^[0-9a-f]{32}$")


class ArtifactStore:
    def __init__(self, root: Path) -> None:
        self.root = Path(root)

    def folder(self, job_id: str) -> Path:
        if not JOB_ID.match(job_id):
            raise ValueError(f"bad job id {job_id!r}")
        return self.root / job_id

    def path(self, job_id: str, name: str) -> Path | None:
        """The finished artifact, or None (bad name, missing)."""
        if not NAME.match(name) or not JOB_ID.match(job_id):
            return None
        p = self.folder(job_id) / name
        return p if p.is_file() else None

    def scratch(self, job_id: str) -> Path:
        """A private temporary folder beside the job's folder (same file system: rename works),
        named after this process so that a sweep removes it if the process dies with it
        (:mod:`farm.scratch`)."""
        if not JOB_ID.match(job_id):
            raise ValueError(f"bad job id {job_id!r}")
        return scratch_folders.make(self.root, job_id)

    def sweep_scratch(self, unfinished: Callable[[Iterable[str]], set[str]] | None) -> list[Path]:
        """Remove scratch folders that dead processes left (:func:`farm.scratch.sweep`)."""
        return scratch_folders.sweep(self.root, unfinished)

    def publish(self, job_id: str, src: Path, name: str) -> Path:
        """Move a finished file into place atomically; an existing artifact of the same name
        (an earlier attempt's identical output) is replaced."""
        if not NAME.match(name):
            raise ValueError(f"bad artifact name {name!r}")
        dest = self.folder(job_id)
        dest.mkdir(parents=True, exist_ok=True)
        # staged in a private folder in dest (a copy there when src is on another file
        # system), then one rename: no other file is touched, no half file ever visible
        with replaced_when_written(dest / name) as tmp:
            shutil.move(src, tmp)
        return dest / name

    def remove(self, job_id: str) -> None:
        """Delete the job's folder and every file in it (none there: nothing to do)."""
        shutil.rmtree(self.folder(job_id), ignore_errors=True)

    def size(self, job_id: str, name: str) -> int:
        p = self.path(job_id, name)
        return p.stat().st_size if p is not None else 0
