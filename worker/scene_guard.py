"""Bounds of an uploaded (untrusted) scene, checked on its layer before the reader composes it.

Parse, bound, then load: the root layer is opened as layer data only (no composition, no
other file opened) and refused when it would make the reader open anything outside the
upload (sublayers, references, payloads, asset paths that are absolute, climb with ``..`` or
name a URL scheme) or when its time samples exceed the cap (a palette authored at 50,000 time
codes is a small file that a reader expands into gigabytes). It runs in the job's child
process, so a reader crash on a crafted file costs that child only. Errors name the prim or
attribute, never a server path.
"""

from __future__ import annotations

import zipfile
from pathlib import Path, PurePosixPath
from typing import Any

from forest.errors import SceneError

MAGIC = {b"#usda": ".usda", b"PXR-USDC": ".usdc", b"PK\x03\x04": ".usdz"}


def _safe_asset(path: str) -> bool:
    """A relative path that stays inside the upload: no root, no ``..``, no scheme."""
    if not path:
        return True
    if ":" in path or "\\" in path or path.startswith(("/", "~")):
        return False
    return ".." not in PurePosixPath(path).parts


def _usdz_members(path: Path) -> None:
    try:
        with zipfile.ZipFile(path) as z:
            infos = z.infolist()
    except zipfile.BadZipFile:
        raise SceneError("not a readable .usdz package", path="scene") from None
    if not infos or not infos[0].filename.endswith((".usda", ".usdc", ".usd")):
        raise SceneError("a .usdz package starts with its root layer", path="scene")
    for info in infos:
        if not _safe_asset(info.filename):
            raise SceneError(f"package member {info.filename!r} leaves the package", path="scene")


def _values(value: Any) -> list[str]:
    """Asset path strings in an attribute value (an asset or an asset array)."""
    from pxr import Sdf

    if isinstance(value, Sdf.AssetPath):
        return [value.path]
    if isinstance(value, Sdf.AssetPathArray | list | tuple):
        return [v.path for v in value if isinstance(v, Sdf.AssetPath)]
    return []


def check_scene_file(path: Path, max_time_samples: int) -> None:
    """Raise :class:`SceneError` (``path`` names the field) unless the scene at ``path`` is
    self-contained and within ``max_time_samples`` time samples in all."""
    from pxr import Sdf

    head = path.read_bytes()[:8]
    suffix = next((sfx for magic, sfx in MAGIC.items() if head.startswith(magic)), None)
    if suffix is None or suffix != path.suffix:
        raise SceneError("not a USD file (.usda, .usdc or .usdz)", path="scene")
    if suffix == ".usdz":
        _usdz_members(path)
    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(path))
    except Exception as exc:  # pxr: Tf.ErrorException for unparsable layers
        raise SceneError(f"not a readable USD file ({type(exc).__name__})", path="scene") from None
    if layer is None:
        raise SceneError("not a readable USD file", path="scene")
    package = suffix == ".usdz"
    for sub in layer.subLayerPaths:
        raise SceneError(f"sublayer {sub!r}: an upload must be self-contained", path="scene")
    problems: list[str] = []
    samples = 0

    def visit(spec_path: Any) -> None:
        nonlocal samples
        if problems:
            return
        if spec_path.IsPrimPath():
            prim = layer.GetPrimAtPath(spec_path)
            if prim is None:
                return
            for what, listop in (("reference", prim.referenceList), ("payload", prim.payloadList)):
                for item in listop.GetAddedOrExplicitItems():
                    # an internal arc (no asset path) stays in the layer; a package may
                    # reference its own members
                    if item.assetPath and not (package and _safe_asset(item.assetPath)):
                        problems.append(
                            f"{spec_path}: {what} to {item.assetPath!r}: an upload must be "
                            "self-contained"
                        )
        elif spec_path.IsPropertyPath():
            n = layer.GetNumTimeSamplesForPath(spec_path)
            samples += n
            if samples > max_time_samples:
                problems.append(
                    f"{spec_path}: more than {max_time_samples} time samples in the scene"
                )
                return
            attr = layer.GetAttributeAtPath(spec_path)
            if attr is None or attr.typeName not in (
                Sdf.ValueTypeNames.Asset, Sdf.ValueTypeNames.AssetArray
            ):
                return
            values = [attr.default] if attr.HasDefaultValue() else []
            for t in layer.ListTimeSamplesForPath(spec_path):
                values.append(layer.QueryTimeSample(spec_path, t))
            for v in values:
                for asset in _values(v):
                    if not _safe_asset(asset):
                        problems.append(
                            f"{spec_path}: asset path {asset!r} leaves the upload "
                            "(relative paths inside it only)"
                        )

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    if problems:
        raise SceneError(problems[0], path="scene")
