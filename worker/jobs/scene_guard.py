"""Bounds of an uploaded (untrusted) scene, checked on its layer before the reader composes it.

Parse, bound, then load: the root layer is opened as layer data only (no composition, no
other file opened) and refused when it would make the reader open anything outside the
upload (sublayers, references, payloads, value clips, asset paths that are absolute, climb
with ``..`` or name a URL scheme; in a ``.usdz`` a second layer or a compressed member) or
when it is bigger than the caps of :class:`UploadCaps`: time samples in all and per attribute
(frames), instances of a PointInstancer, bones of the wind palette, and the palette's memory.
Counts of time samples come from the layer's index, before any value is read; array values
are then read one at a time and measured, so the most the check holds is one value (a
``.usdc`` compresses arrays: a small file can decode into gigabytes), and a value too large
for the job's memory limit fails naming its attribute. It runs in the job's child process,
so a reader crash on a crafted file costs that child only. Errors name the prim or
attribute, never a server path.

A plain ``.usda``/``.usdc`` upload carries no textures: its bark comes from the shipped tile
set its material names. A ``.usdz`` may carry its bark tiles: :func:`package_tiles` copies
them out of the package (never from anywhere else).
"""

from __future__ import annotations

import functools
import re
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from forest.errors import SceneError
from forest.usd.contract import (
    BONE_PARENTS,
    BONE_SCALES,
    BONE_TRANSLATIONS,
    JOINT_ROTATIONS,
    LEGACY_BONE_PALETTE,
    TILE_INDICES,
    primvar,
)
from schemas.tileset import UDIM_PATTERN, udim_file

MAGIC = {b"#usda": ".usda", b"PXR-USDC": ".usdc", b"PK\x03\x04": ".usdz"}
LAYER_SUFFIXES = (".usda", ".usdc", ".usd", ".usdz")
# one entry per bone (the compact rig, and the older matrix-per-bone palette)
BONE_ATTRS = {
    BONE_PARENTS,
    BONE_TRANSLATIONS,
    BONE_SCALES,
    JOINT_ROTATIONS,
    LEGACY_BONE_PALETTE,
}
# a PointInstancer's per-instance arrays hold one entry per instance, except the tile
# indices: one per quad of the instance's piece (356 at most, at 8 segments)
PER_QUAD = {primvar(TILE_INDICES): 512}
# any other array (prototype meshes, a skinned tree's meshes) at most this many entries per
# instance of the cap: a measure of the scene, not of one mesh
VALUES_PER_INSTANCE = 64


@dataclass(frozen=True)
class UploadCaps:
    """What an uploaded scene may hold (the service's ``max_upload_*`` settings)."""

    time_samples: int = 10_000
    """Time samples in all, over every attribute."""
    frames: int = 480
    """Time samples of any one attribute (a wind frame is one time code)."""
    instances: int = 2_000_000
    """Instances of any PointInstancer (pieces, leaf clouds)."""
    bones: int = 6_000_000
    """Bones of the pieces' rig (its per-bone arrays, at one time code)."""
    memory_bytes: int | None = None
    """The job's memory limit: every value of the scene, each time sample counted (the
    reader decodes each), must decode into half of it."""


@dataclass(frozen=True)
class CheckedScene:
    """What the check found: the file's format and the asset paths it names (all inside
    the upload)."""

    suffix: str
    assets: tuple[str, ...]


def _safe_asset(path: str) -> bool:
    """A relative path that stays inside the upload: no root, no ``..``, no scheme."""
    if not path:
        return True
    if ":" in path or "\\" in path or path.startswith(("/", "~")):
        return False
    return ".." not in PurePosixPath(path).parts


def _usdz_members(path: Path) -> None:
    """A package is one layer plus the files it names, stored (USDZ stores members
    uncompressed, which also keeps a zip bomb out), every name inside the package."""
    try:
        with zipfile.ZipFile(path) as z:
            infos = z.infolist()
    except (zipfile.BadZipFile, ValueError, OSError):
        raise SceneError("not a readable .usdz package", path="scene") from None
    if not infos or not infos[0].filename.endswith(LAYER_SUFFIXES[:3]):
        raise SceneError("a .usdz package starts with its root layer", path="scene")
    for k, info in enumerate(infos):
        name = info.filename
        if not _safe_asset(name):
            raise SceneError(f"package member {name!r} leaves the package", path="scene")
        if info.compress_type != zipfile.ZIP_STORED:
            raise SceneError(
                f"package member {name!r} is compressed (a .usdz stores its files)", path="scene"
            )
        if k and name.lower().endswith(LAYER_SUFFIXES):
            raise SceneError(
                f"package member {name!r} is a second layer: an upload is one layer and "
                "its textures",
                path="scene",
            )


def _where(spec_path: Any) -> str:
    # without the leading "/": job errors turn absolute paths into their last part
    return str(spec_path).lstrip("/")


def _refuse(message: str, where: str) -> SceneError:
    """An error of the upload form's ``scene`` field, naming the prim or attribute."""
    return SceneError(f"{where}: {message}", path="scene")


def _load(get: Callable[[], Any], where: str) -> Any:
    """One value out of the layer (decoded now: a .usdc reads values lazily)."""
    try:
        return get()
    except MemoryError:
        raise _refuse("too large to read within the job's memory limit", where) from None
    except Exception as exc:  # pxr: Tf.ErrorException on a corrupt value
        raise _refuse(f"unreadable value ({type(exc).__name__})", where) from None


def _length(value: Any) -> int | None:
    if isinstance(value, str | bytes) or not hasattr(value, "__len__"):
        return None
    return len(value)


def _asset_strings(value: Any) -> list[str]:
    """Asset path strings in an attribute value (an asset or an asset array)."""
    from pxr import Sdf

    if isinstance(value, Sdf.AssetPath):
        return [value.path]
    if isinstance(value, Sdf.AssetPathArray | list | tuple):
        return [v.path for v in value if isinstance(v, Sdf.AssetPath)]
    return []


def _open_layer(path: Path) -> tuple[Any, str]:
    from pxr import Sdf

    with path.open("rb") as f:
        head = f.read(8)
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
    return layer, suffix


def check_scene_file(path: Path, caps: UploadCaps) -> CheckedScene:
    """Raise :class:`SceneError` (``path`` names the field) unless the scene at ``path`` is
    self-contained and within ``caps``."""
    layer, suffix = _open_layer(path)
    for sub in layer.subLayerPaths:
        raise SceneError(f"sublayer {sub!r}: an upload must be self-contained", path="scene")
    specs: list[Any] = []
    layer.Traverse("/", specs.append)
    # typeName by prim path without variant selections: an instancer is defined once and
    # its arrays are authored in variants (overs) too
    types: dict[Any, str] = {}
    samples = 0
    for spec_path in specs:
        if spec_path.IsPrimPath():
            prim = layer.GetPrimAtPath(spec_path)
            if prim is None:
                continue
            _check_arcs(prim, _where(spec_path))
            if prim.typeName:
                types[spec_path.StripAllVariantSelections()] = prim.typeName
        elif spec_path.IsPropertyPath():
            n = layer.GetNumTimeSamplesForPath(spec_path)
            samples += n
            if samples > caps.time_samples:
                raise _refuse(
                    f"more than {caps.time_samples} time samples in the scene", _where(spec_path)
                )
            if n > caps.frames:
                raise _refuse(
                    f"{n} time samples (frames), over the cap of {caps.frames}", _where(spec_path)
                )
    assets: list[str] = []
    budget = _Budget(caps.memory_bytes)
    for spec_path in specs:
        if spec_path.IsPropertyPath():
            prim_type = types.get(spec_path.GetPrimPath().StripAllVariantSelections(), "")
            assets += _check_attribute(layer, spec_path, prim_type, caps, budget)
    return CheckedScene(suffix, tuple(dict.fromkeys(assets)))


def _check_arcs(prim: Any, where: str) -> None:
    """No composition arc to another file (an internal reference, no asset path, stays in
    the layer) and no value clips (they name files of their own)."""
    for what, listop in (("reference", prim.referenceList), ("payload", prim.payloadList)):
        for item in listop.GetAddedOrExplicitItems():
            if item.assetPath:
                raise _refuse(
                    f"{what} to {item.assetPath!r}: an upload must be self-contained", where
                )
    for key in ("clips", "clipSets"):
        if prim.HasInfo(key):
            raise _refuse("value clips: an upload must be self-contained", where)


def _values(layer: Any, spec_path: Any, attr: Any, where: str) -> Iterator[Any]:
    """The attribute's default and its time samples, one at a time."""
    if attr.HasDefaultValue():
        yield _load(lambda: attr.default, where)
    for t in layer.ListTimeSamplesForPath(spec_path):
        yield _load(functools.partial(layer.QueryTimeSample, spec_path, t), where)


class _Budget:
    """Bytes the scene's values may still decode into (None: no limit)."""

    def __init__(self, memory_bytes: int | None) -> None:
        self.total = None if memory_bytes is None else memory_bytes // 2
        self.left = self.total

    def fits(self, nbytes: int, where: str) -> None:
        if self.left is not None and self.total is not None and nbytes > self.left:
            raise _refuse(
                f"the scene's values decode to more than {self.total >> 20} MiB, half the "
                "job's memory limit",
                where,
            )

    def take(self, nbytes: int, where: str) -> None:
        self.fits(nbytes, where)
        if self.left is not None:
            self.left -= nbytes


def _element_bytes(value: Any) -> int:
    """Bytes of one entry of a non-empty array value, as numpy holds it."""
    import numpy as np

    try:
        return int(np.asarray(value[:1]).nbytes)
    except (TypeError, ValueError):
        return 8


def _check_attribute(
    layer: Any, spec_path: Any, prim_type: str, caps: UploadCaps, budget: _Budget
) -> list[str]:
    """The attribute's asset paths (refused when they leave the upload); its arrays measured
    against the caps and the memory budget."""
    from pxr import Sdf

    attr = layer.GetAttributeAtPath(spec_path)
    if attr is None:
        return []
    where = _where(spec_path)
    name = spec_path.name
    is_asset = attr.typeName in (Sdf.ValueTypeNames.Asset, Sdf.ValueTypeNames.AssetArray)
    if name in BONE_ATTRS:
        limit, what = caps.bones, f"bones, over the cap of {caps.bones}"
    elif prim_type == "PointInstancer":
        width = PER_QUAD.get(name, 1)
        limit = caps.instances * width
        what = f"entries, over the cap of {caps.instances} instances" + (
            f" x {width} quads" if width > 1 else ""
        )
    else:
        limit = caps.instances * VALUES_PER_INSTANCE
        what = f"values, over the cap of {limit}"
    count = layer.GetNumTimeSamplesForPath(spec_path) + bool(attr.HasDefaultValue())
    found: list[str] = []
    entry = 0
    for value in _values(layer, spec_path, attr, where):
        n = _length(value)
        if n is not None and n > limit:
            raise _refuse(f"{n} {what}", where)
        if n:
            if not entry:
                entry = _element_bytes(value)
                # the values still to come are (as a rule) the same size: refuse before
                # decoding them all
                budget.fits(n * entry * count, where)
            budget.take(n * entry, where)
        if is_asset:
            for asset in _asset_strings(value):
                if not _safe_asset(asset):
                    raise _refuse(
                        f"asset path {asset!r} leaves the upload (relative paths inside it only)",
                        where,
                    )
                found.append(asset)
        del value
    return found


def package_tiles(path: Path, checked: CheckedScene, dest: Path) -> Path | None:
    """The bark tiles a ``.usdz`` upload carries, copied into ``dest`` as
    ``bark.<1001+k>.png`` (a tile folder for :func:`worker.render.textures.tile_images`); None when
    the scene is no package or names no UDIM tiles in it. Only package members are read."""
    if checked.suffix != ".usdz":
        return None
    udims = [a for a in checked.assets if "<UDIM>" in a]
    if not udims:
        return None
    asset = PurePosixPath(udims[0])
    folder = PurePosixPath(*[p for p in asset.parent.parts if p != "."])
    head, tail = asset.name.split("<UDIM>", 1)
    pattern = re.compile(re.escape(head) + r"(1\d{3})" + re.escape(tail))
    copied = 0
    with zipfile.ZipFile(path) as z:
        for info in z.infolist():
            member = PurePosixPath(info.filename)
            m = pattern.fullmatch(member.name)
            if m is None or member.parent != folder:
                continue
            dest.mkdir(parents=True, exist_ok=True)
            target = dest / udim_file(UDIM_PATTERN, int(m.group(1)) - 1001)
            target.write_bytes(z.read(info))  # stored: no bigger than the upload
            copied += 1
    return dest if copied else None
