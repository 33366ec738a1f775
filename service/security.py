"""Who is calling: API keys -> callers (tenant, admin scope), per-key rate limits, and no
cross-site writes.

Keys live in the job store (``farm.keys``: ``forest keys create/list/revoke``, SHA-256 digests
only); ``FOREST_API_KEYS`` may add ``key=tenant`` (or ``key=tenant:admin``) pairs as a
bootstrap. A request names its key in the ``X-API-Key`` header and every ``/v1`` route depends
on :func:`caller`: 401 without a live key; the presets, public data that a page lists before a
key is pasted, depend on :func:`public` instead (no key needed). A key found in the store is
trusted for ``FOREST_API_KEY_CACHE_S`` (2 s) before it is looked up again, so a revocation
takes effect within that long. An admin key sees, cancels and downloads every tenant's jobs;
any other key only its own tenant's (404 for the rest). With no key anywhere (none in the
settings, none ever made in the store: revoking the last key closes the API, it does not open
it) the API is open, every caller is the tenant ``local``, and only loopback clients are
answered (403 for the rest): the embedded default for one machine, which says so at start.

State-changing requests (POST, PUT, PATCH, DELETE) are rate limited per key with the
``limits`` library (moving window; ``FOREST_RATE_LIMIT``, storage ``FOREST_RATE_LIMIT_STORAGE``,
``memory://`` or a shared ``redis://`` for several API replicas), answered 429 with
``Retry-After``; and refused (403) when a browser sends them from another site (an ``Origin``
not in ``FOREST_ALLOWED_ORIGINS``, which is empty by default), so no web page can submit
uploads or cancel jobs with a user's ambient access.
"""

from __future__ import annotations

import hashlib
import hmac
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, HTTPException, Request
from fastapi.security import APIKeyHeader
from limits import RateLimitItem, parse_many
from limits.storage import storage_from_string
from limits.strategies import MovingWindowRateLimiter
from starlette.types import ASGIApp, Receive, Scope, Send

from farm.keys import KeyStore, check_tenant, digest
from service.errors import PROBLEM_JSON, problem_bytes
from service.settings import ServiceSettings

OPEN_TENANT = "local"
WRITES = frozenset({"POST", "PUT", "PATCH", "DELETE"})
api_key_header = APIKeyHeader(
    name="X-API-Key",
    auto_error=False,
    description="API key (`forest keys create`); not needed when the server has no keys.",
)
LOOPBACK = frozenset({"::1", "localhost"})  # and 127.0.0.0/8, also IPv4-mapped


@dataclass(frozen=True)
class Caller:
    tenant: str
    """Owner of the jobs this caller submits."""
    admin: bool = False

    @property
    def scope(self) -> str | None:
        """The tenant whose jobs this caller may see; None: every tenant's (admin)."""
        return None if self.admin else self.tenant


def is_loopback(host: str | None) -> bool:
    return host is not None and (
        host in LOOPBACK or host.removeprefix("::ffff:").startswith("127.")
    )


def _bootstrap(pairs: str) -> dict[str, Caller]:
    """``FOREST_API_KEYS``: digest -> caller."""
    callers: dict[str, Caller] = {}
    for pair in pairs.split(","):
        if not pair.strip():
            continue
        key, sep, who = pair.strip().partition("=")
        tenant, _, scope = who.partition(":")
        if not sep or not key or not tenant or scope not in ("", "admin"):
            raise ValueError(
                "FOREST_API_KEYS: give key=tenant or key=tenant:admin pairs, comma separated"
            )
        callers[digest(key)] = Caller(check_tenant(tenant), admin=scope == "admin")
    return callers


class Keys:
    """Finds the caller of a key: the bootstrap keys of the settings, then the job store's
    live keys (each found one trusted for ``api_key_cache_s``)."""

    def __init__(
        self,
        settings: ServiceSettings,
        store: KeyStore,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.bootstrap = _bootstrap(settings.api_keys)
        self.store, self.ttl, self.clock = store, settings.api_key_cache_s, clock
        self._found: dict[str, tuple[float, Caller]] = {}  # digest -> (trusted until, caller)
        self._open: tuple[float, bool] = (-math.inf, False)  # (known until, open)

    def open(self) -> bool:
        """No key anywhere: no bootstrap key and none ever made in the store."""
        if self.bootstrap:
            return False
        until, is_open = self._open
        now = self.clock()
        if now >= until:
            is_open = not self.store.has_keys()
            self._open = (now + self.ttl, is_open)
        return is_open

    def caller(self, key: str | None) -> Caller | None:
        """The key's caller; ``Caller(local)`` when the API is open; None: no such live key."""
        if self.open():
            return Caller(OPEN_TENANT)
        if not key:
            return None
        d = digest(key)
        found = None
        for known, who in self.bootstrap.items():  # every digest compared: constant time
            if hmac.compare_digest(known, d):
                found = who
        if found is not None:
            return found
        now = self.clock()
        cached = self._found.get(d)
        if cached is not None and now < cached[0]:
            return cached[1]
        # an unknown key is looked up every time (not cached), so a new key works at once
        live = self.store.lookup(key)
        if live is None:
            self._found.pop(d, None)
            return None
        who = Caller(live.tenant, live.admin)
        self._found[d] = (now + self.ttl, who)
        return who


class RateLimit:
    """Per-key moving-window limits on state-changing requests."""

    def __init__(self, settings: ServiceSettings) -> None:
        self.items: list[RateLimitItem] = (
            parse_many(settings.rate_limit) if settings.rate_limit else []
        )
        self.limiter = MovingWindowRateLimiter(storage_from_string(settings.rate_limit_storage))

    def hit(self, who: str) -> None:
        """Raise 429 (with Retry-After) when ``who`` is over a limit."""
        for item in self.items:
            if not self.limiter.hit(item, who):
                reset = self.limiter.get_window_stats(item, who).reset_time
                wait = max(1, math.ceil(reset - time.time()))
                raise HTTPException(
                    429,
                    f"rate limit {item} exceeded; retry in {wait} s",
                    headers={"Retry-After": str(wait)},
                )


def _loopback_when_open(request: Request) -> None:
    """403 for a client off loopback while the API is open (no key anywhere)."""
    if request.app.state.services.keys.open() and not is_loopback(
        request.client.host if request.client else None
    ):
        raise HTTPException(
            403,
            "this server has no API keys and answers loopback clients only; "
            "create a key with `forest keys create`",
        )


def public(request: Request) -> None:
    """A route anyone may read, key or not (the presets); an open server still answers
    loopback clients only."""
    _loopback_when_open(request)


def caller(request: Request, key: Annotated[str | None, Depends(api_key_header)] = None) -> Caller:
    """The caller (401 without a live key, 403 off loopback when the API is open, 429 over the
    rate limit)."""
    services = request.app.state.services
    who: Caller | None = services.keys.caller(key)
    if who is None:
        raise HTTPException(
            401, "a valid X-API-Key header is required", headers={"WWW-Authenticate": "ApiKey"}
        )
    _loopback_when_open(request)
    if request.method in WRITES:
        # per key (a tenant's keys are limited apart); the open server limits its one caller
        who_key = hashlib.sha256((key or OPEN_TENANT).encode()).hexdigest()[:32]
        services.rate_limit.hit(who_key)
    return who


def caller_tenant(who: Annotated[Caller, Depends(caller)]) -> str:
    """The caller's tenant: the owner of what it submits."""
    return who.tenant


CallerDep = Annotated[Caller, Depends(caller)]
Tenant = Annotated[str, Depends(caller_tenant)]


class SameSiteWrites:
    """Refuse (403) a state-changing request whose ``Origin`` (or ``Sec-Fetch-Site``) says a
    browser sends it from another site, unless that origin is allowed."""

    def __init__(self, app: ASGIApp, allowed: frozenset[str]) -> None:
        self.app, self.allowed = app, allowed

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] in WRITES:
            headers = dict(scope.get("headers", []))
            origin = headers.get(b"origin", b"").decode("latin-1")
            fetch_site = headers.get(b"sec-fetch-site", b"").decode("latin-1")
            host = headers.get(b"host", b"").decode("latin-1")
            foreign = (
                bool(origin) and origin not in self.allowed and (origin.split("://", 1)[-1] != host)
            )
            if foreign or (fetch_site == "cross-site" and origin not in self.allowed):
                body = problem_bytes(403, "cross-site requests that change state are refused")
                await send(
                    {
                        "type": "http.response.start",
                        "status": 403,
                        "headers": [
                            (b"content-type", PROBLEM_JSON.encode()),
                            (b"content-length", str(len(body)).encode()),
                        ],
                    }
                )
                await send({"type": "http.response.body", "body": body})
                return
        await self.app(scope, receive, send)
