"""Job kinds with a test's behaviour added, for worker processes the service tests start
themselves (``Server(..., hooks=...)``, :func:`main`): every kind's first attempt pausing (a
window in which a test kills or cancels the job while it runs), the render kind holding its
GIL in one C call as it starts drawing (as a long GL draw does). The worker's own code has
none of this: :func:`main` wraps the kinds of the registry, then runs the worker command.

Kinds run in a child process that imports them by name: everything here is a module
function (a ``functools.partial`` of them pickles by name too)."""

from __future__ import annotations

import ctypes
import json
import os
import time
from functools import partial
from pathlib import Path

from worker.jobs.context import JobContext, Outcome, TaskKind

HOOKS_ENV = "TEST_JOB_HOOKS"  # not a FOREST_ setting: nothing of the farm reads it
"""JSON of the hooks a worker started by :func:`main` adds: ``pause_first_s`` (each job's
first attempt pauses this long, at stage ``test-pause``), ``hold_gil_s`` (a render holds its
GIL this long when it starts drawing), ``pause_chunk_s`` (the first attempt of a render's
second frame chunk, the one from frame 8, pauses this long: a window to kill its worker)."""


def hold_gil(seconds: float) -> None:
    """A C call that keeps the GIL (``usleep`` through ``PyDLL``), as a long GL draw does."""
    ctypes.PyDLL(None).usleep(int(seconds * 1e6))


def pause_first_attempt(kind: TaskKind, seconds: float, marks: str, ctx: JobContext) -> Outcome:
    """``kind``, after a pause on the job's first attempt (the parent heartbeats and reads
    cancel meanwhile); a mark in the folder ``marks`` tells a later attempt."""
    mark = Path(marks) / ctx.job_id
    if not mark.exists():
        mark.parent.mkdir(parents=True, exist_ok=True)
        mark.touch()
        ctx.report("test-pause", 0.0)
        time.sleep(seconds)
        ctx.report("started", 0.0)
    return kind(ctx)


def hold_gil_drawing(kind: TaskKind, seconds: float, ctx: JobContext) -> Outcome:
    """``kind`` (a render), holding the GIL for ``seconds`` when it reports the ``render``
    stage."""
    report = ctx.on_report

    def on_report(stage: str, fraction: float) -> None:
        if report is not None:
            report(stage, fraction)
        if stage == "render":
            hold_gil(seconds)

    ctx.on_report = on_report
    return kind(ctx)


def pause_second_chunk(kind: TaskKind, seconds: float, marks: str, ctx: JobContext) -> Outcome:
    """``kind`` (``render_chunk``), pausing the first attempt of the chunk from frame 8."""
    if int(ctx.params["chunk"][0]) == 8:
        return pause_first_attempt(kind, seconds, marks, ctx)
    return kind(ctx)


def add_hooks(kinds: dict[str, TaskKind], hooks: dict[str, float], marks: Path) -> None:
    """Wrap the kinds of ``kinds`` in place with ``hooks`` (:data:`HOOKS_ENV`)."""
    if "hold_gil_s" in hooks:
        kinds["render"] = partial(hold_gil_drawing, kinds["render"], hooks["hold_gil_s"])
    if "pause_chunk_s" in hooks:
        kinds["render_chunk"] = partial(
            pause_second_chunk, kinds["render_chunk"], hooks["pause_chunk_s"], str(marks)
        )
    if "pause_first_s" in hooks:
        for name, kind in list(kinds.items()):
            kinds[name] = partial(pause_first_attempt, kind, hooks["pause_first_s"], str(marks))


def main() -> None:
    """``python -c 'import job_hooks; job_hooks.main()' -Q ...``: ``forest worker`` with the
    hooks of :data:`HOOKS_ENV` (marks of paused jobs in ``<data>/run/paused``)."""
    from worker.jobs.main import worker_command
    from worker.jobs.registry import KINDS

    marks = Path(os.environ["FOREST_DATA_DIR"]) / "run" / "paused"
    add_hooks(KINDS, json.loads(os.environ.get(HOOKS_ENV, "{}")), marks)
    worker_command(prog_name="job_hooks")
