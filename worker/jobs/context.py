"""What a task kind is: a function of a :class:`JobContext` (run in the job's child process)
to an :class:`Outcome`."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from farm.artifacts import ArtifactStore
from worker.jobs.scene_guard import UploadCaps


@dataclass
class JobContext:
    """What a task kind gets (in the job's child process): its parameters, a scratch folder
    and a way to report progress, which the supervising worker records with its heartbeat.
    Cancel needs no check: the worker kills the child."""

    job_id: str
    params: dict[str, Any]
    scratch: Path
    artifacts: ArtifactStore
    stage: str = "started"
    progress: float = 0.0
    on_report: Callable[[str, float], None] | None = None
    upload_caps: UploadCaps = field(default_factory=UploadCaps)

    def report(self, stage: str, fraction: float) -> None:
        self.stage, self.progress = stage, fraction
        if self.on_report is not None:
            self.on_report(stage, fraction)


@dataclass(frozen=True)
class Outcome:
    files: dict[str, Path]  # artifact name -> finished file in the scratch folder
    result: dict[str, Any]


class TaskKind(Protocol):
    def __call__(self, ctx: JobContext) -> Outcome: ...
