"""Request body limits: size and time.

Size: 413 before the body is read when Content-Length says so, and while reading when a
chunked body grows past the cap; a body that is not a form (JSON, which is parsed and validated
whole, in memory) has a smaller cap than an upload's, so no request's JSON costs more than a
small one to refuse. Time: a body not received within ``timeout_s`` of its first
read (a client trickling bytes, or one that stops sending) is cut off with 408, and the
connection closed. Both answer in place of whatever the app says once it has seen the error
(FastAPI turns any error while it parses a body into 400)."""

from __future__ import annotations

import asyncio
import time

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.errors import PROBLEM_JSON, problem_bytes

FORMS = (b"multipart/form-data", b"application/x-www-form-urlencoded")


class BodyRefused(Exception):
    def __init__(self, status: int, msg: str, kind: str) -> None:
        super().__init__(msg)
        self.status, self.msg, self.kind = status, msg, kind


class BodyLimitMiddleware:
    def __init__(
        self,
        app: ASGIApp,
        max_bytes: int,
        timeout_s: float | None = None,
        max_json_bytes: int | None = None,
    ) -> None:
        self.app, self.max_bytes, self.timeout_s = app, max_bytes, timeout_s
        self.max_json_bytes = min(max_bytes, max_json_bytes or max_bytes)

    @staticmethod
    def too_large(cap: int) -> BodyRefused:
        return BodyRefused(413, f"body over {cap} bytes", "too_large")

    @staticmethod
    async def _reject(send: Send, refused: BodyRefused) -> None:
        body = problem_bytes(
            refused.status,
            refused.msg,
            errors=[{"loc": ["body"], "msg": refused.msg, "type": refused.kind}],
        )
        await send(
            {
                "type": "http.response.start",
                "status": refused.status,
                "headers": [
                    (b"content-type", PROBLEM_JSON.encode()),
                    (b"content-length", str(len(body)).encode()),
                    # the rest of the body is never read: the connection cannot be reused
                    (b"connection", b"close"),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = scope.get("headers", [])
        form = any(n == b"content-type" and v.lower().startswith(FORMS) for n, v in headers)
        cap = self.max_bytes if form else self.max_json_bytes
        for name, value in headers:
            if name == b"content-length":
                try:
                    too_big = int(value) > cap
                except ValueError:
                    too_big = False
                if too_big:
                    await self._reject(send, self.too_large(cap))
                    return
        seen = 0
        deadline: float | None = None
        body_done = started = replaced = False
        refused: BodyRefused | None = None

        async def limited() -> Message:
            nonlocal seen, deadline, body_done, refused
            if body_done or self.timeout_s is None:
                # after the body, receive() waits for the disconnect (streamed responses
                # listen for it): no deadline then
                message = await receive()
            else:
                if deadline is None:
                    deadline = time.monotonic() + self.timeout_s
                try:
                    message = await asyncio.wait_for(receive(), deadline - time.monotonic())
                except TimeoutError:
                    refused = BodyRefused(
                        408, f"body not received within {self.timeout_s:g} s", "timeout"
                    )
                    raise refused from None
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                body_done = not message.get("more_body", False)
                if seen > cap:
                    refused = self.too_large(cap)
                    raise refused
            return message

        async def tracking(message: Message) -> None:
            nonlocal started, replaced
            if refused is not None and (replaced or not started):
                if not replaced:
                    started = replaced = True
                    await self._reject(send, refused)
                return
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited, tracking)
        except BodyRefused as exc:
            if not started:
                started = True
                await self._reject(send, exc)
