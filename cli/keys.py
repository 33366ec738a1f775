"""``forest keys create|list|revoke``: the service's API keys, kept in its job store."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from cli.app import data_option as cli_data_option
from cli.app import input_errors, main, needs
from forest.errors import ForestError

if TYPE_CHECKING:
    from farm.keys import KeyStore

data_option = cli_data_option(
    "Data folder of the embedded job store (when FOREST_DATABASE_URL is unset)."
)


def _store(data_dir: Path) -> KeyStore:
    """The key table of the configured job store, migrated (the server may not have run)."""
    needs("service", "sqlalchemy", "alembic")
    from sqlalchemy.exc import OperationalError

    from farm.db import migrate
    from farm.keys import KeyStore
    from farm.settings import FarmSettings

    url = FarmSettings(data_dir=data_dir).db_url
    try:
        migrate(url)
    except OperationalError as exc:
        where = url.split("@")[-1]  # no credentials
        raise ForestError(
            f"the job store {where} does not answer ({type(exc.orig).__name__})",
            path="FOREST_DATABASE_URL",
        ) from None
    return KeyStore(url)


def _when(t: Any) -> str:
    return t.strftime("%Y-%m-%dT%H:%M:%SZ") if t is not None else "-"


@main.group()
def keys() -> None:
    """API keys of the service, in its job store (FOREST_DATABASE_URL, else the SQLite store
    in --data). Only a key's SHA-256 digest is stored: a key is shown once, when created."""


@keys.command("create")
@click.option("--tenant", required=True, help="Tenant whose jobs the key owns and sees.")
@click.option("--admin", is_flag=True, help="Admin scope: sees and cancels every tenant's jobs.")
@data_option
@input_errors
def create(tenant: str, admin: bool, data_dir: Path) -> None:
    """Make a key; it is printed once (stdout), its id and scope on stderr."""
    record, key = _store(data_dir).create(tenant, admin)
    scope = "admin" if record.admin else "tenant"
    click.echo(
        f"key {record.id} of tenant {record.tenant} ({scope}); shown only now, keep it:",
        err=True,
    )
    click.echo(key)


@keys.command("list")
@data_option
@input_errors
def list_keys(data_dir: Path) -> None:
    """Every key: id, tenant, scope, created, revoked (UTC)."""
    store = _store(data_dir)  # a missing job store or extra: its line, no table header
    echo: Callable[[str], None] = click.echo
    echo("id\ttenant\tscope\tcreated\trevoked")
    for k in store.list():
        scope = "admin" if k.admin else "tenant"
        echo(f"{k.id}\t{k.tenant}\t{scope}\t{_when(k.created_at)}\t{_when(k.revoked_at)}")


@keys.command("revoke")
@click.argument("key_id", metavar="ID")
@data_option
@input_errors
def revoke(key_id: str, data_dir: Path) -> None:
    """Revoke key ID (as `forest keys list` shows it): the API refuses it within
    FOREST_API_KEY_CACHE_S (2 s)."""
    record = _store(data_dir).revoke(key_id)
    if record is None:
        raise ForestError(f"no key {key_id!r} in the job store", path="id")
    click.echo(f"revoked key {record.id} of tenant {record.tenant} at {_when(record.revoked_at)}")
