"""Frame chunks of a render job: a render of more than ``FOREST_RENDER_CHUNK_FRAMES`` frames
(:attr:`FarmSettings.render_chunk_frames`, 8) fans out into ``render_chunk`` jobs of that many
frames each, and once every chunk completed the render job assembles ``preview.png``,
``metrics.json`` and the clip from their frames. The pattern is the tiled forest's
(:mod:`farm.tiles`): the chunk rows are the render job's children (``parent``), written held
and sent by the fair window (:mod:`farm.fair`) to any render worker of the job's pool, each
retried alone; the render job does not wait in a worker but goes back to the queue and looks
at its chunks again in :data:`POLL_S` (as Celery's chord_unlock polls a group).

A chunk draws its frames as the whole run draws them
(:func:`worker.render.render_file.render_chunk`: the same camera, warm-up and palette sample
per frame index) and writes each as
``frame_<k>.png`` into the render job's artifacts; the join reads them back in order, so a
chunked render's files equal one worker's, pixel for pixel. The frame files go once the render
job has completed. What a chunk runs and how the clip is encoded are the worker's
(:mod:`worker.jobs.chunk`).
"""

from __future__ import annotations

import hashlib
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from farm.artifacts import ArtifactStore
from farm.dispatch import Dispatcher
from farm.fair import CHUNK_KIND
from farm.family import look, write_children
from farm.settings import FarmSettings
from farm.store import Claim, JobStore
from schemas.jobs import JobState

POLL_S = 0.5  # how often a chunked render job looks at its chunks

ChunkResults = list[tuple[dict[str, Any], dict[str, Any] | None]]
Assemble = Callable[
    [str, dict[str, Any], ChunkResults, Path], tuple[dict[str, Path], dict[str, Any]]
]
"""The worker's join: ``(render job id, its params, (params, result) of every chunk in frame
order, a scratch folder)`` -> the render job's files (name -> path in the scratch folder) and
result."""


def chunk_ranges(frames: int, size: int) -> list[tuple[int, int]]:
    """``[start, stop)`` of each chunk of ``frames`` measured frames, ``size`` at most each."""
    return [(a, min(a + size, frames)) for a in range(0, frames, size)]


def chunk_job_id(parent: str, index: int) -> str:
    """The job id of chunk ``index`` of a render job."""
    return hashlib.md5(f"{parent}:chunk:{index}".encode(), usedforsecurity=False).hexdigest()


def is_chunked(kind: str, params: dict[str, Any], settings: FarmSettings) -> bool:
    """A render job that joins frame chunks rather than rendering itself: more frames asked
    than one chunk holds (a clip of the whole wind loop, ``frames`` 1, is one job)."""
    return kind == "render" and int(params.get("frames", 1)) > settings.render_chunk_frames


def _chunk_name(params: dict[str, Any]) -> str:
    a, b = params.get("chunk", ["?", "?"])
    return f"frames {a}-{b}"


def set_up(store: JobStore, claim: Claim, settings: FarmSettings, made: int) -> str | None:
    """Write the chunk rows not written yet (held; the render job's lease heartbeated between
    batches); None when done, else what happened (canceled, lost)."""
    job_id, params = claim.job_id, claim.params
    ranges = chunk_ranges(int(params["frames"]), settings.render_chunk_frames)
    pool = params.get("pool")
    rows = [
        (chunk_job_id(job_id, n), {"parent": job_id, "chunk": [a, b], "pool": pool})
        for n, (a, b) in enumerate(ranges)
    ]
    return write_children(store, claim, CHUNK_KIND, rows, made, settings.lease_s, "chunks")


def join(
    store: JobStore,
    dispatcher: Dispatcher,
    artifacts: ArtifactStore,
    claim: Claim,
    settings: FarmSettings,
    assemble: Assemble,
) -> str:
    """One delivery of a chunked render job: write its chunk rows (the first delivery), let
    the fair window send what it may, then look at the chunks: all completed, assemble the
    render's files and complete; a chunk failed (after its own retries) or canceled, end so;
    else record frames done over frames and come back in :data:`POLL_S`. Answers what
    happened; a store or broker error is raised (the caller retries the delivery)."""
    job_id, params = claim.job_id, claim.params
    frames = int(params["frames"])
    summary = store.child_summary(job_id)
    made = sum(count for count, _ in summary.values())
    n = max(made, len(chunk_ranges(frames, settings.render_chunk_frames)))
    if made < n:
        ended = set_up(store, claim, settings, made)
        if ended is not None:
            return ended
    ended, summary = look(store, dispatcher, settings, claim, _chunk_name)
    if ended is not None:
        return ended
    done = summary.get(JobState.COMPLETED, (0, 0.0))[0]
    if done < n:
        # frames done over frames: the completed chunks' frames and the running ones' share
        # (chunks are equal but for the last: counted as whole ones, capped)
        size = -(-frames // n)
        running = sum(p for st, (_, p) in summary.items() if st != JobState.COMPLETED)
        drawn = min(frames, done * size + int(running * size))
        if store.park(claim, 0.95 * drawn / frames, f"frames {drawn}/{frames}"):
            dispatcher.send(job_id, claim.kind, countdown=POLL_S, pool=params.get("pool"))
            return "waiting"
        if store.heartbeat(claim, settings.lease_s) is None:
            return "lost"
        store.cancel_family(job_id, children_only=True)
        store.finish(claim, JobState.CANCELED, error="canceled on request")
        return JobState.CANCELED
    results = sorted(store.child_results(job_id), key=lambda pr: int(pr[0]["chunk"][0]))
    store.heartbeat(claim, settings.lease_s, 0.95, "assembling the clip")
    scratch = artifacts.scratch(job_id)
    try:
        files, result = assemble(job_id, params, results, scratch)
        published: list[Path] = []
        try:
            for name, path in files.items():
                published.append(artifacts.publish(job_id, path, name))
        except Exception:
            for p in published:
                p.unlink(missing_ok=True)
            raise
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    ok = store.finish(claim, JobState.COMPLETED, artifacts=sorted(files), result=result)
    if not ok:
        return "lost"
    for _, r in results:  # the chunks' frames are in the clip now
        drop_frames(artifacts, job_id, r)
    return JobState.COMPLETED


def drop_frames(artifacts: ArtifactStore, render_id: str, result: dict[str, Any] | None) -> int:
    """Delete the frames a chunk (its ``result``) wrote into render job ``render_id``'s
    folder; how many there were."""
    dropped = 0
    for name in (result or {}).get("files", []):
        frame = artifacts.path(render_id, name)
        if frame is not None:
            frame.unlink(missing_ok=True)
            dropped += 1
    return dropped
