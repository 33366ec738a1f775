"""Files that appear whole or not at all, and no file but the one named is ever touched.

Every write goes to a private folder made with :func:`tempfile.mkdtemp` in the target's own
folder (same file system, so the final :func:`os.replace` is atomic), under the target's own
name (writers that go by the suffix still can); only when the write completes is it renamed
over the target. A reader (a render job's client, a tile-set loader, Blender) never sees half
a file; a failed write leaves the old file in place, and the private folder is removed
whatever happens, so no temporary is left behind. A sibling file (``forest.usdc`` next to
``forest.usdz``) is never used as scratch space.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path

from forest.errors import OutputError


def make_private_folder(beside: Path) -> Path:
    """A new, empty folder (mode 0700, a dot name no other writer picks) in ``beside``'s
    folder; an OS failure (missing or unwritable folder) is an OutputError naming ``beside``."""
    folder = beside.parent if str(beside.parent) else Path(".")
    try:
        return Path(tempfile.mkdtemp(prefix=f".{beside.name}.", suffix=".tmp", dir=folder))
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", path=str(beside)) from None


def remove_private_folder(folder: Path) -> None:
    """Remove a folder from :func:`make_private_folder` with all it holds."""
    shutil.rmtree(folder, ignore_errors=True)


@contextmanager
def private_folder(beside: Path) -> Iterator[Path]:
    """:func:`make_private_folder` for the block, removed when it ends (error or not)."""
    folder = make_private_folder(beside)
    try:
        yield folder
    finally:
        remove_private_folder(folder)


def move_into_place(src: Path, path: Path) -> Path:
    """Rename ``src`` over ``path`` atomically (both on one file system); an OS failure is an
    OutputError naming ``path``."""
    try:
        os.replace(src, path)
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", path=str(path)) from None
    return path


@contextmanager
def replaced_when_written(path: Path) -> Iterator[Path]:
    """A temporary path with ``path``'s name in a private folder beside it, to write; moved
    over ``path`` when the block ends without an error; the folder is removed either way."""
    with private_folder(path) as folder:
        tmp = folder / path.name
        yield tmp
        move_into_place(tmp, path)


@contextmanager
def all_replaced_when_written(paths: Sequence[Path]) -> Iterator[list[Path]]:
    """:func:`replaced_when_written` for several files that belong together (a preview and
    its metrics): one temporary per path, and none is moved into place unless the whole block
    succeeds, so a failure leaves every old file as it was."""
    with ExitStack() as stack:
        folders = [stack.enter_context(private_folder(p)) for p in paths]
        tmps = [f / p.name for f, p in zip(folders, paths, strict=True)]
        with _errors_name_targets(dict(zip(tmps, paths, strict=True))):
            yield tmps
        for tmp, path in zip(tmps, paths, strict=True):
            move_into_place(tmp, path)


@contextmanager
def folder_updated_when_written(folder: Path, last: Sequence[str] = ()) -> Iterator[Path]:
    """A private staging folder inside ``folder`` to write a set of files into (a tile set);
    when the block ends without an error each file in it is renamed to the same name in
    ``folder``, those named in ``last`` (a manifest that readers go by) after the others.
    A failure while writing leaves every old file in ``folder`` as it was."""
    with private_folder(folder / "set") as staging:
        with _errors_name_targets({staging: folder}):
            yield staging
        names = sorted(p.name for p in staging.iterdir() if p.is_file())
        ordered = [n for n in names if n not in last] + [n for n in last if n in names]
        for name in ordered:
            move_into_place(staging / name, folder / name)


@contextmanager
def _errors_name_targets(targets: dict[Path, Path]) -> Iterator[None]:
    """An OutputError raised while writing a temporary names the target instead (the user
    never sees the private folder)."""
    try:
        yield
    except OutputError as exc:
        for tmp, target in targets.items():
            if exc.path == str(tmp) or exc.path.startswith(f"{tmp}{os.sep}"):
                exc.path = str(target) + exc.path[len(str(tmp)) :]
                break
        raise


def write_text(path: Path, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` whole; an OS failure is an OutputError naming it."""
    try:
        with replaced_when_written(path) as tmp:
            tmp.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", path=str(path)) from None
    return path
