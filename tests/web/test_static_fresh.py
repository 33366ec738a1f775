"""The committed build of the page (service/static, shipped in the wheel so ``pip install``
needs no node) matches its sources: service/static/build.json holds the digest that
web/scripts/stamp.mjs computed over them at build time; this computes it again."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
WEB = ROOT / "web"
STATIC = ROOT / "service" / "static"
# web/scripts/stamp.mjs's roots, relative to web/ (keep the two in step)
ROOTS = [
    "../schemas/json/grammar.schema.json",
    "index.html",
    "package.json",
    "package-lock.json",
    "vite.config.js",
    "src",
    "scripts",
]


def source_digest() -> tuple[str, int]:
    files: list[str] = []
    for r in ROOTS:
        path = WEB / r
        found = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
        for p in found:
            files.append(Path(os.path.relpath(p, WEB)).as_posix())
    files.sort()
    h = hashlib.sha256()
    for f in files:
        h.update(f.encode() + b"\0")
        h.update((WEB / f).read_bytes())
        h.update(b"\0")
    return h.hexdigest(), len(files)


def test_build_matches_sources() -> None:
    stamp = json.loads((STATIC / "build.json").read_text())
    digest, count = source_digest()
    assert (stamp["sources"], stamp["files"]) == (digest, count), (
        "service/static is stale: rebuild the page with `make web` and commit service/static"
    )


def test_build_has_page_and_docs() -> None:
    for rel in [
        "index.html",
        "assets/index.js",
        "assets/index.css",
        "vendor/swagger-ui/swagger-ui-bundle.js",
        "vendor/swagger-ui/swagger-ui.css",
        "vendor/redoc/redoc.standalone.js",
    ]:
        assert (STATIC / rel).is_file(), rel
    html = (STATIC / "index.html").read_text()
    assert "http://" not in html and "https://" not in html  # nothing from a CDN
