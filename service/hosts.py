"""The ``Host`` allow-list: a request must name this server by one of its names, so a web page
whose DNS name is rebound to this server's address (DNS rebinding: the browser then sends the
page's own name as ``Host``, and treats the answers as same-origin) is refused (400) before
anything runs. Starlette's ``TrustedHostMiddleware`` does not fit: its list is fixed at start,
where the default here follows whether the API has keys, and it answers in plain text."""

from __future__ import annotations

from collections.abc import Callable
from urllib.parse import urlsplit

from sqlalchemy.exc import DBAPIError
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import Headers
from starlette.requests import Request
from starlette.types import ASGIApp, Receive, Scope, Send

from service.errors import database_unavailable, problem

LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})


def host_name(header: str | None) -> str | None:
    """The name of a ``Host`` header, lower case, without its port or an IPv6 literal's
    brackets; None when it is missing or malformed."""
    if not header or any(c in header for c in "/?#@\\ "):
        return None
    try:
        parts = urlsplit(f"//{header}")
        parts.port  # noqa: B018 (raises on a port that is not a number in range)
    except ValueError:
        return None
    return parts.hostname or None


def matches(name: str, pattern: str) -> bool:
    """``pattern``: a name, ``*.example.com`` (its subdomains) or ``*`` (any)."""
    if pattern == "*":
        return True
    if pattern.startswith("*."):
        return name.endswith(pattern[1:])
    return name == pattern


class AllowedHosts:
    """400 for a request whose ``Host`` is not allowed: ``allowed`` (comma separated) when
    set, else the loopback names while ``is_open()`` (the API has no key), any host once it
    has keys."""

    def __init__(self, app: ASGIApp, allowed: str, is_open: Callable[[], bool]) -> None:
        self.app, self.is_open = app, is_open
        self.allowed = [h.strip().lower().strip("[]") for h in allowed.split(",") if h.strip()]

    async def _allowed(self, name: str | None) -> bool:
        if name is None:
            return False
        if self.allowed:
            return any(matches(name, p) for p in self.allowed)
        # the store says whether the API is open (cached a moment): only for other names
        return name in LOOPBACK_NAMES or not await run_in_threadpool(self.is_open)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket"):
            header = Headers(scope=scope).get("host")
            try:
                allowed = await self._allowed(host_name(header))
            except DBAPIError as exc:
                await (await database_unavailable(Request(scope), exc))(scope, receive, send)
                return
            if not allowed:
                detail = f"Host {header!r} is not a name of this server (FOREST_ALLOWED_HOSTS)"
                await problem(400, detail)(scope, receive, send)
                return
        await self.app(scope, receive, send)
