"""The job store: every state change of a job is one SQL statement on the job table.

Workers claim a job with a lease (``lease_owner``, ``lease_expires``) that their heartbeat
extends; only the lease holder may finish it, so a job delivered twice runs to completion
once. The reaper hands expired leases back to the queue.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import uuid
import zlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any, NamedTuple

from sqlalchemy import Engine, delete, exists, func, insert, select, text, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, aliased

from farm.db import JobRow, engine_for, utcnow
from farm.error_text import capped
from schemas.jobs import JobState

FINISHED = (JobState.COMPLETED, JobState.FAILED, JobState.CANCELED)
UNFINISHED = (JobState.QUEUED, JobState.ACTIVE)
IN_BATCH = 500  # ids per IN list: far below every driver's bound-parameter limit
WINDOW_LOCK = 7318450022  # the fair window's advisory lock (beside the migrations' 7318450021)
QUOTA_LOCK_SPACE = 731845  # tenants' quota locks: (this, crc32 of the tenant), two int4 keys
TILE_KIND = "forest_tile"
CHUNK_KIND = "render_chunk"
"""A chunk of a render job's frames (:mod:`farm.chunks`): like tiles, a child row (``parent``)
that the fair window sends."""
PARENT_KINDS = ("forest", "render")  # the kinds that make children (with ``tiles`` > 0)
HELD = "waiting for a turn"
"""The stage of a job (or tile) that is queued but not sent yet (:mod:`farm.fair`)."""


def waiting_for(after: list[str]) -> str:
    """The stage of a job that waits for others (:mod:`farm.graph`)."""
    return f"waiting for {len(after)} job(s)"


class IdempotencyConflict(Exception):
    """The idempotency key was used before with a different request."""

    def __init__(self, key: str) -> None:
        super().__init__(f"Idempotency-Key {key!r} was used with a different request")
        self.key = key


def scoped_key(tenant: str, key: str) -> str:
    """An idempotency key as stored: per tenant (two tenants may use the same key)."""
    return hashlib.sha256(f"{tenant}\0{key}".encode()).hexdigest()


def request_hash(kind: str, params: dict[str, Any]) -> str:
    text = json.dumps({"kind": kind, "params": params}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


class FinishedJob(NamedTuple):
    kind: str
    started_at: datetime | None
    finished_at: datetime | None
    result: dict[str, Any] | None


@dataclass(frozen=True)
class Claim:
    job_id: str
    owner: str
    attempt: int
    kind: str
    params: dict[str, Any]
    max_attempts: int


class JobStore:
    def __init__(self, url: str) -> None:
        self.engine: Engine = engine_for(url)

    def session(self) -> Session:
        return Session(self.engine, expire_on_commit=False)

    # -- API side ---------------------------------------------------------------------------

    def create(
        self,
        kind: str,
        params: dict[str, Any],
        max_attempts: int,
        key: str | None = None,
        tenant: str = "local",
        priority: int = 5,
        estimate: dict[str, Any] | None = None,
        after: list[str] | None = None,
        admit: Callable[[tuple[int, int]], Exception | None] | None = None,
    ) -> tuple[JobRow, bool]:
        """Insert a queued job of ``tenant``, held until the fair window sends it
        (:func:`farm.fair.pump`); with an idempotency key the tenant already used
        for the same request, answer that job instead (``created`` False). ``estimate``
        (:class:`schemas.jobs.JobCost`) is what the tenant's quotas sum while it is unfinished.
        ``after``: jobs it waits for (:mod:`farm.graph`); each lists it in its ``then``.
        ``admit``: given the tenant's load (:meth:`tenant_load`), the exception that refuses
        the job, or None; asked and answered under the tenant's lock, so that requests at
        once cannot each see room and together overshoot the quota."""
        digest = request_hash(kind, params)
        stored = scoped_key(tenant, key) if key is not None else None
        if key is not None and stored is not None:
            old = self.by_key(stored)
            if old is not None:
                if old.request_hash != digest:
                    raise IdempotencyConflict(key)
                return old, False
        now = utcnow()
        row = JobRow(
            id=uuid.uuid4().hex,
            kind=kind,
            tenant=tenant,
            state=JobState.QUEUED,
            params=params,
            attempts=0,
            max_attempts=max_attempts,
            progress=0.0,
            cancel_requested=False,
            idempotency_key=stored,
            request_hash=digest,
            artifacts=[],
            created_at=now,
            enqueued_at=None,  # held: the fair window sends it (farm.fair.pump)
            stage=HELD,
            priority=priority,
            cost=int((estimate or {}).get("units", 0)),
            tiles=int((estimate or {}).get("tiles", 0)),
            estimate=estimate,
            after=list(after) if after else None,
            blocked=bool(after),
            # called once it ends (farm.webhooks); the service checked its host
            webhook_url=params.get("webhook"),
            webhook_pending=params.get("webhook") is not None,
        )
        if after:
            row.stage = waiting_for(after)
        try:
            with self.session() as s, s.begin():
                if admit is not None:
                    self._lock_tenant(s, tenant)
                    refused = admit(self._load(s, tenant))
                    if refused is not None:
                        raise refused
                s.add(row)
                for parent in s.scalars(
                    select(JobRow).where(JobRow.id.in_(after or [])).with_for_update()
                ):
                    parent.then = [*(parent.then or []), row.id]
        except IntegrityError:  # a concurrent request with the same key won the insert
            if key is None or stored is None:
                raise
            old = self.by_key(stored)
            if old is None or old.request_hash != digest:
                raise IdempotencyConflict(key) from None
            return old, False
        return row, True

    def by_key(self, key: str) -> JobRow | None:
        with self.session() as s:
            return s.scalars(select(JobRow).where(JobRow.idempotency_key == key)).first()

    def tenant_load(self, tenant: str) -> tuple[int, int]:
        """The estimated cost (piece-frames) and tiles of the tenant's queued and running jobs
        (a tiled forest's tiles count through their forest job)."""
        with self.session() as s:
            return self._load(s, tenant)

    @staticmethod
    def _load(s: Session, tenant: str) -> tuple[int, int]:
        cost, tiles = s.execute(
            select(
                func.coalesce(func.sum(JobRow.cost), 0),
                func.coalesce(func.sum(JobRow.tiles), 0),
            ).where(JobRow.tenant == tenant, JobRow.state.in_(UNFINISHED), JobRow.parent.is_(None))
        ).one()
        return int(cost), int(tiles)

    def _lock_tenant(self, s: Session, tenant: str) -> None:
        """Hold the tenant's lock to the end of the transaction: an advisory lock keyed by the
        tenant on PostgreSQL (other tenants go on), the write lock on SQLite."""
        if self.engine.dialect.name == "postgresql":
            key = zlib.crc32(tenant.encode()) - 2**31  # int4
            s.execute(
                text("SELECT pg_advisory_xact_lock(:space, :key)"),
                {"space": QUOTA_LOCK_SPACE, "key": key},
            )
        elif self.engine.dialect.name == "sqlite":
            s.execute(text("BEGIN IMMEDIATE"))

    def get(self, job_id: str, tenant: str | None = None) -> JobRow | None:
        """The job; with ``tenant``, only if it is that tenant's (another's is None)."""
        with self.session() as s:
            row = s.get(JobRow, job_id)
        if row is not None and tenant is not None and row.tenant != tenant:
            return None
        return row

    def list_jobs(
        self,
        state: str | None,
        kind: str | None,
        limit: int,
        offset: int,
        tenant: str | None = None,
    ) -> tuple[Sequence[JobRow], int]:
        q = select(JobRow)
        if tenant is not None:
            q = q.where(JobRow.tenant == tenant)
        if state is not None:
            q = q.where(JobRow.state == state)
        if kind is not None:
            q = q.where(JobRow.kind == kind)
        with self.session() as s:
            total = s.scalar(select(func.count()).select_from(q.subquery())) or 0
            rows = s.scalars(
                q.order_by(JobRow.created_at.desc(), JobRow.id).limit(limit).offset(offset)
            ).all()
        return rows, total

    def cancel_family(self, job_id: str, children_only: bool = False) -> None:
        """Cancel a job and the jobs it made (a tiled forest's tiles, found by ``parent``: a
        few indexed statements whatever their number, no id list). Children never sent (held
        by the fair window) are deleted: no worker saw them, and deleting 100,000 rows is a
        tenth of a second where rewriting them (every index of each) took seconds. Queued
        jobs are canceled at once; active ones get the flag their worker reads (and kill the
        job's process)."""
        now = utcnow()
        whom = [JobRow.parent == job_id]
        if not children_only:
            whom.append(JobRow.id == job_id)
        with self.session() as s, s.begin():
            s.execute(
                delete(JobRow)
                .where(
                    JobRow.parent == job_id,
                    JobRow.state == JobState.QUEUED,
                    JobRow.enqueued_at.is_(None),
                )
                .execution_options(synchronize_session=False)
            )
            for who in whom:  # separate indexed updates, not one OR that may scan the table
                s.execute(
                    update(JobRow)
                    .where(who, JobRow.state == JobState.QUEUED)
                    .values(
                        state=JobState.CANCELED,
                        cancel_requested=True,
                        finished_at=now,
                        stage=JobState.CANCELED,
                    )
                    .execution_options(synchronize_session=False)
                )
                s.execute(
                    update(JobRow)
                    .where(who, JobRow.state == JobState.ACTIVE)
                    .values(cancel_requested=True)
                    .execution_options(synchronize_session=False)
                )

    def abandon(self, job_id: str, error: str) -> JobRow | None:
        """A job that never reached the broker is failed with ``error`` and its idempotency
        key let go (the caller was told to retry: the retry makes a new job). Only while it is
        still queued with no attempt; None if a worker took it after all (the message did go
        out). Only while held (no ``enqueued_at``): a job whose message went out is not."""
        with self.session() as s, s.begin():
            res = s.execute(
                update(JobRow)
                .where(
                    JobRow.id == job_id,
                    JobRow.state == JobState.QUEUED,
                    JobRow.attempts == 0,
                    JobRow.enqueued_at.is_(None),
                )
                .values(
                    state=JobState.FAILED,
                    stage=JobState.FAILED,
                    error=capped(error),
                    finished_at=utcnow(),
                    idempotency_key=None,
                )
                .execution_options(synchronize_session=False)
            )
        return self.get(job_id) if res.rowcount == 1 else None  # type: ignore[attr-defined]

    def discard(self, job_id: str) -> bool:
        """Delete a job that was never sent (queued, no attempt): its input could not be
        stored, so there is no job to tell of, and its idempotency key is free again. False
        if it is not such a job."""
        with self.session() as s, s.begin():
            res = s.execute(
                delete(JobRow)
                .where(JobRow.id == job_id, JobRow.state == JobState.QUEUED, JobRow.attempts == 0)
                .execution_options(synchronize_session=False)
            )
        deleted: int = res.rowcount  # type: ignore[attr-defined]
        return deleted == 1

    def artifacts_deleted(self, job_id: str) -> JobRow | None:
        """Record that a finished job's artifacts were deleted (its folder is gone): it lists
        none from now on. None unless the job is finished."""
        with self.session() as s, s.begin():
            s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.state.in_(FINISHED))
                .values(
                    artifacts=[],
                    artifacts_deleted_at=func.coalesce(JobRow.artifacts_deleted_at, utcnow()),
                )
                .execution_options(synchronize_session=False)
            )
        row = self.get(job_id)
        return row if row is not None and row.state in FINISHED else None

    def ended_children(self, kind: str, limit: int = 200) -> list[tuple[str, str, bool, Any]]:
        """Completed children of ``kind`` whose parent has ended and whose files are not
        recorded as deleted: (child id, parent id, whether the parent completed, the child's
        result). Each is looked at once (:meth:`artifacts_deleted` marks it)."""
        parent = aliased(JobRow)
        with self.session() as s:
            rows = s.execute(
                select(JobRow.id, JobRow.parent, parent.state, JobRow.result)
                .join(parent, parent.id == JobRow.parent)
                .where(
                    JobRow.kind == kind,
                    JobRow.state == JobState.COMPLETED,
                    JobRow.artifacts_deleted_at.is_(None),
                    parent.state.in_(FINISHED),
                )
                .limit(limit)
            ).all()
        return [(i, str(p), st == JobState.COMPLETED, r) for i, p, st, r in rows]

    def expired(self, ttl_s: float, limit: int = 200) -> list[str]:
        """Finished jobs whose artifacts outlived ``ttl_s`` and are not deleted yet, oldest
        first."""
        cutoff = utcnow() - timedelta(seconds=ttl_s)
        with self.session() as s:
            return list(
                s.scalars(
                    select(JobRow.id)
                    .where(
                        JobRow.state.in_(FINISHED),
                        JobRow.finished_at < cutoff,
                        JobRow.artifacts_deleted_at.is_(None),
                    )
                    .order_by(JobRow.finished_at)
                    .limit(limit)
                )
            )

    def counts(self) -> dict[tuple[str, str], int]:
        with self.session() as s:
            rows = s.execute(
                select(JobRow.kind, JobRow.state, func.count()).group_by(JobRow.kind, JobRow.state)
            ).all()
        return {(k, st): int(n) for k, st, n in rows}

    def recent_finished(self, limit: int = 1000) -> list[FinishedJob]:
        """What the metrics scrape needs of the latest completed jobs: four columns, not the
        rows (a forest job's params can hold a whole grammar)."""
        with self.session() as s:
            rows = s.execute(
                select(JobRow.kind, JobRow.started_at, JobRow.finished_at, JobRow.result)
                .where(JobRow.state == JobState.COMPLETED)
                .order_by(JobRow.finished_at.desc())
                .limit(limit)
            ).all()
        return [FinishedJob(*r) for r in rows]

    # -- jobs that make jobs (a tiled forest's tiles: farm.tiles) ----------------------------

    def count_children(self, parent: str) -> int:
        """How many jobs ``parent`` made so far."""
        with self.session() as s:
            return int(s.scalar(select(func.count()).where(JobRow.parent == parent)) or 0)

    def set_tiles(self, job_id: str, tiles: int) -> None:
        """Record how many tiles a job makes where its estimate did not (a job made without
        the API's estimate): the fair window looks for jobs with tiles."""
        with self.session() as s, s.begin():
            s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.tiles == 0)
                .values(tiles=tiles)
                .execution_options(synchronize_session=False)
            )

    def add_children(
        self, parent: Claim, kind: str, children: Sequence[tuple[str, dict[str, Any]]]
    ) -> None:
        """Insert the jobs ``(id, params)`` of ``kind`` that ``parent`` makes, held: queued
        but not sent (no ``enqueued_at``) until the fair window sends them
        (:func:`farm.fair.pump`). One statement per call: callers pass a bounded batch
        (SQLAlchemy pages an executemany at 1,000 rows, within PostgreSQL's 65,535 and
        SQLite's 32,766 parameters)."""
        with self.session() as s:
            tenant, priority = s.execute(
                select(JobRow.tenant, JobRow.priority).where(JobRow.id == parent.job_id)
            ).one()
        now = utcnow()
        rows: list[dict[str, Any]] = [
            {
                "id": t, "kind": kind, "tenant": tenant, "state": JobState.QUEUED, "params": p,
                "attempts": 0, "max_attempts": parent.max_attempts, "progress": 0.0,
                "stage": HELD, "cancel_requested": False, "artifacts": [], "created_at": now,
                "enqueued_at": None, "parent": parent.job_id, "priority": priority,
            }
            for t, p in children
        ]  # fmt: skip
        if rows:
            with self.session() as s, s.begin():
                s.execute(
                    insert(JobRow.metadata.tables["jobs"]), rows
                )  # Core: no ORM bookkeeping per row

    def child_summary(self, parent: str) -> dict[str, tuple[int, float]]:
        """State -> (how many, summed progress) of the jobs ``parent`` made (one query)."""
        with self.session() as s:
            got = s.execute(
                select(JobRow.state, func.count(), func.coalesce(func.sum(JobRow.progress), 0.0))
                .where(JobRow.parent == parent)
                .group_by(JobRow.state)
            ).all()
        return {st: (int(n), float(p)) for st, n, p in got}

    def failed_child(self, parent: str) -> tuple[dict[str, Any], str | None] | None:
        """The params and error of one failed job that ``parent`` made, if any."""
        with self.session() as s:
            row = s.execute(
                select(JobRow.params, JobRow.error)
                .where(JobRow.parent == parent, JobRow.state == JobState.FAILED)
                .limit(1)
            ).first()
        return None if row is None else (dict(row[0]), row[1])

    def child_results(self, parent: str) -> list[tuple[dict[str, Any], dict[str, Any] | None]]:
        """``(params, result)`` of every job ``parent`` made (a finished forest's join)."""
        with self.session() as s:
            got = s.execute(
                select(JobRow.params, JobRow.result).where(JobRow.parent == parent)
            ).all()
        return [(dict(p), r) for p, r in got]

    # -- the fair window (farm.fair) ---------------------------------------------------------

    @contextlib.contextmanager
    def exclusive(self) -> Iterator[Session]:
        """A transaction that one process at a time holds (the fair window counts, then
        takes: two at once would both see room and overshoot): a transaction-scoped advisory
        lock on PostgreSQL, the write lock from the start (``BEGIN IMMEDIATE``) on SQLite."""
        with self.session() as s, s.begin():
            if self.engine.dialect.name == "postgresql":
                s.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": WINDOW_LOCK})
            elif self.engine.dialect.name == "sqlite":
                s.execute(text("BEGIN IMMEDIATE"))
            yield s

    @staticmethod
    def waiting(s: Session) -> dict[str, datetime]:
        """Tenants with something the window may send, each with its oldest such job: held
        top-level jobs, and unfinished tiled forests (which may hold tiles not sent yet)."""
        held = s.execute(
            select(JobRow.tenant, func.min(JobRow.created_at))
            .where(
                JobRow.state == JobState.QUEUED,
                JobRow.enqueued_at.is_(None),
                JobRow.parent.is_(None),
                JobRow.cancel_requested.is_(False),
                JobRow.blocked.is_(False),
            )
            .group_by(JobRow.tenant)
        ).all()
        tiled = s.execute(  # tiled forests and chunked renders (their tiles count the chunks)
            select(JobRow.tenant, func.min(JobRow.created_at))
            .where(
                JobRow.kind.in_(PARENT_KINDS),
                JobRow.tiles > 0,
                JobRow.state.in_(UNFINISHED),
                JobRow.cancel_requested.is_(False),
            )
            .group_by(JobRow.tenant)
        ).all()
        oldest: dict[str, datetime] = {}
        for tenant, at in [*held, *tiled]:
            oldest[tenant] = min(at, oldest.get(tenant, at))
        return oldest

    def in_flight(self, s: Session | None = None) -> dict[str, int]:
        """Per tenant: its jobs and tiles sent to the broker and not finished. A tiled forest
        whose tiles are written is not counted while it waits on them (its tiles are: counting
        both, a tenant's forests could fill its share and starve their own tiles)."""
        child = aliased(JobRow)
        sent = (JobRow.state == JobState.ACTIVE) | (
            (JobRow.state == JobState.QUEUED) & JobRow.enqueued_at.is_not(None)
        )
        has_tiles = exists().where(child.parent == JobRow.id)
        q = select(JobRow.tenant, func.count()).where(sent, ~has_tiles).group_by(JobRow.tenant)
        with contextlib.nullcontext(s) if s is not None else self.session() as ss:
            got = ss.execute(q).all()
        return {str(t): int(n) for t, n in got}

    def take_next(self, s: Session, tenant: str) -> tuple[str, str] | None:
        """Mark the next job of ``tenant`` sent (the caller sends it once ``s`` commits): its
        most urgent, oldest held job, or a held tile of its most urgent, oldest tiled forest,
        whichever comes first; ``(id, kind)``, or None when it holds nothing."""
        top = s.execute(
            select(JobRow.id, JobRow.kind, JobRow.priority, JobRow.created_at)
            .where(
                JobRow.tenant == tenant,
                JobRow.state == JobState.QUEUED,
                JobRow.enqueued_at.is_(None),
                JobRow.parent.is_(None),
                JobRow.cancel_requested.is_(False),
                JobRow.blocked.is_(False),
            )
            .order_by(JobRow.priority.desc(), JobRow.created_at, JobRow.id)
            .limit(1)
        ).first()
        forests = s.execute(
            select(JobRow.id, JobRow.priority, JobRow.created_at).where(
                JobRow.tenant == tenant,
                JobRow.kind.in_(PARENT_KINDS),
                JobRow.tiles > 0,
                (JobRow.state == JobState.ACTIVE)
                | ((JobRow.state == JobState.QUEUED) & JobRow.enqueued_at.is_not(None)),
                JobRow.cancel_requested.is_(False),
            )
        ).all()
        order: list[tuple[int, datetime, str, str | None]] = [
            (-p, at, str(i), None) for i, p, at in forests
        ]
        if top is not None:
            order.append((-top.priority, top.created_at, str(top.id), str(top.kind)))
        for _, _, job_id, kind in sorted(order):
            if kind is not None:  # a held job: itself
                s.execute(
                    update(JobRow)
                    .where(JobRow.id == job_id, JobRow.enqueued_at.is_(None))
                    .values(enqueued_at=utcnow(), stage=JobState.QUEUED)
                    .execution_options(synchronize_session=False)
                )
                return job_id, kind
            child = self.take_held(s, job_id)
            if child is not None:
                return child
        return None

    @staticmethod
    def take_held(s: Session, parent: str) -> tuple[str, str] | None:
        """Mark one held child of ``parent`` sent (the caller sends it once ``s`` commits);
        its ``(id, kind)``, or None when none is held."""
        got = s.execute(
            select(JobRow.id, JobRow.kind)
            .where(
                JobRow.parent == parent,
                JobRow.state == JobState.QUEUED,
                JobRow.enqueued_at.is_(None),
            )
            .limit(1)
        ).first()
        if got is None:
            return None
        s.execute(
            update(JobRow)
            .where(JobRow.id == got[0])
            .values(enqueued_at=utcnow(), stage=JobState.QUEUED)
            .execution_options(synchronize_session=False)
        )
        return str(got[0]), str(got[1])

    def hold_again(self, job_id: str) -> None:
        """A job or tile whose message could not be sent goes back to held."""
        with self.session() as s, s.begin():
            s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.state == JobState.QUEUED)
                .values(enqueued_at=None, stage=HELD)
                .execution_options(synchronize_session=False)
            )

    def park(self, claim: Claim, progress: float, stage: str) -> bool:
        """Back to the queue while the jobs it made run (a poll, not an attempt: the attempt
        count is given back); False if the lease was lost or cancel was asked (a parked job
        asked to cancel would never be claimed again: the caller ends it)."""
        with self.session() as s, s.begin():
            res = s.execute(
                update(JobRow)
                .where(*self._held(claim), JobRow.cancel_requested.is_(False))
                .values(
                    **{
                        "state": JobState.QUEUED,
                        "stage": stage[:64],
                        "progress": max(0.0, min(1.0, progress)),
                        "lease_owner": None,
                        "lease_expires": None,
                        "attempts": claim.attempt - 1,
                        "enqueued_at": utcnow(),
                    }
                )
                .execution_options(synchronize_session=False)
            )
        return res.rowcount == 1  # type: ignore[attr-defined, no-any-return]

    # -- worker side ------------------------------------------------------------------------

    def claim(self, job_id: str, owner: str, lease_s: float) -> Claim | None:
        """Take the job if it is queued, or active under an expired lease; None otherwise
        (done, canceled, or another worker holds a live lease)."""
        now = utcnow()
        with self.session() as s, s.begin():
            res = s.execute(
                update(JobRow)
                .where(
                    JobRow.id == job_id,
                    JobRow.cancel_requested.is_(False),
                    (JobRow.state == JobState.QUEUED)
                    | ((JobRow.state == JobState.ACTIVE) & (JobRow.lease_expires < now)),
                )
                .values(
                    state=JobState.ACTIVE,
                    lease_owner=owner,
                    lease_expires=now + timedelta(seconds=lease_s),
                    heartbeat_at=now,
                    attempts=JobRow.attempts + 1,
                    started_at=func.coalesce(JobRow.started_at, now),
                    stage="started",
                    progress=0.0,  # a new attempt starts over
                )
                .execution_options(synchronize_session=False)
            )
            if res.rowcount != 1:  # type: ignore[attr-defined]
                return None
            row = s.get(JobRow, job_id)
            assert row is not None
            # which worker ran each attempt (lease_owner says only who holds it now); the
            # row is this claim's until it commits
            run = {"attempt": row.attempts, "worker": owner, "started_at": now.isoformat()}
            runs = list(row.runs or [])
            if runs and runs[-1].get("attempt") == row.attempts:
                runs.pop()  # a tiled forest's poll takes the same attempt again: one entry
            row.runs = [*runs, run]
            return Claim(job_id, owner, row.attempts, row.kind, dict(row.params), row.max_attempts)

    def heartbeat(
        self, claim: Claim, lease_s: float, progress: float | None = None, stage: str | None = None
    ) -> bool | None:
        """Extend the lease (and record progress). Answers the cancel flag, or None when the
        lease was lost (the reaper gave the job to another worker)."""
        now = utcnow()
        values: dict[str, Any] = {
            "lease_expires": now + timedelta(seconds=lease_s),
            "heartbeat_at": now,
        }
        if progress is not None:
            values["progress"] = max(0.0, min(1.0, progress))
        if stage is not None:
            values["stage"] = stage[:64]
        with self.session() as s, s.begin():
            if not self._update_held(s, claim, values):
                return None
            return bool(s.scalar(select(JobRow.cancel_requested).where(JobRow.id == claim.job_id)))

    def finish(
        self,
        claim: Claim,
        state: JobState,
        *,
        artifacts: list[str] | None = None,
        result: dict[str, Any] | None = None,
        error: str | None = None,
    ) -> bool:
        """Completed, failed or canceled, by the lease holder only; False if the lease was lost."""
        values: dict[str, Any] = {
            "state": state,
            "stage": state,
            "finished_at": utcnow(),
            "lease_owner": None,
            "lease_expires": None,
            "error": error,
        }
        if state == JobState.COMPLETED:
            values |= {"progress": 1.0, "artifacts": artifacts or [], "result": result}
        return self._finish(claim, values)

    def retry(self, claim: Claim, error: str) -> bool:
        """Back to the queue after a failed attempt (the caller checked the attempt cap)."""
        return self._finish(
            claim,
            {
                "state": JobState.QUEUED,
                "stage": "retrying",
                "progress": 0.0,  # the next attempt starts over
                "lease_owner": None,
                "lease_expires": None,
                "error": error,
                "enqueued_at": utcnow(),
            },
        )

    def _finish(self, claim: Claim, values: dict[str, Any]) -> bool:
        with self.session() as s, s.begin():
            return self._update_held(s, claim, values)

    def _update_held(self, s: Session, claim: Claim, values: dict[str, Any]) -> bool:
        """Update the job only while ``claim`` still holds its lease; whether it did. An
        error is stored capped (:mod:`farm.error_text`)."""
        if "error" in values:
            values = values | {"error": capped(values["error"])}
        res = s.execute(
            update(JobRow)
            .where(*self._held(claim))
            .values(**values)
            .execution_options(synchronize_session=False)
        )
        updated: int = res.rowcount  # type: ignore[attr-defined]  # (a CursorResult's)
        return updated == 1

    @staticmethod
    def _held(claim: Claim) -> tuple[Any, ...]:
        return (
            JobRow.id == claim.job_id,
            JobRow.state == JobState.ACTIVE,
            JobRow.lease_owner == claim.owner,
            JobRow.attempts == claim.attempt,
        )

    # -- reaper -----------------------------------------------------------------------------

    def unfinished(self, job_ids: Iterable[str]) -> set[str]:
        """Which of these jobs are queued or running (a scratch folder of theirs may be in
        use); unknown ids are not."""
        ids = list(job_ids)
        found: set[str] = set()
        with self.session() as s:
            for i in range(0, len(ids), IN_BATCH):  # bounded IN lists
                found.update(
                    s.scalars(
                        select(JobRow.id).where(
                            JobRow.id.in_(ids[i : i + IN_BATCH]),
                            JobRow.state.in_(UNFINISHED),
                        )
                    )
                )
        return found

    def reap(self, requeue_after_s: float) -> tuple[list[JobRow], list[JobRow]]:
        """Expired leases go back to ``queued`` (or ``failed`` past the attempt cap; canceled
        if cancel was asked). Answers (jobs to send to the broker again, jobs failed)."""
        now = utcnow()
        stale = now - timedelta(seconds=requeue_after_s)
        resend: list[JobRow] = []
        failed: list[JobRow] = []
        with self.session() as s:
            expired = s.scalars(
                select(JobRow).where(JobRow.state == JobState.ACTIVE, JobRow.lease_expires < now)
            ).all()
            lost = s.scalars(
                select(JobRow).where(
                    JobRow.state == JobState.QUEUED,
                    # a job with no enqueued_at is held by the fair window, not lost
                    JobRow.enqueued_at < stale,
                )
            ).all()
        for row in expired:
            if row.cancel_requested:
                values: dict[str, Any] = {"state": JobState.CANCELED, "stage": JobState.CANCELED}
            elif row.attempts >= row.max_attempts:
                values = {
                    "state": JobState.FAILED,
                    "stage": JobState.FAILED,
                    "error": f"worker lost {row.attempts} time(s) (lease expired)",
                }
            else:
                # the next attempt starts over: a queued job shows none of a dead one's progress
                values = {
                    "state": JobState.QUEUED,
                    "stage": "requeued",
                    "progress": 0.0,
                    "enqueued_at": now,
                }
            if values["state"] != JobState.QUEUED:
                values["finished_at"] = now
            with self.session() as s, s.begin():
                res = s.execute(
                    update(JobRow)
                    .where(
                        JobRow.id == row.id,
                        JobRow.state == JobState.ACTIVE,
                        JobRow.lease_owner == row.lease_owner,
                        JobRow.attempts == row.attempts,
                        JobRow.lease_expires < now,
                    )
                    .values(lease_owner=None, lease_expires=None, **values)
                    .execution_options(synchronize_session=False)
                )
            if res.rowcount == 1:  # type: ignore[attr-defined]
                (resend if values["state"] == JobState.QUEUED else failed).append(row)
        for row in lost:  # claimed by one reaper only: every API process and worker runs one
            with self.session() as s, s.begin():
                res = s.execute(
                    update(JobRow)
                    .where(
                        JobRow.id == row.id,
                        JobRow.state == JobState.QUEUED,
                        JobRow.enqueued_at == row.enqueued_at,
                    )
                    .values(enqueued_at=now)
                    .execution_options(synchronize_session=False)
                )
            if res.rowcount == 1:  # type: ignore[attr-defined]
                resend.append(row)
        return resend, failed
