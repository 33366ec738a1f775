"""The reaper: expired leases (a worker died) and queued jobs whose message went missing are
sent to the broker again and the fair window is pumped (:mod:`farm.fair`); beside it, a
thread of its own calls due webhooks (:mod:`farm.webhooks`: a slow receiver never holds up
the recovery of a lease). Runs as a thread
in the API process and in every worker process; every ``housekeeping_s`` it also removes
scratch folders that dead processes left behind and the artifacts of jobs finished more than
``artifact_ttl_s`` ago."""

from __future__ import annotations

import logging
import threading
import time

from farm import joblog
from farm.artifacts import ArtifactStore
from farm.chunks import drop_frames
from farm.dispatch import Dispatcher
from farm.fair import pump_quietly
from farm.settings import FarmSettings
from farm.store import CHUNK_KIND, JobStore
from farm.webhooks import Deliveries
from schemas.jobs import JobState

log = logging.getLogger(__name__)


def reap_once(
    store: JobStore,
    dispatcher: Dispatcher,
    requeue_after_s: float,
    settings: FarmSettings | None = None,
) -> int:
    """One round: expired leases and lost messages sent again; with ``settings``, the fair
    window pumped too (held jobs are sent even if the pump that should have sent them was
    lost with its process)."""
    resend, failed = store.reap(requeue_after_s)
    cap = settings.job_log_lines if settings is not None else 1000
    for row in resend:
        dispatcher.send(row.id, row.kind, pool=(row.params or {}).get("pool"))
        log.info("re-enqueued job %s (%s)", row.id, row.stage)
        if row.state == JobState.ACTIVE:  # (the row as it was) a lease expired, not a message
            _note(store, row.id, row.attempts, "warning", f"worker {row.lease_owner} lost "
                  "(its lease expired): the job is queued again", cap)  # fmt: skip
    for row in failed:
        log.warning("job %s failed: lease expired after %d attempt(s)", row.id, row.attempts)
        what = "canceled" if row.cancel_requested else f"failed after {row.attempts} attempt(s)"
        _note(store, row.id, row.attempts, "error",
              f"worker {row.lease_owner} lost (its lease expired): {what}", cap)  # fmt: skip
    if settings is not None:
        pump_quietly(store, dispatcher, settings)
    return len(resend)


def _note(store: JobStore, job_id: str, attempt: int, level: str, text: str, cap: int) -> None:
    try:
        joblog.append(store, job_id, attempt, [joblog.Line(level, text)], cap)
    except Exception:  # the job's state is what counts; its log line is a courtesy
        log.exception("writing the log of job %s failed", job_id)


def tidy_once(store: JobStore, artifacts: ArtifactStore, artifact_ttl_s: float = 0.0) -> int:
    """Remove the scratch folders of dead processes (:mod:`farm.scratch`) and, with a TTL,
    expired artifacts; how many folders went."""
    swept = artifacts.sweep_scratch(store.unfinished)
    for path in swept:
        log.info("removed the scratch folder %s (its process is gone)", path.name)
    drop_stray_frames(store, artifacts)
    expired = expire_artifacts(store, artifacts, artifact_ttl_s) if artifact_ttl_s else 0
    return len(swept) + expired


def drop_stray_frames(store: JobStore, artifacts: ArtifactStore) -> int:
    """Delete the frames that completed chunks wrote into a render job that then failed or
    was canceled (listed by no job: nobody could download or delete them); a completed
    render's join already took its chunks' frames. How many frames went."""
    dropped = 0
    for chunk_id, render_id, completed, result in store.ended_children(CHUNK_KIND):
        if not completed:
            dropped += drop_frames(artifacts, render_id, result)
        store.artifacts_deleted(chunk_id)
    if dropped:
        log.info("deleted %d frame(s) of chunked renders that did not complete", dropped)
    return dropped


def delete_artifacts(store: JobStore, artifacts: ArtifactStore, job_id: str) -> None:
    """Delete a finished job's artifact folder, then record it (a crash between the two
    leaves the record to the next round, which deletes again: nothing is half done)."""
    artifacts.remove(job_id)
    store.artifacts_deleted(job_id)


def expire_artifacts(store: JobStore, artifacts: ArtifactStore, ttl_s: float) -> int:
    """Delete the artifacts of jobs finished more than ``ttl_s`` ago (a batch per round)."""
    ids = store.expired(ttl_s)
    for job_id in ids:
        delete_artifacts(store, artifacts, job_id)
        log.info("deleted the artifacts of job %s (older than %g s)", job_id, ttl_s)
    return len(ids)


class Reaper(threading.Thread):
    def __init__(
        self,
        store: JobStore,
        dispatcher: Dispatcher,
        interval_s: float,
        requeue_after_s: float,
        artifacts: ArtifactStore | None = None,
        housekeeping_s: float = 300.0,
        artifact_ttl_s: float = 0.0,
        settings: FarmSettings | None = None,
    ) -> None:
        super().__init__(name="forest-reaper", daemon=True)
        self.store, self.dispatcher, self.artifacts = store, dispatcher, artifacts
        self.interval_s, self.requeue_after_s = interval_s, requeue_after_s
        self.housekeeping_s, self.artifact_ttl_s = housekeeping_s, artifact_ttl_s
        self.settings = settings  # the fair window's, pumped each round
        self.stopped = threading.Event()
        self.webhooks = Deliveries(store, settings, interval_s) if settings is not None else None

    def run(self) -> None:
        if self.webhooks is not None:
            self.webhooks.start()
        tidied = time.monotonic()
        while not self.stopped.wait(self.interval_s):
            try:
                reap_once(self.store, self.dispatcher, self.requeue_after_s, self.settings)
            except Exception:  # a database or broker hiccup: try again next round
                log.exception("reaper round failed")
            # listing the artifact folder is not free (shared storage): less often
            if self.artifacts is not None and time.monotonic() - tidied >= self.housekeeping_s:
                tidied = time.monotonic()
                try:
                    tidy_once(self.store, self.artifacts, self.artifact_ttl_s)
                except Exception:
                    log.exception("housekeeping round failed")

    def stop(self) -> None:
        self.stopped.set()
        if self.webhooks is not None:
            self.webhooks.stop()
