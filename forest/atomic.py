"""Files that appear whole or not at all: written under a sibling temporary name, then renamed
over the target, so a reader (a render job's client, a tile-set loader) never sees half a file
and a failed write leaves the old file in place."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from forest.errors import OutputError


@contextmanager
def replaced_when_written(path: Path) -> Iterator[Path]:
    """A temporary path beside ``path`` (same suffix, so writers that go by it still can) to
    write; moved over ``path`` when the block ends without an error, removed otherwise."""
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    try:
        yield tmp
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text(path: Path, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` whole; an OS failure is an OutputError naming it."""
    try:
        with replaced_when_written(path) as tmp:
            tmp.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", path=str(path)) from None
    return path
