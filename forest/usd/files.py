"""Saving a stage as .usda, .usdc or .usdz: atomically, and byte-identically for equal input."""

from __future__ import annotations

import os
import struct
import tempfile
from collections.abc import Callable
from pathlib import Path

from pxr import Sdf, Usd, UsdUtils

from forest.errors import OutputError

FORMATS = (".usda", ".usdc", ".usdz")
# DOS date 1980-01-01 00:00: zip entries otherwise carry the temp file's local mtime
_DOS_TIME, _DOS_DATE = 0, (0 << 9) | (1 << 5) | 1


def check_output_path(path: str | Path) -> Path:
    """The output's suffix must be a USD format and its folder writable; fail before work."""
    p = Path(path)
    if p.suffix.lower() not in FORMATS:
        raise OutputError(
            f"unknown format {p.suffix or '(none)'!r}; use one of {', '.join(FORMATS)}", path=str(p)
        )
    folder = p.parent if str(p.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError("folder does not exist", path=str(folder))
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError("folder is not writable", path=str(folder))
    if p.is_dir():
        raise OutputError("is a folder", path=str(p))
    try:  # permissions alone do not tell (read-only mounts, /proc): try it
        fd, probe = tempfile.mkstemp(prefix=f".{p.stem}.", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise OutputError(f"folder is not writable ({exc.strerror})", path=str(folder)) from None
    return p


def new_stage_layer(path: Path) -> tuple[Usd.Stage, Path]:
    """A stage whose root layer is a temporary file beside ``path`` in the right format;
    :func:`finish` moves it into place."""
    suffix = ".usdc" if path.suffix.lower() == ".usdz" else path.suffix.lower()
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix, dir=path.parent)
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", path=str(path)) from None
    os.close(fd)
    os.unlink(tmp)  # Sdf wants to create the file itself
    stage = Usd.Stage.CreateNew(tmp)
    if stage is None:
        raise OutputError("cannot create a USD layer here", path=str(path))
    return stage, Path(tmp)


def finish(stage: Usd.Stage, tmp: Path, path: Path) -> None:
    """Save and move into place; a .usdz packs the .usdc with fixed zip timestamps."""
    try:
        stage.GetRootLayer().Save()
        if path.suffix.lower() == ".usdz":
            _package_usdz(tmp, path)
        else:
            os.replace(tmp, path)
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", path=str(path)) from None
    finally:
        if tmp.exists():
            tmp.unlink()


def _package_usdz(usdc: Path, path: Path) -> None:
    # the package's inner file name must not depend on the random temporary name
    inner = usdc.with_name(f"{path.stem}.usdc")
    tmpz = usdc.with_suffix(".usdz")
    os.replace(usdc, inner)
    try:
        layer = Sdf.Layer.FindOrOpen(str(inner))
        if layer is None or not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(inner)), str(tmpz)):
            raise OutputError("usdz packaging failed", path=str(path))
        _zero_zip_times(tmpz)
        os.replace(tmpz, path)
    finally:
        for p in (inner, tmpz):
            if p.exists():
                p.unlink()


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
