"""The HTTP edge of a real ``forest serve`` (uvicorn, embedded backend, no workers): made-up
methods do not grow ``/metrics``; a chunked body over the cap is 413; a client that trickles
its headers or its body is cut off with 408; ``/docs`` and ``/redoc`` load from the service's
own files."""

from __future__ import annotations

import re
import select
import socket
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from service_harness import Server

MAX_BODY = 2000
ENV = {
    "FOREST_MAX_BODY_BYTES": str(MAX_BODY),
    "FOREST_HEADER_TIMEOUT_S": "1",
    "FOREST_BODY_TIMEOUT_S": "1",
}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    s = Server(tmp_path_factory.mktemp("edges"), ENV, workers=0).start()
    try:
        yield s
    finally:
        s.stop()


def series(server: Server) -> list[str]:
    return [
        line
        for line in server.get("/metrics").text.splitlines()
        if line.startswith("forest_http_requests_total{")
    ]


def test_made_up_methods_do_not_grow_metrics(server: Server) -> None:
    for i in range(3):
        httpx.request(f"MADEUP{i}", f"{server.url}/v1/jobs", timeout=10)
        httpx.request(f"MADEUP{i}", f"{server.url}/no/such/{i}", timeout=10)
    series(server)  # the scrape's own series
    before = len(series(server))
    for i in range(3, 40):
        r = httpx.request(f"MADEUP{i}", f"{server.url}/v1/jobs", timeout=10)
        assert r.status_code == 405
        httpx.request(f"MADEUP{i}", f"{server.url}/no/such/{i}", timeout=10)
    lines = series(server)
    assert len(lines) == before, [x for x in lines if "MADEUP" in x][:5]
    assert not [x for x in lines if "MADEUP" in x]
    assert any('method="other"' in x and 'status="405"' in x for x in lines), lines


def test_chunked_body_over_the_cap_is_413(server: Server) -> None:
    # well-formed up to the cap, so no parser can refuse it first (a body that is not
    # multipart at all is 400 or 413 depending on how its chunks arrive)
    json_head, json_tail = b'{"preset": "oak", "seed": 1, "pad": "', b'"}'
    part_head = (
        b"--b0undary\r\n"
        b'Content-Disposition: form-data; name="scene"; filename="scene.usda"\r\n'
        b"Content-Type: application/octet-stream\r\n\r\n#usda 1.0\n"
    )
    part_tail = b"\r\n--b0undary--\r\n"

    def body(head: bytes, tail: bytes) -> Iterator[bytes]:
        yield head  # a generator: httpx sends it chunked, no Content-Length
        for _ in range(10):
            yield b"x" * 500
        yield tail

    for path, ctype, head, tail in (
        ("/v1/forests", "application/json", json_head, json_tail),
        ("/v1/renders/upload", "multipart/form-data; boundary=b0undary", part_head, part_tail),
    ):
        r = httpx.post(
            f"{server.url}{path}",
            content=body(head, tail),
            headers={"content-type": ctype},
            timeout=30,
        )
        assert r.status_code == 413, (path, r.text)
        assert r.json()["errors"][0] == {
            "loc": ["body"],
            "msg": f"body over {MAX_BODY} bytes",
            "type": "too_large",
        }
    # under the cap, chunked, the same route answers as usual
    r = httpx.post(
        f"{server.url}/v1/forests",
        content=iter([b'{"preset": "nope"}']),
        headers={"content-type": "application/json"},
        timeout=30,
    )
    assert r.status_code == 422, r.text


def exchange(server: Server, pieces: list[bytes], gap_s: float) -> bytes:
    """Send ``pieces`` ``gap_s`` apart until the server answers (or hangs up), then read until
    it closes the connection; what it answered. (Sending on after its answer would make its
    kernel reset the connection, which can drop the answer before we read it.)"""
    with socket.create_connection(("127.0.0.1", server.port), timeout=30) as sock:
        try:
            for piece in pieces:
                if select.select([sock], [], [], 0)[0]:
                    break  # it answered
                sock.sendall(piece)
                select.select([sock], [], [], gap_s)
        except OSError:  # the server closed the connection: read what it said
            pass
        answer = b""
        try:
            while chunk := sock.recv(65536):
                answer += chunk
        except ConnectionResetError:
            pass
        return answer


HEAD = (
    b"POST /v1/forests HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
    b"Content-Length: 400\r\n\r\n"
)


def test_trickled_body_is_408(server: Server) -> None:
    # 400 bytes announced, one sent every 0.1 s: the 1 s body timeout cuts it off
    answer = exchange(server, [HEAD] + [b" "] * 400, 0.1)
    assert answer.startswith(b"HTTP/1.1 408 "), answer[:300]
    assert b"connection: close" in answer.lower()
    assert b"body not received within 1 s" in answer


def test_trickled_headers_are_408(server: Server) -> None:
    answer = exchange(server, [bytes([c]) for c in HEAD], 0.1)
    assert answer.startswith(b"HTTP/1.1 408 "), answer[:300]
    assert b"request headers not received in time" in answer


def test_idle_connection_is_closed(server: Server) -> None:
    assert exchange(server, [], 0) == b""  # recv returned: the server hung up, saying nothing


def test_a_prompt_client_is_served_on_one_connection(server: Server) -> None:
    with httpx.Client(base_url=server.url, timeout=30) as client:
        for _ in range(3):
            assert client.get("/healthz").status_code == 200
        r = client.post("/v1/forests", json={"preset": "nope"})
        assert r.status_code == 422, r.text


@pytest.mark.parametrize("page", ["/docs", "/redoc"])
def test_api_docs_load_from_own_files(server: Server, page: str) -> None:
    r = server.get(page)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    html = r.text
    external = re.findall(r"""(?:https?:)?//[\w.-]+\.[a-z]{2,}[^\s"'<>)]*""", html)
    assert external == [], external  # no CDN, no web fonts
    refs = re.findall(r"""(?:src|href|spec-url)=["']([^"']+)["']""", html)
    refs += re.findall(r"""\burl:\s*["']([^"']+)["']""", html)  # Swagger's spec URL
    assert any(ref.endswith(".js") for ref in refs), refs
    assert "/openapi.json" in refs, refs
    for ref in refs:
        assert ref.startswith("/"), ref
        asset = server.get(ref)
        assert asset.status_code == 200 and asset.content, ref
    bundle = Path(__file__).resolve().parents[2] / "service" / "static" / "vendor"
    assert all((bundle / name / "LICENSE").is_file() for name in ("swagger-ui", "redoc"))
