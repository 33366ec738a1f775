"""schemathesis over the published OpenAPI, signed in with an API key, on the embedded backend
and on PostgreSQL + Redis: no 5xx (PostgreSQL refuses a NUL that SQLite takes), responses match
their schemas (every error a problem), content types and status codes are documented (a
bounded number of examples, fixed seed). JSON cannot carry NaN or Infinity, so schemathesis
never sends them: a second pass takes the bodies it generates for each JSON operation and
writes ``NaN``, ``Infinity``, ``-Infinity`` or ``1e400`` (Python's JSON reads all four) into
one of their numbers: each is 422 naming that field, never 5xx; so is each number field of the
multipart upload form."""

from __future__ import annotations

import json
import subprocess
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from service_harness import (
    PG,
    REDIS,
    REDIS_URL,
    Server,
    delete_redis_keys,
    pg_database,
    require_server,
)

from schemas.jobs import unfit

pytestmark = pytest.mark.slow  # schemathesis against a running server

SMALL_CAPS = {  # generated requests stay cheap: the point is the contract, not the work
    "FOREST_MAX_FOREST_TREES": "4",
    "FOREST_MAX_FOREST_PIECES": "3000",
    "FOREST_MAX_TREE_PIECES": "3000",
    "FOREST_MAX_FRAMES": "4",
    "FOREST_MAX_IMAGE_SIZE": "256",
    "FOREST_MAX_RENDER_FRAMES": "4",
}
KEY = {"X-API-Key": "key-fuzz"}
NON_FINITE = ["NaN", "Infinity", "-Infinity", "1e400"]
SENTINEL = "__non_finite__"


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    env = SMALL_CAPS | {"FOREST_API_KEYS": "key-fuzz=fuzz,key-ops=ops:admin"}
    s = Server(tmp_path_factory.mktemp("openapi"), env, workers=0).start()
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture(scope="module")
def pg_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """The same server on PostgreSQL + Redis (a database and keys of its own)."""
    require_server("PostgreSQL", PG)
    require_server("Redis", REDIS)
    tag = uuid.uuid4().hex[:12]
    prefix = f"forest-test-{tag}."
    with pg_database(tag) as db_url:
        env = SMALL_CAPS | {
            "FOREST_API_KEYS": "key-fuzz=fuzz,key-ops=ops:admin",
            "FOREST_DATABASE_URL": db_url,
            "FOREST_BROKER_URL": REDIS_URL,
            "FOREST_QUEUE_PREFIX": prefix,
        }
        s = Server(tmp_path_factory.mktemp("openapi-pg"), env, workers=0).start()
        try:
            yield s
        finally:
            s.stop()
            delete_redis_keys(prefix)


def test_openapi_contract(server: Server, tmp_path: Path) -> None:
    contract(server, tmp_path)


def test_openapi_contract_on_postgresql(pg_server: Server, tmp_path: Path) -> None:
    contract(pg_server, tmp_path)


def contract(server: Server, tmp_path: Path) -> None:
    st_bin = Path(sys.executable).with_name("schemathesis")
    proc = subprocess.run(
        [
            str(st_bin),
            "run",
            f"{server.url}/openapi.json",
            "--header",
            f"X-API-Key: {KEY['X-API-Key']}",
            "--max-examples",
            "20",
            "--seed",
            "7",
            "--checks",
            "not_a_server_error,response_schema_conformance,content_type_conformance,"
            "status_code_conformance",
            "--request-timeout",
            "30",
        ],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stdout[-6000:] + proc.stderr[-2000:]
    assert server.get("/healthz").status_code == 200
    # signed in: calls reached the routes behind the key check (a 422 or 404 comes after it),
    # not only its 401
    text = server.get("/metrics", headers={"X-API-Key": "key-ops"}).text  # every tenant's
    for route, status in (("/v1/forests", "422"), ("/v1/jobs/{job_id}", "404")):
        assert f'route="{route}",status="{status}"' in text, (route, status)


def numbers(value: Any, path: tuple[Any, ...] = ()) -> Iterator[tuple[Any, ...]]:
    """Paths of every number (not bool) in a JSON value."""
    if isinstance(value, bool):
        return
    if isinstance(value, int | float):
        yield path
    elif isinstance(value, dict):
        for k, v in value.items():
            yield from numbers(v, (*path, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from numbers(v, (*path, i))


def with_token(body: Any, path: tuple[Any, ...], token: str) -> str:
    """``body`` as JSON text with the number at ``path`` written as ``token``."""
    body = json.loads(json.dumps(body))  # a copy
    node = body
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = SENTINEL
    text = json.dumps(body)
    assert text.count(f'"{SENTINEL}"') == 1
    return text.replace(f'"{SENTINEL}"', token)


def spoil_numbers(op: Any, client: httpx.Client, sent: dict[str, int]) -> None:
    """Send bodies schemathesis generates for ``op``, each with one number made non-finite:
    each must be 422 naming that number's field."""

    @settings(
        max_examples=20,
        derandomize=True,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
        phases=[Phase.explicit, Phase.generate],  # no shrinking: the case is printed
    )
    @given(case=op.as_strategy(), data=st.data())
    def check(case: Any, data: st.DataObject) -> None:
        paths = list(numbers(case.body))
        # a body with a fault of its own (a NUL in a string: 422 at that string) says nothing
        # of the spoiled number
        if not paths or unfit(case.body) is not None:
            return
        path = data.draw(st.sampled_from(paths), label="number")
        token = data.draw(st.sampled_from(NON_FINITE), label="token")
        text = with_token(case.body, path, token)
        r = client.request(
            op.method.upper(),
            case.formatted_path,
            content=text,
            headers={"content-type": "application/json"},
        )
        assert r.status_code == 422, (op.path, path, token, text[:2000], r.text[:2000])
        # the 422 body itself serialises, and names the spoiled field (not some other fault
        # of the generated body)
        field = json.dumps([k for k in path if isinstance(k, str)][-1])[1:-1]
        said = json.dumps([[d["loc"], d["msg"]] for d in r.json()["errors"]])
        assert field in said, (op.path, path, token, text[:2000], said)
        sent[op.path] = sent.get(op.path, 0) + 1

    check()


def test_non_finite_numbers_are_422_everywhere(server: Server) -> None:
    schema = schemathesis.openapi.from_url(f"{server.url}/openapi.json")
    ops = [
        op
        for op in (r.ok() for r in schema.get_all_operations())
        if any(b.media_type == "application/json" for b in op.body)
    ]
    assert {op.path for op in ops} >= {"/v1/trees", "/v1/forests", "/v1/renders"}
    sent: dict[str, int] = {}
    with httpx.Client(base_url=server.url, headers=KEY, timeout=30) as client:
        for op in ops:
            spoil_numbers(op, client, sent)
    # the pass can fail: every JSON operation got bodies with numbers to spoil
    assert all(sent.get(op.path, 0) >= 5 for op in ops), sent


def test_non_finite_form_numbers_are_422(server: Server) -> None:
    """The multipart upload's number fields, each written as NaN, Infinity or 1e400."""
    spec = httpx.get(f"{server.url}/openapi.json", timeout=30).json()
    fields = []
    for path, item in spec["paths"].items():
        for method, op in item.items():
            form = op.get("requestBody", {}).get("content", {}).get("multipart/form-data")
            if form is None:
                continue
            schema = form["schema"]
            if "$ref" in schema:
                schema = spec["components"]["schemas"][schema["$ref"].rsplit("/", 1)[1]]
            # a small file in each of the form's file fields, so only the number is wrong
            files = {
                name: ("f.bin", b"#usda 1.0\n")
                for name, prop in schema["properties"].items()
                if "application/octet-stream"
                in (prop.get("contentMediaType"), prop.get("items", {}).get("contentMediaType"))
            }
            for name, prop in schema["properties"].items():
                if prop.get("type") in ("number", "integer"):
                    fields.append((method, path, name, files))
    assert ("post", "/v1/renders/upload", "tess_max") in [f[:3] for f in fields], fields
    assert ("post", "/v1/tilesets", "per_class") in [f[:3] for f in fields], fields
    for method, path, name, files in fields:
        for token in ["nan", "NaN", "inf", "-Infinity", "1e400"]:
            r = httpx.request(
                method.upper(),
                f"{server.url}{path}",
                files=files,
                data={name: token},
                headers=KEY,
                timeout=30,
            )
            assert r.status_code == 422, (path, name, token, r.text)
            assert r.json()["errors"][0]["loc"] == ["body", name], r.text
