"""Methods of a path: a request whose path is an API route's but whose method is none of that
path's answers 405 with an ``Allow`` header naming every method of the path, and ``OPTIONS``
answers 204 with it. The router alone does not: it tries the routes in order and the web
page's mount at ``/`` (static files: GET and HEAD) takes any request that no route fully
matched, so its 405 named GET and HEAD whatever the path had."""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from typing import Any

from starlette.responses import Response
from starlette.routing import BaseRoute, compile_path
from starlette.types import ASGIApp, Receive, Scope, Send

from service.errors import problem


def route_methods(routes: Sequence[BaseRoute]) -> list[tuple[re.Pattern[str], frozenset[str]]]:
    """Each route's path pattern and methods, routers included with a prefix flattened."""
    contexts: Iterable[Any]
    try:
        from fastapi.routing import iter_route_contexts

        contexts = iter_route_contexts(routes)
    except ImportError:  # a FastAPI that keeps included routes in the list itself
        contexts = routes
    found = []
    for route in contexts:
        path, methods = getattr(route, "path", None), getattr(route, "methods", None)
        if path and methods:
            found.append((compile_path(path)[0], frozenset(methods)))
    return found


class AllowedMethods:
    def __init__(self, app: ASGIApp, routes: Sequence[BaseRoute]) -> None:
        self.app, self.routes = app, routes
        self.table: list[tuple[re.Pattern[str], frozenset[str]]] | None = None

    def methods(self, scope: Scope) -> set[str]:
        if self.table is None:  # on the first request: every route is added by then
            self.table = route_methods(self.routes)
        path = scope["path"].removeprefix(scope.get("root_path", ""))
        return {m for pattern, methods in self.table if pattern.match(path) for m in methods}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            methods = self.methods(scope)
            if methods and scope["method"] not in methods:
                allow = {"Allow": ", ".join(sorted(methods | {"OPTIONS"}))}
                if scope["method"] == "OPTIONS":
                    await Response(status_code=204, headers=allow)(scope, receive, send)
                else:
                    detail = f"{scope['method']} is not a method of this path"
                    await problem(405, detail, allow)(scope, receive, send)
                return
        await self.app(scope, receive, send)
