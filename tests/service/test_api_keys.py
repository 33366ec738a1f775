"""API keys in the job store, on SQLite and PostgreSQL: stored as digests only, made and revoked
with `forest keys`, checked by the API (a revoked key is refused once its cache time is over),
tenants apart and an admin scope over every tenant; every route needs a key but the presets
(public); with no key anywhere the API answers loopback clients only."""

from __future__ import annotations

import asyncio
import re
import uuid
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from click.testing import CliRunner
from fastapi import FastAPI
from service_harness import PG, pg_database, require_server
from sqlalchemy import text

from cli import main
from farm.db import engine_for, migrate
from farm.keys import KeyStore
from farm.store import JobStore
from forest.errors import ForestError
from service.app import create_app
from service.security import Keys
from service.settings import ServiceSettings


@pytest.fixture(params=["sqlite", "postgresql"])
def db_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path / 'jobs.sqlite'}"
        migrate(url)
        yield url
        return
    require_server("PostgreSQL", PG)
    with pg_database(uuid.uuid4().hex[:12]) as url:
        migrate(url)
        yield url
        engine_for(url).dispose()  # the database is dropped next


def test_keys_are_stored_as_digests_and_revoked(db_url: str) -> None:
    keys = KeyStore(db_url)
    record, key = keys.create("alpha")
    admin, _ = keys.create("ops", admin=True)
    assert key.startswith(f"fk_{record.id}_") and len(key) > 50
    assert (record.tenant, record.admin, admin.admin) == ("alpha", False, True)
    with engine_for(db_url).connect() as conn:
        stored = [str(v) for row in conn.execute(text("SELECT * FROM api_keys")) for v in row]
    # the secret is all after "fk_<id>_" (URL-safe base64: it may hold "_" itself)
    assert key not in stored and key.removeprefix(f"fk_{record.id}_") not in " ".join(stored)
    assert keys.lookup(key) == record
    assert keys.lookup(key + "x") is None
    assert [k.id for k in keys.list()] == [record.id, admin.id]
    revoked = keys.revoke(record.id)
    assert revoked is not None and revoked.revoked_at is not None
    assert keys.lookup(key) is None
    again = keys.revoke(f"fk_{record.id}")  # the printed prefix works too; the time is kept
    assert again is not None and again.revoked_at == revoked.revoked_at
    assert keys.revoke("0" * 12) is None
    keys.revoke(admin.id)
    assert keys.has_keys()  # revoked keys count: the API stays closed, it does not open again
    with pytest.raises(ForestError, match="12 hex digits") as bad_id:
        keys.revoke("../etc")
    assert bad_id.value.path == "id"
    with pytest.raises(ForestError, match="letters, digits") as bad_tenant:
        keys.create("a b")
    assert bad_tenant.value.path == "tenant"


def test_cli_creates_lists_and_revokes(db_url: str, tmp_path: Path) -> None:
    env = {"FOREST_DATABASE_URL": db_url, "FOREST_DATA_DIR": str(tmp_path / "unused")}
    runner = CliRunner(env=env)
    made = runner.invoke(main, ["keys", "create", "--tenant", "alpha", "--admin"])
    assert made.exit_code == 0, made.output
    key = made.stdout.strip()  # the key alone on stdout, its id and scope on stderr
    key_id = key.split("_")[1]
    assert f"key {key_id} of tenant alpha (admin)" in made.stderr
    assert KeyStore(db_url).lookup(key) is not None
    listed = runner.invoke(main, ["keys", "list"])
    assert listed.exit_code == 0
    header, row = listed.stdout.splitlines()
    assert header.split("\t") == ["id", "tenant", "scope", "created", "revoked"]
    assert row.split("\t")[:3] == [key_id, "alpha", "admin"] and row.endswith("\t-")
    assert key not in listed.stdout
    gone = runner.invoke(main, ["keys", "revoke", key_id])
    assert gone.exit_code == 0 and f"revoked key {key_id} of tenant alpha" in gone.stdout
    assert KeyStore(db_url).lookup(key) is None
    unknown = runner.invoke(main, ["keys", "revoke", "abcdef012345"])
    assert unknown.exit_code == 2
    assert "error: id: no key 'abcdef012345' in the job store" in unknown.stderr
    bad = runner.invoke(main, ["keys", "create", "--tenant", "../x"])
    assert bad.exit_code == 2 and "error: tenant: '../x'" in bad.stderr


def test_cli_names_an_unreachable_job_store() -> None:
    env = {"FOREST_DATABASE_URL": "postgresql+psycopg://u:secret@127.0.0.1:9/db"}
    result = CliRunner(env=env).invoke(main, ["keys", "list"])
    assert result.exit_code == 2
    assert "error: FOREST_DATABASE_URL: the job store 127.0.0.1:9/db does not answer" in (
        result.stderr
    )
    assert "secret" not in result.output


def _app(db_url: str, tmp_path: Path, **settings: object) -> tuple[FastAPI, ServiceSettings]:
    s = ServiceSettings(
        data_dir=tmp_path,
        database_url=db_url,
        rate_limit="",
        **settings,  # type: ignore[arg-type]
    )
    s.artifacts.mkdir(parents=True, exist_ok=True)
    return create_app(s, reaper=False), s


def _call(
    app: FastAPI, requests: list[tuple[str, str, str | None]], client: str = "127.0.0.1"
) -> list[httpx.Response]:
    """(method, path, key) in order; ``client`` is the caller's address."""

    async def run() -> list[httpx.Response]:
        transport = httpx.ASGITransport(app=app, client=(client, 1234))
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as c:
            out = []
            for method, path, key in requests:
                headers = {"X-API-Key": key} if key else {}
                out.append(await c.request(method, path, headers=headers))
            return out

    return asyncio.run(run())


def _post(app: FastAPI, path: str, body: object, keys: list[str]) -> list[httpx.Response]:
    async def run() -> list[httpx.Response]:
        transport = httpx.ASGITransport(app=app, client=("127.0.0.1", 1234))
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as c:
            return [await c.post(path, json=body, headers={"X-API-Key": k}) for k in keys]

    return asyncio.run(run())


def test_tenants_apart_admin_sees_all_and_revocation_holds(db_url: str, tmp_path: Path) -> None:
    app, s = _app(db_url, tmp_path, api_key_cache_s=0, api_keys="boot-key=ops:admin")
    keys, jobs = KeyStore(db_url), JobStore(db_url)
    _, alpha = keys.create("alpha")
    _, beta = keys.create("beta")
    _, admin = keys.create("root", admin=True)
    a_job, _ = jobs.create("forest", {"seed": 1}, 3, tenant="alpha")
    b_job, _ = jobs.create("forest", {"seed": 2}, 3, tenant="beta")
    claim = jobs.claim(b_job.id, "w", 60)
    assert claim is not None and jobs.finish(
        claim, "completed", artifacts=["scene.usda"], result={"scene": "scene.usda"}
    )
    (s.artifacts / b_job.id).mkdir()
    (s.artifacts / b_job.id / "scene.usda").write_text("#usda 1.0\n")
    b = f"/v1/jobs/{b_job.id}"

    r = _call(
        app,
        [
            ("GET", "/v1/jobs", None),
            ("GET", "/v1/jobs", alpha),
            ("GET", b, alpha),
            ("GET", f"{b}/artifacts/scene.usda", alpha),
            ("DELETE", b, alpha),
            ("GET", b, beta),
            ("GET", "/v1/jobs", admin),
            ("GET", "/v1/jobs", "boot-key"),
            ("GET", f"{b}/artifacts/scene.usda", admin),
            ("DELETE", f"/v1/jobs/{a_job.id}", admin),
        ],
    )
    assert r[0].status_code == 401
    assert [j["id"] for j in r[1].json()["items"]] == [a_job.id]
    assert [x.status_code for x in r[2:5]] == [404, 404, 404]  # another tenant's: no such job
    assert r[5].status_code == 200
    assert {j["id"] for j in r[6].json()["items"]} == {a_job.id, b_job.id}  # admin: all
    assert {j["id"] for j in r[7].json()["items"]} == {a_job.id, b_job.id}  # bootstrap admin
    assert r[8].status_code == 200 and r[8].text == "#usda 1.0\n"
    assert r[9].status_code == 200 and r[9].json()["state"] == "canceled"

    render = {"forest_job": b_job.id, "width": 64, "height": 48}
    refused, taken = _post(app, "/v1/renders", render, [alpha, admin])
    assert refused.status_code == 422 and "no such forest job" in refused.text
    assert taken.status_code == 202, taken.text  # an admin renders any tenant's forest
    assert jobs.get(taken.json()["id"], "root") is not None  # owned by the admin's tenant

    keys.revoke(alpha.split("_")[1])
    after = _call(app, [("GET", "/v1/jobs", alpha), ("GET", "/v1/jobs", beta)])
    assert [x.status_code for x in after] == [401, 200]


def test_a_revoked_key_is_refused_once_its_cache_time_is_over(db_url: str) -> None:
    now = [1000.0]
    keys = Keys(ServiceSettings(api_key_cache_s=2.0), KeyStore(db_url), clock=lambda: now[0])
    record, key = KeyStore(db_url).create("alpha")
    caller = keys.caller(key)
    assert caller is not None and (caller.tenant, caller.scope) == ("alpha", "alpha")
    KeyStore(db_url).revoke(record.id)
    now[0] += 1.0
    assert keys.caller(key) is not None  # still trusted from the cache (within 2 s)
    now[0] += 1.5
    assert keys.caller(key) is None
    assert keys.caller("fk_000000000000_guess") is None


PUBLIC = ("/v1/presets", "/v1/recipes")


def test_only_the_presets_and_recipes_are_public(db_url: str, tmp_path: Path) -> None:
    app, _ = _app(db_url, tmp_path, api_keys="boot-key=alpha")
    routes = sorted(
        (method.upper(), path)
        for path, item in app.openapi()["paths"].items()
        if path.startswith("/v1/")
        for method in item
    )
    assert {("GET", p) for p in PUBLIC} <= set(routes) and len(routes) >= 9
    # every path parameter filled in ({job_id}, {name:path}): the key is checked before them
    calls = [(method, re.sub(r"\{[^}]+\}", "x", path), None) for method, path in routes]
    r = _call(app, [*calls, ("GET", "/v1/presets", "not-a-key")])
    for (method, path, _), answer in zip(calls, r, strict=False):
        want = 200 if path in PUBLIC else 401
        assert answer.status_code == want, (method, path, answer.text)
    assert r[-1].status_code == 200  # a wrong key does not hide public data
    assert {"birch", "oak"} <= {p["name"] for p in r[-1].json()["items"]}


def test_without_keys_only_loopback_is_answered(db_url: str, tmp_path: Path) -> None:
    app, _ = _app(db_url, tmp_path, api_key_cache_s=0)
    local = _call(app, [("GET", "/v1/jobs", None), ("GET", "/v1/presets", None)])
    remote = _call(
        app,
        [("GET", "/v1/jobs", None), ("GET", "/healthz", None), ("GET", "/v1/presets", None)],
        client="10.1.2.3",
    )
    assert [x.status_code for x in local] == [200, 200]
    assert remote[0].status_code == 403 and "loopback" in remote[0].json()["detail"]
    assert remote[1].status_code == 200  # probes stay open
    assert remote[2].status_code == 403  # public data too: an open server is loopback's only
    _, key = KeyStore(db_url).create("alpha")  # a key exists now: no more open access
    keyed = _call(app, [("GET", "/v1/jobs", None), ("GET", "/v1/jobs", key)], client="10.1.2.3")
    assert [x.status_code for x in keyed] == [401, 200]


def test_bootstrap_keys_are_checked() -> None:
    with pytest.raises(ValueError, match="key=tenant or key=tenant:admin"):
        Keys(ServiceSettings(api_keys="k=alpha:root"), KeyStore("sqlite://"))
