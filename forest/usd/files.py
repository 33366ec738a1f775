"""Saving a stage as .usda, .usdc or .usdz: atomically, and byte-identically for equal input."""

from __future__ import annotations

import os
import struct
import tempfile
from collections.abc import Callable
from pathlib import Path

from pxr import Sdf, Usd

from forest.atomic import make_private_folder, move_into_place, remove_private_folder
from forest.errors import OutputError

FORMATS = (".usda", ".usdc", ".usdz")
# DOS date 1980-01-01 00:00: zip entries otherwise carry the temp file's local mtime
_DOS_TIME, _DOS_DATE = 0, (0 << 9) | (1 << 5) | 1


def check_output_path(path: str | Path, formats: tuple[str, ...] = FORMATS) -> Path:
    """The output's suffix must be one of ``formats`` (USD's by default; the CLI adds .glb)
    and its folder writable; fail before work."""
    p = Path(path)
    if p.suffix.lower() not in formats:
        raise OutputError(
            f"unknown format {p.suffix or '(none)'!r}; use one of {', '.join(formats)}", path=str(p)
        )
    folder = p.parent if str(p.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError("folder does not exist", path=str(folder))
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError("folder is not writable", path=str(folder))
    if p.is_dir():
        raise OutputError("is a folder", path=str(p))
    try:  # permissions alone do not tell (read-only mounts, /proc): try it, touching no file
        os.rmdir(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".tmp", dir=folder))
    except OSError as exc:
        raise OutputError(f"folder is not writable ({exc.strerror})", path=str(folder)) from None
    return p


def new_stage_layer(path: Path) -> tuple[Usd.Stage, Path]:
    """A stage whose root layer is a file in a private folder beside ``path``
    (:func:`forest.atomic.make_private_folder`), in the right format; :func:`finish` moves it
    into place and :func:`discard` removes the folder (call it in a ``finally``)."""
    suffix = ".usdc" if path.suffix.lower() == ".usdz" else path.suffix.lower()
    folder = make_private_folder(path)
    # the stem is kept: a .usdz's inner layer is named after it, independent of the folder
    tmp = folder / f"{path.stem}{suffix}"
    stage = Usd.Stage.CreateNew(str(tmp))
    if stage is None:
        remove_private_folder(folder)
        raise OutputError("cannot create a USD layer here", path=str(path))
    return stage, tmp


def discard(tmp: Path) -> None:
    """Remove the private folder of a layer from :func:`new_stage_layer` and all it holds
    (nothing is left once :func:`finish` has succeeded; after a failure, the partial layer)."""
    remove_private_folder(tmp.parent)


def finish(stage: Usd.Stage, tmp: Path, path: Path) -> None:
    """Save and move into place; a .usdz packs the .usdc with fixed zip timestamps. Only
    ``path`` is ever replaced: every intermediate file lives in ``tmp``'s private folder."""
    try:
        stage.GetRootLayer().Save()
        if path.suffix.lower() == ".usdz":
            _package_usdz(stage.GetRootLayer(), tmp, path)
        else:
            move_into_place(tmp, path)
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", path=str(path)) from None
    finally:
        discard(tmp)


def _package_usdz(layer: Sdf.Layer, usdc: Path, path: Path) -> None:
    """Pack ``usdc`` (named ``<stem>.usdc``, in its private folder) into ``path``. The
    pictures it names lie beside it under ``./`` paths (:mod:`forest.usd.textures`), which the
    packager keeps as they are: any other relative path it renames (``1/bark.png``), and
    Blender resolves such a name inside a package to nothing."""
    from pxr import UsdUtils  # usdz packaging only: a twentieth of a second to import

    tmpz = usdc.with_suffix(".usdz")
    if not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(usdc)), str(tmpz)):
        raise OutputError("usdz packaging failed", path=str(path))
    _zero_zip_times(tmpz)
    move_into_place(tmpz, path)


def _zero_zip_times(path: Path) -> None:
    """Overwrite every DOS time/date in local and central zip headers."""
    data = bytearray(path.read_bytes())
    pack: Callable[..., bytes] = struct.pack
    i = 0
    while (i := data.find(b"PK\x03\x04", i)) >= 0:
        data[i + 10 : i + 14] = pack("<HH", _DOS_TIME, _DOS_DATE)
        name_len, extra_len = struct.unpack_from("<HH", data, i + 26)
        comp = struct.unpack_from("<I", data, i + 18)[0]
        i += 30 + name_len + extra_len + comp
    i = 0
    while (i := data.find(b"PK\x01\x02", i)) >= 0:
        data[i + 12 : i + 16] = pack("<HH", _DOS_TIME, _DOS_DATE)
        i += 46
    path.write_bytes(bytes(data))
