"""Farm settings: the job store, broker, artifacts, leases and job limits that the API and the
workers share, read from ``FOREST_*`` environment variables (pydantic-settings).

Read them through :func:`get_settings`, which tests override with :func:`override_settings`; the
HTTP API's own settings extend these with request caps, keys and origins.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

from pydantic import Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


class FarmSettings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="FOREST_", frozen=True, extra="ignore")

    data_dir: Path = Path("forest-data")
    """Embedded default: job store, broker and artifacts all live in this folder."""
    database_url: str | None = None
    """SQLAlchemy URL of the job store; default ``sqlite:///<data_dir>/jobs.sqlite``."""
    broker_url: str | None = None
    """Celery broker; default kombu's SQLite transport ``sqla+sqlite:///<data_dir>/broker.sqlite``."""
    artifacts_dir: Path | None = None
    """Shared artifact storage; default ``<data_dir>/artifacts``."""
    queue_prefix: str = ""
    """Prefix of the queue names (``default``, ``gpu``), so clusters or test runs can share a
    broker."""
    quorum_queues: bool = False
    """Declare RabbitMQ quorum queues (replicated, survive a broker node)."""
    broker_visibility_timeout_s: float = Field(3600.0, gt=0)
    """Redis broker: a delivered message not acknowledged within this long goes back to its
    queue (Redis has no connection-bound redelivery). It must outlast the reaper's recovery
    (lease, then the requeue delay), so a dead worker's job is recovered by the reaper; a job
    that runs longer than this is delivered again and the copy skipped (the lease is held)."""

    lease_s: float = Field(30.0, gt=0)
    """A claimed job whose heartbeat is older than this is handed to another worker."""
    heartbeat_s: float = Field(2.0, gt=0)
    """The worker extends its lease (and reads the cancel flag) this often: a canceled job's
    process is killed within about this long."""
    job_memory_mb: int = Field(6144, ge=0)
    """Address-space limit of a job's process (``RLIMIT_AS``, MiB; 0: none): a scene that would
    take more fails as that job's error instead of taking the worker down."""
    job_cpu_s: int = Field(3600, ge=0)
    """CPU-time limit of a job's process (``RLIMIT_CPU``, seconds; 0: none)."""
    max_upload_time_samples: int = Field(10_000, gt=0)
    """Time samples an uploaded scene may author in all (counted before it is read)."""
    max_upload_frames: int = Field(480, gt=0)
    """Time samples (wind frames) of any one attribute of an uploaded scene."""
    max_upload_instances: int = Field(2_000_000, gt=0)
    """Instances of any PointInstancer of an uploaded scene (its arrays measured one at a time
    before the reader runs; any other array may hold 64 values per instance of this cap)."""
    max_upload_bones: int = Field(6_000_000, gt=0)
    """Bones of an uploaded scene's rig (at one time code)."""
    reaper_interval_s: float = Field(5.0, gt=0)
    housekeeping_s: float = Field(300.0, gt=0)
    """The reaper's slower round: scratch folders of dead processes, expired artifacts."""
    artifact_ttl_s: float = Field(0.0, ge=0)
    """A finished job's artifacts are deleted this long after it finished (the job row
    stays, saying so); 0 keeps them for ever."""
    requeue_after_s: float = Field(60.0, gt=0)
    """A queued job this long without a worker is sent to the broker again (lost messages)."""
    max_tiles_in_flight: int = Field(4, ge=1)
    """Jobs and tiles of tiled forests sent to the broker and not finished, all tenants
    together (:mod:`farm.fair`; the name predates untiled jobs joining the window): the rest
    wait in the job table. About twice the job workers."""
    render_chunk_frames: int = Field(8, ge=1)
    """A render job of more frames than this splits into ``render_chunk`` jobs of this many
    frames each, run in parallel on any render worker and joined into the clip and metrics
    (:mod:`farm.chunks`); a render of this many frames or fewer is one job."""
    max_tenant_tiles_in_flight: int = Field(2, ge=1)
    """The same, per tenant: another tenant's job waits behind at most this many of one
    tenant's jobs and tiles. About the number of job workers."""
    max_attempts: int = Field(3, ge=1, le=100)
    retry_delay_s: float = Field(2.0, ge=0)
    worker_heartbeat_s: float = Field(5.0, gt=0)
    """A worker writes its row in the worker registry (last seen, current job) this often."""
    worker_timeout_s: float = Field(30.0, gt=0)
    """A worker not seen for this long is shown ``lost`` (killed, or its host gone); it must
    exceed ``worker_heartbeat_s``."""
    worker_forget_s: float = Field(86400.0, gt=0)
    """A lost or stopped worker's row is deleted this long after it was last seen."""
    job_log_lines: int = Field(1000, ge=10, le=100_000)
    """Log lines kept per job (stage changes, warnings, errors, timings): past it the oldest
    go, and the log says how many."""

    webhook_secret: str = ""
    """The key of the HMAC-SHA256 signature of every webhook call (``X-Forest-Signature``);
    empty: webhooks are off (a request naming one is 422)."""
    webhook_hosts: str = ""
    """Hosts (comma separated; ``*.example.com`` for subdomains) a job's ``webhook`` may name,
    checked when the job is submitted and again before each call; empty: none."""
    webhook_attempts: int = Field(5, ge=1, le=20)
    """Calls of a webhook before it is given up (answers other than 2xx, or none)."""
    webhook_timeout_s: float = Field(10.0, gt=0, le=120)
    """One call's time limit (connect, send, answer)."""

    @model_validator(mode="after")
    def _timeout_after_heartbeats(self) -> FarmSettings:
        if self.worker_timeout_s <= self.worker_heartbeat_s:
            raise ValueError(
                f"worker_timeout_s ({self.worker_timeout_s:g}) must exceed worker_heartbeat_s "
                f"({self.worker_heartbeat_s:g}): a live worker would show as lost"
            )
        return self

    @model_validator(mode="after")
    def _reaper_recovers_first(self) -> FarmSettings:
        floor = self.lease_s + self.requeue_after_s + self.reaper_interval_s
        if self.is_redis and self.broker_visibility_timeout_s <= floor:
            raise ValueError(
                f"broker_visibility_timeout_s ({self.broker_visibility_timeout_s:g}) must "
                f"exceed lease_s + requeue_after_s + reaper_interval_s ({floor:g}): the "
                "reaper, not the broker's redelivery, recovers a dead worker's job"
            )
        return self

    @property
    def is_redis(self) -> bool:
        """The broker is Redis (``redis://``, ``rediss://``, ``redis+socket://``, ``sentinel://``)."""
        return self.broker.split(":", 1)[0].split("+", 1)[0] in ("redis", "rediss", "sentinel")

    @property
    def db_url(self) -> str:
        return self.database_url or f"sqlite:///{self.data_dir.resolve() / 'jobs.sqlite'}"

    @property
    def broker(self) -> str:
        return self.broker_url or f"sqla+sqlite:///{self.data_dir.resolve() / 'broker.sqlite'}"

    @property
    def artifacts(self) -> Path:
        return (self.artifacts_dir or self.data_dir / "artifacts").resolve()

    def queue(self, name: str) -> str:
        return f"{self.queue_prefix}{name}"


_override: FarmSettings | None = None


@cache
def _from_env() -> FarmSettings:
    return FarmSettings()


def get_settings() -> FarmSettings:
    return _override if _override is not None else _from_env()


def override_settings(settings: FarmSettings | None) -> None:
    """Tests: make :func:`get_settings` answer ``settings`` (``None`` restores the env)."""
    global _override
    _override = settings
    _from_env.cache_clear()
