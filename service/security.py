"""Who is calling: API keys -> tenants, per-key rate limits, and no cross-site writes.

``FOREST_API_KEYS`` lists ``key=tenant`` pairs (comma separated); a request names its key in
the ``X-API-Key`` header and every route depends on :func:`caller_tenant`, which yields the
caller's tenant (401 without a known key). With no keys configured the API is open and every
caller is the tenant ``local``: the embedded default for one machine, which says so at start.
Keys are kept as SHA-256 digests in memory and compared in constant time.

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
import json
import math
import time
from typing import Annotated

from fastapi import Depends, HTTPException, Request
from fastapi.security import APIKeyHeader
from limits import RateLimitItem, parse_many
from limits.storage import storage_from_string
from limits.strategies import MovingWindowRateLimiter
from starlette.types import ASGIApp, Receive, Scope, Send

from service.settings import ServiceSettings

OPEN_TENANT = "local"
WRITES = frozenset({"POST", "PUT", "PATCH", "DELETE"})
api_key_header = APIKeyHeader(
    name="X-API-Key",
    auto_error=False,
    description="API key (FOREST_API_KEYS); not needed when the server runs without keys.",
)


def _digest(key: str) -> bytes:
    return hashlib.sha256(key.encode("utf-8", "surrogatepass")).digest()


class Keys:
    """The configured keys as digest -> tenant; empty: the API is open."""

    def __init__(self, settings: ServiceSettings) -> None:
        self.tenants: dict[bytes, str] = {}
        for pair in settings.api_keys.split(","):
            if not pair.strip():
                continue
            key, sep, tenant = pair.strip().partition("=")
            if not sep or not key or not tenant:
                raise ValueError("FOREST_API_KEYS: give key=tenant pairs, comma separated")
            self.tenants[_digest(key)] = tenant[:64]

    @property
    def open(self) -> bool:
        return not self.tenants

    def tenant(self, key: str | None) -> str | None:
        if self.open:
            return OPEN_TENANT
        if not key:
            return None
        d = _digest(key)
        found = None
        for digest, tenant in self.tenants.items():  # every digest compared: constant time
            if hmac.compare_digest(digest, d):
                found = tenant
        return found


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


def caller_tenant(
    request: Request, key: Annotated[str | None, Depends(api_key_header)] = None
) -> str:
    """The caller's tenant (401 without a valid key, 429 over the rate limit)."""
    services = request.app.state.services
    tenant = services.keys.tenant(key)
    if tenant is None:
        raise HTTPException(
            401, "a valid X-API-Key header is required", headers={"WWW-Authenticate": "ApiKey"}
        )
    if request.method in WRITES:
        # per key (a tenant's keys are limited apart); the open server limits its one caller
        who = hashlib.sha256((key or OPEN_TENANT).encode()).hexdigest()[:32]
        services.rate_limit.hit(who)
    return tenant


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
            foreign = bool(origin) and origin not in self.allowed and (
                origin.split("://", 1)[-1] != host
            )
            if foreign or (fetch_site == "cross-site" and origin not in self.allowed):
                body = json.dumps(
                    {"detail": "cross-site requests that change state are refused"}
                ).encode()
                await send({
                    "type": "http.response.start",
                    "status": 403,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(body)).encode())],
                })
                await send({"type": "http.response.body", "body": body})
                return
        await self.app(scope, receive, send)
