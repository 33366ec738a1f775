"""API keys in the job store: created, listed and revoked by ``forest keys``, looked up by the
API on every request (``service.security``).

A key reads ``fk_<id>_<secret>``: the id (12 hex digits) names the key in listings and
revocations and is not secret; the secret is 32 random bytes. Only the SHA-256 digest of the
whole key is stored. A fast, unsalted hash is enough because a key is a 256-bit random token,
not a password: no dictionary or brute force reaches it from the digest, so a slow or salted
hash would only cost every request time, and a salt would rule out the indexed lookup by
digest. A key is shown once, when it is created.
"""

from __future__ import annotations

import hashlib
import re
import secrets
from dataclasses import dataclass
from datetime import datetime

from sqlalchemy import select, update
from sqlalchemy.orm import Session

from farm.db import ApiKeyRow, engine_for, utcnow
from forest.errors import ForestError

KEY_PREFIX = "fk_"
TENANT = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
KEY_ID = re.compile(r"^[0-9a-f]{12}$")


@dataclass(frozen=True)
class ApiKey:
    id: str
    tenant: str
    admin: bool
    created_at: datetime
    revoked_at: datetime | None

    @classmethod
    def of(cls, row: ApiKeyRow) -> ApiKey:
        return cls(row.id, row.tenant, bool(row.admin), row.created_at, row.revoked_at)


def digest(key: str) -> str:
    return hashlib.sha256(key.encode("utf-8", "surrogatepass")).hexdigest()


def check_tenant(tenant: str) -> str:
    if not TENANT.match(tenant):
        raise ForestError(
            f"{tenant[:80]!r}: 1 to 64 letters, digits, '.', '_' or '-', "
            "starting with a letter or digit",
            path="tenant",
        )
    return tenant


class KeyStore:
    """The ``api_keys`` table of the job store at ``url`` (migrated by ``farm.db.migrate``)."""

    def __init__(self, url: str) -> None:
        self.engine = engine_for(url)

    def session(self) -> Session:
        return Session(self.engine, expire_on_commit=False)

    def create(self, tenant: str, admin: bool = False) -> tuple[ApiKey, str]:
        """A new key of ``tenant``: its record and the key itself (never stored)."""
        check_tenant(tenant)
        key_id = secrets.token_hex(6)
        key = f"{KEY_PREFIX}{key_id}_{secrets.token_urlsafe(32)}"
        row = ApiKeyRow(
            id=key_id, digest=digest(key), tenant=tenant, admin=admin, created_at=utcnow()
        )
        with self.session() as s, s.begin():
            s.add(row)
        return ApiKey.of(row), key

    def list(self) -> list[ApiKey]:
        """Every key, revoked ones too, oldest first."""
        with self.session() as s:
            rows = s.scalars(select(ApiKeyRow).order_by(ApiKeyRow.created_at, ApiKeyRow.id))
            return [ApiKey.of(r) for r in rows]

    def revoke(self, key_id: str) -> ApiKey | None:
        """Revoke the key ``key_id`` (``fk_<id>`` is accepted too); None if there is none. A
        revoked key stays revoked (the first revocation time is kept)."""
        key_id = key_id.removeprefix(KEY_PREFIX)
        if not KEY_ID.match(key_id):
            raise ForestError(
                f"{key_id[:80]!r}: 12 hex digits, as `forest keys list` shows", path="id"
            )
        with self.session() as s, s.begin():
            s.execute(
                update(ApiKeyRow)
                .where(ApiKeyRow.id == key_id, ApiKeyRow.revoked_at.is_(None))
                .values(revoked_at=utcnow())
            )
            row = s.get(ApiKeyRow, key_id)
            return ApiKey.of(row) if row is not None else None

    def lookup(self, key: str) -> ApiKey | None:
        """The live (not revoked) key ``key``, or None."""
        with self.session() as s:
            row = s.scalars(
                select(ApiKeyRow).where(
                    ApiKeyRow.digest == digest(key), ApiKeyRow.revoked_at.is_(None)
                )
            ).first()
            return ApiKey.of(row) if row is not None else None

    def has_keys(self) -> bool:
        """Whether any key was ever made here, revoked ones too: revoking the last key closes
        the API rather than opening it."""
        with self.session() as s:
            return s.scalars(select(ApiKeyRow.id).limit(1)).first() is not None
