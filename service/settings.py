"""Service settings: one pydantic-settings class read from ``FOREST_*`` environment variables.

Everything a deployment changes is here (URLs, folders, caps, lease timing); read it through
:func:`get_settings`, which tests override with :func:`override_settings`.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

from pydantic import Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


class ServiceSettings(BaseSettings):
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
    reaper_interval_s: float = Field(5.0, gt=0)
    requeue_after_s: float = Field(60.0, gt=0)
    """A queued job this long without a worker is sent to the broker again (lost messages)."""
    max_attempts: int = Field(3, ge=1, le=100)
    retry_delay_s: float = Field(2.0, ge=0)

    max_body_bytes: int = Field(4 << 20, gt=0)
    max_forest_trees: int = Field(10_000, gt=0)
    max_forest_pieces: int = Field(2_000_000, gt=0)
    max_tree_pieces: int = Field(100_000, gt=0)
    max_frames: int = Field(480, gt=0)
    max_image_size: int = Field(4096, gt=0)
    max_render_frames: int = Field(240, gt=0)

    api_keys: str = ""
    """``key=tenant`` pairs, comma separated; a request names its key in ``X-API-Key``. Empty:
    the API is open (every caller is tenant ``local``): for one machine only."""
    rate_limit: str = "20/second;600/minute"
    """Per-key limit of state-changing requests (``limits`` notation; empty: none)."""
    rate_limit_storage: str = "memory://"
    """Where the rate-limit counters live (``redis://...`` to share them between replicas)."""
    allowed_origins: str = ""
    """Browser origins (comma separated) allowed to send state-changing requests; none by
    default, so no web page can submit jobs or uploads cross-site."""

    test_hook: str = ""
    """Test hook of a job's process: ``abort-on-read`` (the reader crashes),
    ``hold-gil:SECONDS`` (a C call holding the GIL before drawing). Empty in production."""
    test_pause_s: float = Field(0.0, ge=0)
    """Test hook: a job's first attempt pauses this long after it is claimed (heartbeating,
    checking cancel), so a test can kill or cancel it mid-task. 0 in production."""

    @model_validator(mode="after")
    def _reaper_recovers_first(self) -> ServiceSettings:
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


_override: ServiceSettings | None = None


@cache
def _from_env() -> ServiceSettings:
    return ServiceSettings()


def get_settings() -> ServiceSettings:
    return _override if _override is not None else _from_env()


def override_settings(settings: ServiceSettings | None) -> None:
    """Tests: make :func:`get_settings` answer ``settings`` (``None`` restores the env)."""
    global _override
    _override = settings
    _from_env.cache_clear()
