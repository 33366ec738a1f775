"""Clean answers to bad input, through a real ``forest serve``: a job id no job can have (a NUL,
a control character, too long) is 404 in the path and 422 in a body on every backend, never
503 (PostgreSQL refuses a NUL in text); a NUL or a lone surrogate in any field is 422 naming
the field, never 500 nor a stored job; a grammar named in any script downloads with an RFC
6266 ``filename*``; a large invalid body is refused before it is parsed, or answered without
echoing it; every error, Starlette's own 404 and 405 included, is one RFC 9457 problem."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import unquote

import httpx
import pytest
from service_harness import Server

KEY = {"X-API-Key": "key-a"}
ENV = {"FOREST_API_KEYS": "key-a=alpha"}
BAD_IDS = [
    "a%00b",  # NUL: PostgreSQL's text refuses it
    "%00",
    "a%01b",
    "a%7Fb",
    "a%0Ab",
    "a%E5%90%8Db",  # printable, but no job id
    "x" * 65,
    "f" * 4000,
]


@pytest.fixture(scope="module")
def server(backend: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    s = Server(tmp_path_factory.mktemp("clean"), backend | ENV, workers=0).start()
    s.headers = dict(KEY)
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture(scope="module")
def plain(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """The embedded backend, for what does not depend on the job store."""
    s = Server(tmp_path_factory.mktemp("plain"), ENV, workers=0).start()
    s.headers = dict(KEY)
    try:
        yield s
    finally:
        s.stop()


def problem(r: httpx.Response, status: int) -> dict[str, Any]:
    """The RFC 9457 problem ``r`` carries, checked against ``status``."""
    assert r.status_code == status, r.text[:2000]
    assert r.headers["content-type"] == "application/problem+json", r.headers
    body: dict[str, Any] = r.json()
    assert body["status"] == status and body["type"] == "about:blank", body
    assert isinstance(body["title"], str) and body["title"], body
    assert isinstance(body["detail"], str) and body["detail"], body
    return body


def raw_post(server: Server, path: str, text: str) -> httpx.Response:
    """``text`` as the JSON body, unchanged (``\\ud800`` and ``\\u0000`` escapes kept)."""
    return httpx.post(
        f"{server.url}{path}",
        content=text.encode(),
        headers=KEY | {"content-type": "application/json"},
        timeout=60,
    )


def grammar(server: Server, name: str = "oak") -> dict[str, Any]:
    presets = server.get("/v1/presets").json()["items"]
    found: dict[str, Any] = next(p["grammar"] for p in presets if p["name"] == name)
    return found


def test_unstorable_job_ids_are_404_not_503(server: Server) -> None:
    for job in BAD_IDS:
        for method, path in (
            ("GET", f"/v1/jobs/{job}"),
            ("DELETE", f"/v1/jobs/{job}"),
            ("DELETE", f"/v1/jobs/{job}/artifacts"),
            ("GET", f"/v1/jobs/{job}/artifacts/preview.png"),
        ):
            r = httpx.request(method, f"{server.url}{path}", headers=KEY, timeout=30)
            assert problem(r, 404)["detail"] == "no such job", (method, path)
            assert "retry-after" not in r.headers
    assert server.get("/readyz").status_code == 200
    # a well-formed id of no job is still asked of the store: 404 too
    assert problem(server.get(f"/v1/jobs/{'0' * 32}"), 404)["detail"] == "no such job"


def test_unstorable_forest_job_in_a_render_is_422(server: Server) -> None:
    for job in ("a\u0000b", "\u0000", "a\u0001b", "a b", "x" * 65, "a\u540db"):
        r = server.post("/v1/renders", {"forest_job": job})
        body = problem(r, 422)
        assert body["errors"][0]["loc"] == ["body", "forest_job"], body
        assert body["errors"][0]["pointer"] == "#/forest_job", body
    r = raw_post(server, "/v1/renders", '{"forest_job": "a\\ud800b"}')
    assert problem(r, 422)["errors"][0]["loc"] == ["body", "forest_job"]
    assert server.get("/readyz").status_code == 200


def test_nul_or_lone_surrogate_in_any_field_is_422_naming_it(server: Server) -> None:
    g = grammar(server)
    for text in ("a\\u0000b", "\\ud800", "a\\udfffb"):
        cases = [
            ("/v1/trees", f'{{"preset": "{text}"}}', ["body", "preset"]),
            ("/v1/forests", f'{{"preset": "{text}", "trees": 1}}', ["body", "preset"]),
            (
                "/v1/forests",
                json.dumps({"grammar": g, "trees": 1})[:-1] + f', "x{text}": 1}}',
                ["body"],  # a key: the object holding it is named
            ),
        ]
        named = json.dumps({"grammar": g | {"name": "@"}, "trees": 1}).replace('"@"', f'"{text}"')
        cases.append(("/v1/forests", named, ["body", "grammar", "name"]))
        for path, body_text, loc in cases:
            r = raw_post(server, path, body_text)
            body = problem(r, 422)
            assert body["errors"][0]["loc"] == loc, (path, body_text[:80], body)
            r.content.decode("utf-8")  # strict UTF-8, whatever came in
    # nothing was stored: no job holds such a name
    assert server.get("/v1/jobs").json()["total"] == 0


def test_a_grammar_named_in_any_script_downloads(tmp_path: Path) -> None:
    # a tree is a job: this server has a worker to make it
    s = Server(tmp_path / "data", ENV, workers=1).start()
    s.headers = dict(KEY)
    try:
        g = grammar(s, "hazel") | {"name": 'a名 "x";y'}
        r = s.post("/v1/trees", {"grammar": g, "format": "usda"})
    finally:
        s.stop()
    assert r.status_code == 200, r.text[:2000]
    cd = r.headers["content-disposition"]
    assert cd.startswith('attachment; filename="a___x__y-0.usda"; '), cd
    star = cd.split("filename*=", 1)[1]
    assert star.startswith("UTF-8''"), cd
    assert unquote(star.removeprefix("UTF-8''"), errors="strict") == 'a名 "x";y-0.usda'
    assert cd.isascii()


def test_a_large_invalid_body_is_refused_before_parsing(plain: Server) -> None:
    seeds = json.dumps({"preset": "oak", "seed": [1] * 2_000_000}).encode()  # 6 MB
    assert len(seeds) > 4 << 20
    healthy: list[int] = []

    def probe() -> None:
        healthy.append(httpx.get(f"{plain.url}/healthz", timeout=30).status_code)

    r = httpx.post(
        f"{plain.url}/v1/trees",
        content=seeds,
        headers=KEY | {"content-type": "application/json"},
        timeout=60,
    )
    body = problem(r, 413)
    assert len(r.content) < 1000, len(r.content)
    assert body["errors"][0]["type"] == "too_large"
    # under the JSON cap (1 MiB): parsed, 422, and nothing of it echoed
    seeds = json.dumps({"preset": "oak", "seed": [1] * 80_000}).encode()
    thread = threading.Thread(target=probe)
    thread.start()
    r = httpx.post(
        f"{plain.url}/v1/trees",
        content=seeds,
        headers=KEY | {"content-type": "application/json"},
        timeout=60,
    )
    thread.join(60)
    body = problem(r, 422)
    assert len(r.content) < 2000, r.text[:3000]
    assert body["errors"][0]["loc"] == ["body", "seed"] and "input" not in body["errors"][0]
    assert healthy == [200]
    # a short input is still echoed
    body = problem(plain.post("/v1/trees", {"preset": "oak", "seed": "x"}), 422)
    assert body["errors"][0]["input"] == "x"


def test_a_long_field_name_is_not_echoed(plain: Server) -> None:
    """An unknown field's name is the client's text: a 900 KB one was echoed three times (in
    ``detail``, ``loc`` and ``pointer``: a 2.7 MB answer)."""
    name = "x" * 900_000
    r = raw_post(plain, "/v1/forests", json.dumps({"preset": "oak", name: 1}))
    body = problem(r, 422)
    assert len(r.content) < 5000, len(r.content)
    [err] = body["errors"]
    assert err["type"] == "extra_forbidden", err
    assert err["loc"][0] == "body" and err["loc"][1].startswith("xxx"), err
    assert err["loc"][1].endswith("\u2026") and err["pointer"].endswith("\u2026"), err


def test_the_number_of_errors_is_capped(plain: Server) -> None:
    r = plain.post("/v1/trees", {f"field{i}": i for i in range(500)} | {"preset": "oak"})
    body = problem(r, 422)
    assert len(body["errors"]) == 20 and body["errors_left_out"] == 480, body
    assert body["detail"].endswith("(and 499 more errors)"), body["detail"]
    assert len(r.content) < 10_000


def test_every_error_is_one_problem_shape(plain: Server) -> None:
    url = plain.url
    problem(httpx.get(f"{url}/v1/jobs/{'0' * 32}", headers=KEY), 404)
    problem(httpx.get(f"{url}/v1/no/such/route", headers=KEY), 404)
    problem(httpx.get(f"{url}/no/such/file.js"), 404)
    r = httpx.put(f"{url}/v1/jobs", headers=KEY)
    problem(r, 405)
    assert "GET" in r.headers["allow"].split(", "), r.headers
    r = httpx.get(f"{url}/v1/jobs", headers={"X-API-Key": "wrong"})
    problem(r, 401)
    assert r.headers["www-authenticate"] == "ApiKey"
    r = httpx.post(
        f"{url}/v1/forests",
        json={"preset": "oak"},
        headers=KEY | {"Origin": "https://evil.example"},
    )
    problem(r, 403)
    r = plain.post("/v1/trees", {"preset": "oak", "seed": -1})
    body = problem(r, 422)
    assert body["detail"] == "seed: Input should be greater than or equal to 0", body
    assert body["errors"][0]["loc"] == ["body", "seed"]
    # a body that is no JSON at all
    r = httpx.post(
        f"{url}/v1/trees", content=b"{", headers=KEY | {"content-type": "application/json"}
    )
    problem(r, 422)
    key = {"Idempotency-Key": "clean-1"}
    assert plain.post("/v1/forests", {"preset": "oak"}, headers=key).status_code == 202
    problem(plain.post("/v1/forests", {"preset": "oak", "seed": 2}, headers=key), 409)
    r = httpx.get(f"{url}/v1/jobs?limit=0", headers=KEY)
    assert problem(r, 422)["errors"][0]["loc"] == ["query", "limit"]
    assert "pointer" not in r.json()["errors"][0]  # a pointer points into the body only
