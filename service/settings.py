"""Settings of the HTTP API: the farm's (job store, broker, artifacts, leases) plus request caps,
keys, rate limits, hosts and origins, read from ``FOREST_*`` environment variables."""

from __future__ import annotations

from pydantic import Field

from farm.settings import FarmSettings


class ServiceSettings(FarmSettings):
    max_body_bytes: int = Field(4 << 20, gt=0)
    """The largest request body: an upload (a multipart form)."""
    max_json_body_bytes: int = Field(1 << 20, gt=0)
    """The largest body that is not a form (a JSON request, parsed and validated whole): 413
    before it is parsed. A grammar is about 10 KB."""
    body_timeout_s: float = Field(60.0, gt=0)
    """A request body must arrive within this long of its first read (a client trickling an
    upload ties up a connection and its buffers): else 408 and the connection is closed."""
    header_timeout_s: float = Field(10.0, gt=0)
    """A request's line and headers must arrive within this long (slowloris): else 408."""
    keep_alive_s: int = Field(5, ge=1)
    """An idle keep-alive connection is closed after this long (uvicorn)."""
    max_forest_trees: int = Field(10_000, gt=0)
    max_forest_pieces: int = Field(2_000_000, gt=0)
    max_tree_pieces: int = Field(100_000, gt=0)
    max_forest_memory_mb: int = Field(4096, gt=0)
    """Estimated peak memory (MiB, ``forest.cost``) of generating and writing one forest (one
    tile of a tiled one) or one ``POST /v1/trees`` tree; over it: 422 before any work. Keep it
    under ``job_memory_mb``, which also counts address space that is never touched."""
    tree_wait_s: float = Field(30.0, ge=0)
    """``POST /v1/trees`` makes its tree as a job on the workers and waits this long for it:
    done in time, 200 with the file; else 202 with the job (0: always 202 at once)."""
    max_scene_bytes: int = Field(2 << 30, gt=0)
    """Estimated bytes of one scene file (a tiled forest: of each tile); over it: 422."""
    max_frames: int = Field(480, gt=0)
    tenant_max_cost: int = Field(2_000_000_000, gt=0)
    """Estimated piece-frames (expected pieces x max(frames, 1), ``service.quotas``) of one
    tenant's queued and running jobs together: a job past it is refused with 429 (422 if it
    is over on its own). The default is a few hours of one machine's two workers."""
    tenant_max_tiles: int = Field(100_000, gt=0)
    """Tiles of one tenant's queued and running tiled forests together (429/422 as above)."""
    max_image_size: int = Field(4096, gt=0)
    max_render_frames: int = Field(240, gt=0)
    events_max_s: float = Field(300.0, gt=0)
    """``GET /v1/jobs/{id}/events`` ends after this long even while the job runs (a client
    reconnects with ``Last-Event-ID``): no stream holds a connection and a thread for ever."""
    events_poll_s: float = Field(0.5, gt=0)
    """How often an event stream reads its job (and new log lines) from the store."""
    min_free_mb: int = Field(64, ge=0)
    """``/readyz`` answers 503 while the data volume (the artifacts folder's file system) has
    less than this free (MiB; 0: never): a full volume fails every job that writes."""

    api_keys: str = ""
    """Bootstrap keys besides the job store's (``forest keys create``): ``key=tenant`` or
    ``key=tenant:admin`` pairs, comma separated; a request names its key in ``X-API-Key``. No
    key here nor in the store: the API is open (every caller is tenant ``local``) to loopback
    clients only."""
    api_key_cache_s: float = Field(2.0, ge=0)
    """A key found in the job store is trusted this long before it is looked up again: a
    revoked key stops working within this long."""
    rate_limit: str = "20/second;600/minute"
    """Per-key limit of state-changing requests (``limits`` notation; empty: none)."""
    rate_limit_storage: str = "memory://"
    """Where the rate-limit counters live (``redis://...`` to share them between replicas)."""
    auth_failure_limit: str = "20/minute"
    """Wrong keys a client address may send (``limits`` notation; empty: no limit); past it:
    429 with ``Retry-After`` and no store lookup until the window frees. Keys the server
    knows already (bootstrap keys, store keys it found a moment ago) still pass."""
    allowed_hosts: str = ""
    """Host names (comma separated; ``*.example.com`` for subdomains, ``*`` for any; any port)
    a request's ``Host`` may name, else 400: a web page that rebinds its DNS name to this
    server cannot reach it. Empty: ``localhost``, ``127.0.0.1`` and ``[::1]`` while the API is
    open (no key anywhere), any host once it has keys (a key is what guards it then)."""
    allowed_origins: str = ""
    """Browser origins (comma separated) allowed to send state-changing requests; none by
    default, so no web page can submit jobs or uploads cross-site."""
