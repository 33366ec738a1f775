"""The job store's tables (jobs, API keys; SQLAlchemy 2) and engines; the schema is owned by
Alembic migrations."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from threading import Lock
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    DateTime,
    Engine,
    Float,
    Index,
    Integer,
    String,
    Text,
    create_engine,
    false,
    text,
)
from sqlalchemy import event as sa_event
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

MIGRATIONS = Path(__file__).parent / "migrations"


def utcnow() -> datetime:
    """Naive UTC: SQLite keeps no zone, so every stored time is naive UTC on every database."""
    return datetime.now(UTC).replace(tzinfo=None)


class Base(DeclarativeBase):
    pass


class JobRow(Base):
    __tablename__ = "jobs"

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    kind: Mapped[str] = mapped_column(String(32), index=True)
    tenant: Mapped[str] = mapped_column(String(64), index=True, default="local")
    state: Mapped[str] = mapped_column(String(16), index=True)
    params: Mapped[dict[str, Any]] = mapped_column(JSON)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    max_attempts: Mapped[int] = mapped_column(Integer)
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    stage: Mapped[str] = mapped_column(String(64), default="")
    lease_owner: Mapped[str | None] = mapped_column(String(128), nullable=True)
    lease_expires: Mapped[datetime | None] = mapped_column(DateTime, nullable=True, index=True)
    heartbeat_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)
    cancel_requested: Mapped[bool] = mapped_column(Boolean, default=False)
    idempotency_key: Mapped[str | None] = mapped_column(String(255), nullable=True, unique=True)
    request_hash: Mapped[str | None] = mapped_column(String(64), nullable=True)
    artifacts: Mapped[list[str]] = mapped_column(JSON, default=list)
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime, index=True)
    enqueued_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)
    started_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True, index=True)
    artifacts_deleted_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)
    """When the job's artifacts were deleted (on request or past ``artifact_ttl_s``)."""
    parent: Mapped[str | None] = mapped_column(String(32), nullable=True)
    """The job that made this one (a tile's forest job). A queued job or tile with no
    ``enqueued_at`` is held back by the fair window (:mod:`farm.fair`), not lost."""
    priority: Mapped[int] = mapped_column(Integer, default=5, server_default="5")
    """0-9, higher first among a tenant's held work."""
    cost: Mapped[int] = mapped_column(BigInteger, default=0, server_default="0")
    """Estimated piece-frames (pieces x max(frames, 1)): what the tenant's cost quota sums."""
    tiles: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    """Tile jobs this job makes (0: not tiled): what the tenant's tile quota sums."""
    estimate: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    """The cost estimate made before it was queued (:class:`schemas.jobs.JobCost`)."""
    after: Mapped[list[str] | None] = mapped_column(JSON, nullable=True)
    """Jobs this one waits for (:mod:`farm.graph`): it is held until all have completed."""
    then: Mapped[list[str] | None] = mapped_column(JSON, nullable=True)
    """Jobs that wait for this one."""
    blocked: Mapped[bool] = mapped_column(
        Boolean, default=False, server_default=false(), index=True
    )
    """Still waiting for a job of ``after``: the fair window does not send it."""
    runs: Mapped[list[dict[str, Any]] | None] = mapped_column(JSON, nullable=True)
    """Which worker ran each attempt: ``{"attempt", "worker", "started_at"}`` per claim
    (the lease owner is cleared when a job ends, this is not)."""
    log_dropped: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    """Log lines dropped past the per-job cap (the oldest go first)."""
    webhook_url: Mapped[str | None] = mapped_column(String(2048), nullable=True)
    """Called once the job has ended (:mod:`farm.webhooks`)."""
    webhook_pending: Mapped[bool] = mapped_column(Boolean, default=False, server_default="0")
    """A webhook to deliver (once the job has ended); false once delivered or given up."""
    webhook_attempts: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    webhook_next_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)
    """Not before then: the next try after a failed one, or the lease of one under way."""
    webhook_done_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)
    webhook_error: Mapped[str | None] = mapped_column(Text, nullable=True)

    __table_args__ = (
        Index("ix_jobs_parent_state", "parent", "state", "enqueued_at"),
        Index("ix_jobs_webhook_pending", "webhook_pending", "webhook_next_at"),
    )


class ApiKeyRow(Base):
    """An API key (``farm.keys``): only its SHA-256 digest is stored, never the key."""

    __tablename__ = "api_keys"

    id: Mapped[str] = mapped_column(String(16), primary_key=True)
    """Not secret: names the key in listings and revocations (and is part of the key)."""
    digest: Mapped[str] = mapped_column(String(64), unique=True)
    tenant: Mapped[str] = mapped_column(String(64), index=True)
    admin: Mapped[bool] = mapped_column(Boolean, default=False)
    created_at: Mapped[datetime] = mapped_column(DateTime)
    revoked_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)


class WorkerRow(Base):
    """A worker process (:mod:`farm.workers`): written at start and on every registry
    heartbeat; one not seen for ``worker_timeout_s`` is lost (killed, or its host gone)."""

    __tablename__ = "workers"

    id: Mapped[str] = mapped_column(String(128), primary_key=True)
    """``host:pid:tag``: the lease owner its jobs carry."""
    name: Mapped[str] = mapped_column(String(255))
    """The Celery node name (``--name``)."""
    host: Mapped[str] = mapped_column(String(255))
    pid: Mapped[int] = mapped_column(Integer)
    queues: Mapped[list[str]] = mapped_column(JSON)
    renderer: Mapped[str | None] = mapped_column(String(255), nullable=True)
    """GL_RENDERER of its render jobs' context, or why there is none."""
    current_job: Mapped[str | None] = mapped_column(String(32), nullable=True)
    started_at: Mapped[datetime] = mapped_column(DateTime)
    last_seen: Mapped[datetime] = mapped_column(DateTime, index=True)
    stopped_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)
    """Set when it shut down cleanly (never for a killed one)."""


class JobLogRow(Base):
    """One line of a job's log: stage changes, warnings, errors, timings (:mod:`farm.joblog`)."""

    __tablename__ = "job_logs"

    # INTEGER on SQLite: only that type is its rowid (autoincrement)
    id: Mapped[int] = mapped_column(
        BigInteger().with_variant(Integer(), "sqlite"), primary_key=True, autoincrement=True
    )
    job_id: Mapped[str] = mapped_column(String(32))
    attempt: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    at: Mapped[datetime] = mapped_column(DateTime)
    level: Mapped[str] = mapped_column(String(8))
    message: Mapped[str] = mapped_column(Text)

    __table_args__ = (Index("ix_job_logs_job_id", "job_id", "id"),)


_engines: dict[str, Engine] = {}
SQLITE_LOCK_S = 30  # how long a SQLite file (job store, embedded broker) waits for a lock
_lock = Lock()


def _sqlite_pragmas(dbapi_conn: Any, _record: Any) -> None:
    cur = dbapi_conn.cursor()
    cur.execute("PRAGMA journal_mode=WAL")  # readers never block the one writer
    cur.execute(f"PRAGMA busy_timeout={SQLITE_LOCK_S * 1000}")
    cur.execute("PRAGMA synchronous=NORMAL")
    cur.close()


def engine_for(url: str) -> Engine:
    """One engine per URL and process (SQLite in WAL mode with a busy timeout)."""
    with _lock:
        eng = _engines.get(url)
        if eng is None:
            if url.startswith("sqlite"):
                eng = create_engine(
                    url, connect_args={"timeout": SQLITE_LOCK_S, "check_same_thread": False}
                )
                sa_event.listen(eng, "connect", _sqlite_pragmas)
            else:
                eng = create_engine(url, pool_pre_ping=True)
            _engines[url] = eng
        return eng


def migrate(url: str) -> None:
    """Apply every Alembic migration to ``url`` (idempotent; run on API and worker start)."""
    from alembic import command
    from alembic.config import Config

    if url.startswith("sqlite:///"):
        Path(url.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    eng = engine_for(url)
    with eng.begin() as conn:
        if conn.dialect.name == "postgresql":  # replicas starting together migrate one by one
            conn.execute(text("SELECT pg_advisory_xact_lock(7318450021)"))
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "head")
