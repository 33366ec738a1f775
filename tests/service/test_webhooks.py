"""Webhooks on every backend: a job that names a ``webhook`` has it called once it ends, a
POST of the job's summary signed with HMAC-SHA256 (``X-Forest-Signature`` over the timestamp
and body); a call answered 500 is tried again (with a back-off) until one answers 2xx, and the
job says so (``webhook``: attempts, delivered, no error) and logs each try; a URL whose host
the server does not allow, or a server without a webhook secret, is 422 on ``webhook`` before
any job is made."""

from __future__ import annotations

import hashlib
import hmac
import json
import threading
import time
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import pytest
from service_harness import Server, served

SECRET = "webhook-test-secret"
ENV = {"FOREST_WEBHOOK_SECRET": SECRET, "FOREST_WEBHOOK_HOSTS": "127.0.0.1,*.example.org"}
BODY = {"preset": "hazel", "trees": 1, "seed": 61, "format": "usdc"}


class Receiver:
    """An HTTP server on loopback that records each call and answers the next status of
    ``answers`` (then 200)."""

    def __init__(self, answers: list[int]) -> None:
        self.calls: list[dict[str, Any]] = []
        self.answers = list(answers)
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                body = self.rfile.read(int(self.headers["Content-Length"]))
                outer.calls.append({"headers": dict(self.headers), "body": body})
                status = outer.answers.pop(0) if outer.answers else 200
                self.send_response(status)
                self.send_header("Content-Length", "0")
                self.end_headers()

            def log_message(self, *args: Any) -> None:
                pass

        self.http = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.http.server_address[1]}/hook"
        threading.Thread(target=self.http.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.http.shutdown()
        self.http.server_close()


@pytest.fixture(scope="module")
def farm(backend: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    yield from served(tmp_path_factory.mktemp("hooks"), backend | ENV)


def test_webhook_called_signed_and_retried(farm: Server) -> None:
    receiver = Receiver([500])
    try:
        job_id = farm.post("/v1/forests", BODY | {"webhook": receiver.url}).json()["id"]
        done = farm.wait(job_id, timeout=120)
        assert done["state"] == "completed", done
        deadline = time.monotonic() + 30
        while (
            farm.get(f"/v1/jobs/{job_id}").json()["webhook"]["pending"]
            and time.monotonic() < deadline
        ):
            time.sleep(0.2)
        job = farm.get(f"/v1/jobs/{job_id}").json()
    finally:
        receiver.close()
    hook = job["webhook"]
    assert hook["url"] == receiver.url and hook["pending"] is False, hook
    assert hook["attempts"] == 2 and hook["delivered_at"] and hook["error"] is None, hook
    assert len(receiver.calls) == 2  # the 500, then the one that was answered 200
    for n, call in enumerate(receiver.calls, 1):
        headers, body = call["headers"], call["body"]
        mac = hmac.new(
            SECRET.encode(), headers["X-Forest-Timestamp"].encode() + b"." + body, hashlib.sha256
        )
        assert headers["X-Forest-Signature"] == f"sha256={mac.hexdigest()}"
        assert headers["X-Forest-Delivery"] == f"{job_id}.{n}"
        sent = json.loads(body)
        assert sent["event"] == "job.ended"
        assert sent["job"]["id"] == job_id and sent["job"]["state"] == "completed"
        assert sent["job"]["artifacts"] == ["scene.usdc"]
    log = [x["message"] for x in farm.get(f"/v1/jobs/{job_id}/log").json()["items"]]
    assert any(
        m.startswith("webhook attempt 1 failed, again in 1 s: answered HTTP 500") for m in log
    )
    assert log[-1] == "webhook called (attempt 2)", log


@pytest.mark.parametrize(
    "url",
    [
        "http://example.com/hook",  # not an allowed host
        "http://evil.org.example.com/hook",
        "https://user:pw@a.example.org/hook",  # credentials in the URL
        "ftp://127.0.0.1/hook",  # the schema's pattern: http(s) only
    ],
)
def test_webhook_host_must_be_allowed(farm: Server, url: str) -> None:
    r = farm.post("/v1/forests", BODY | {"webhook": url})
    assert r.status_code == 422, r.text
    assert r.json()["errors"][0]["loc"] == ["body", "webhook"]
