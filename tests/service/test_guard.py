"""The API's gate, through a real ``forest serve`` (issue 26, defects 8 and 9): a request naming
another host (DNS rebinding: a web page whose name now points at this server) is 400 before
anything runs, and a cross-site write 403; ``/metrics`` needs an admin key once the server has
keys; wrong keys from one address are throttled (429 with Retry-After) without a job-store
lookup each, on SQLite and PostgreSQL; the key of a write is checked before its body is read;
a method a path lacks is 405 with ``Allow``, and OPTIONS answers with it."""

from __future__ import annotations

import socket
import uuid
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from service_harness import PG, Proxy, Server, pg_database, require_server

TENANT = {"X-API-Key": "key-a"}
ADMIN = {"X-API-Key": "key-ops"}
KEYS = "key-a=alpha,key-ops=ops:admin"
FOREST = {"preset": "almond", "seed": 3}


@pytest.fixture(scope="module")
def open_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """No key anywhere: the API answers loopback clients, by their loopback names only."""
    s = Server(tmp_path_factory.mktemp("open"), {}, workers=0).start()
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture(scope="module")
def keyed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    env = {
        "FOREST_API_KEYS": KEYS,
        "FOREST_ALLOWED_HOSTS": "127.0.0.1,*.example.org",
        # a body that never comes would hold the connection this long: the key goes first
        "FOREST_BODY_TIMEOUT_S": "600",
    }
    s = Server(tmp_path_factory.mktemp("keyed"), env, workers=0).start()
    try:
        yield s
    finally:
        s.stop()


def as_host(
    server: Server,
    method: str,
    path: str,
    host: str,
    headers: dict[str, str] | None = None,
    body: object = None,
) -> httpx.Response:
    """A request to ``server`` that names ``host`` in its ``Host`` header."""
    headers = {"Host": host} | (headers or {})
    return httpx.request(method, f"{server.url}{path}", headers=headers, json=body, timeout=30)


def test_rebinding_host_is_refused(open_server: Server) -> None:
    port = open_server.port
    evil = {"Origin": f"http://evil.example:{port}"}
    for method, path, body in (("GET", "/v1/jobs", None), ("POST", "/v1/forests", FOREST)):
        r = as_host(open_server, method, path, f"evil.example:{port}", evil, body)
        assert r.status_code == 400, r.text
        assert r.headers["content-type"] == "application/problem+json"
        assert "evil.example" in r.json()["detail"]  # a string, naming the host
    for host in (f"localhost:{port}", f"127.0.0.1:{port}", f"[::1]:{port}", "LOCALHOST"):
        assert as_host(open_server, "GET", "/v1/jobs", host).status_code == 200, host
    assert open_server.get("/v1/jobs").json()["total"] == 0  # the refused POST made no job
    for host in ("evil.example", "127.0.0.1.evil.example:1", "[::1", "a:b", "localhost:x"):
        assert as_host(open_server, "GET", "/healthz", host).status_code == 400, host


def test_cross_site_write_is_refused(open_server: Server) -> None:
    r = open_server.post("/v1/forests", FOREST, headers={"Origin": "http://evil.example"})
    assert r.status_code == 403 and isinstance(r.json()["detail"], str), r.text
    assert open_server.get("/v1/jobs").json()["total"] == 0


def test_allowed_hosts_setting(keyed: Server) -> None:
    assert as_host(keyed, "GET", "/v1/jobs", "api.example.org:443", TENANT).status_code == 200
    assert as_host(keyed, "GET", "/v1/jobs", "evil.example", TENANT).status_code == 400
    assert as_host(keyed, "GET", "/v1/jobs", "localhost", TENANT).status_code == 400


def test_metrics_need_an_admin_key(keyed: Server, open_server: Server) -> None:
    assert httpx.get(f"{keyed.url}/metrics", timeout=30).status_code == 401
    assert httpx.get(f"{keyed.url}/metrics", headers=TENANT, timeout=30).status_code == 403
    r = httpx.get(f"{keyed.url}/metrics", headers=ADMIN, timeout=30)
    assert r.status_code == 200 and "forest_jobs{" in r.text
    assert open_server.get("/metrics").status_code == 200  # no key anywhere: loopback reads


def test_key_is_checked_before_the_body(keyed: Server) -> None:
    head = (
        b"POST /v1/forests HTTP/1.1\r\nHost: 127.0.0.1\r\nX-API-Key: wrong\r\n"
        b"Content-Type: application/json\r\nContent-Length: 100000\r\n\r\n{"
    )
    # the body never comes: the answer must not wait for it (600 s); 30 s guards a hang
    with socket.create_connection(("127.0.0.1", keyed.port), timeout=30) as sock:
        sock.sendall(head)
        answer = sock.recv(65536)
    assert answer.startswith(b"HTTP/1.1 401 "), answer[:300]
    assert b"application/problem+json" in answer


def test_405_names_every_method_and_options_answers(open_server: Server) -> None:
    r = httpx.put(f"{open_server.url}/v1/jobs/{'0' * 32}", timeout=30)
    assert r.status_code == 405, r.text
    assert set(r.headers["allow"].split(", ")) == {"GET", "DELETE", "OPTIONS"}
    assert isinstance(r.json()["detail"], str)
    r = httpx.patch(f"{open_server.url}/v1/forests", timeout=30)
    assert (r.status_code, r.headers["allow"]) == (405, "OPTIONS, POST")
    r = httpx.options(f"{open_server.url}/v1/forests", timeout=30)
    assert (r.status_code, r.headers["allow"]) == (204, "OPTIONS, POST")


@pytest.fixture(params=["embedded", "postgresql"])
def throttled(
    request: pytest.FixtureRequest, tmp_path: Path
) -> Iterator[tuple[Server, Proxy | None]]:
    """A keyed server allowing 5 wrong keys a minute per address; on PostgreSQL its job store
    is behind a proxy the test can cut."""
    env = {"FOREST_API_KEYS": KEYS, "FOREST_AUTH_FAILURE_LIMIT": "5/minute"}
    if request.param == "embedded":
        s = Server(tmp_path / "data", env, workers=0).start()
        try:
            yield s, None  # the embedded store is a file: it cannot go away
        finally:
            s.stop()
        return
    require_server("PostgreSQL", PG)
    with pg_database(uuid.uuid4().hex[:12]) as url:
        proxy = Proxy(PG)
        env["FOREST_DATABASE_URL"] = url.replace(":5432/", f":{proxy.port}/")
        s = Server(tmp_path / "data", env, workers=0).start()
        try:
            yield s, proxy
        finally:
            s.stop()
            proxy.close()


def test_wrong_keys_are_throttled_per_address(throttled: tuple[Server, Proxy | None]) -> None:
    server, proxy = throttled
    for i in range(5):
        r = server.get("/v1/jobs", headers={"X-API-Key": f"guess-{i}"})
        assert r.status_code == 401, r.text
    for method, path in (("GET", "/v1/jobs"), ("POST", "/v1/forests")):
        r = httpx.request(
            method, f"{server.url}{path}", headers={"X-API-Key": "guess-6"}, json=FOREST, timeout=30
        )
        assert r.status_code == 429, r.text
        assert 1 <= int(r.headers["retry-after"]) <= 60
        assert "wrong API keys" in r.json()["detail"]
    # a key the server knows still passes: the guesses do not lock its owner out
    assert server.get("/v1/jobs", headers=TENANT).status_code == 200
    if proxy is not None:
        proxy.cut()  # the job store is gone: a throttled guess still answers 429, not 503,
        r = server.get("/v1/jobs", headers={"X-API-Key": "guess-7"})  # so it was not looked up
        assert r.status_code == 429, r.text
