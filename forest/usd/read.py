"""Reading a forest scene back into the generator's arrays. Anything that breaks the contract
gets a SceneError naming the prim and attribute."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pxr import Usd, UsdGeom

from forest.bark.tilesets import DEFAULT_SET, SETS
from forest.errors import SceneError
from forest.geometry.pieces import PieceArrays
from forest.geometry.transforms import F64, compose_similarity
from forest.growth.foliage import FAMILIES, LEAF_GREEN, LeafCloud, anchor_positions
from forest.growth.rig import BoneRig, rest_rows, rest_table
from forest.sniff import USD_SUFFIXES, require_usd
from forest.usd.contract import (
    BARK_MATERIAL,
    BARK_TILE_SET,
    BARK_TILES,
    BARK_TILES_SHIPPED,
    BONE_FORMAT,
    BONE_FORMAT_VERSION,
    BONE_OFFSET,
    BONE_PARENTS,
    BONE_SCALES,
    BONE_TRANSLATIONS,
    BUILDING,
    DEPTH,
    ENGINE,
    FOLIAGE,
    FOREST,
    GRAMMAR,
    INSTANCE,
    JOINT,
    JOINT_INDICES,
    JOINT_PARENTS,
    JOINT_REST,
    JOINT_ROTATIONS,
    JOINT_WEIGHTS,
    LEAF_FAMILY,
    LEAF_RIMS,
    LEGACY_BONE_PALETTE,
    OPTIONS,
    PARENT,
    PARENT_RIM,
    PIECES,
    REPRESENTATION,
    REST_POSITION,
    ROOT_RIM,
    ROOT_ROTATIONS,
    SEED,
    SKINNED,
    SYMBOL,
    TILE_CLASS,
    TILE_INDICES,
    TILE_MANIFEST,
    TREE_ID,
    TREE_TRANSFORMS,
    TWIST,
    VERSION,
    YAW,
    primvar,
)
from forest.usd.textures import FOLDER_SUFFIX
from schemas.tileset import TileSetManifest

I32 = NDArray[np.int32]


@dataclass(frozen=True, eq=False)
class SceneArrays:
    """A scene's arrays, shaped like the generator's (see ``forest.growth.generate.Forest``).

    rig : the bones' time-independent part      joint_rotations : (f, a, 4) float32 xyzw, the
    turning bones' rotations at each entry of ``times`` (``None`` for a still scene); the
    palette of frame ``k`` is :meth:`palette` (forward kinematics, forest.growth.rig)
    """

    path: str
    grammar_json: str
    seed: int
    version: str
    options: dict[str, Any]
    manifest: TileSetManifest
    tile_folder: Path | None
    """The folder the bark material reads its UDIM tiles from (resolved against the scene
    file's folder), or None for a flat-colour material."""
    bark_tile_set: str
    """The shipped tile set the bark material names (``forest:barkTileSet``; ``"default"``
    in scenes written before species bark): the renderer's tiles when no folder is given."""
    pieces: tuple[PieceArrays, ...]
    proto_indices: I32
    transforms: F64
    tree: I32
    bone_offset: I32
    tile_indices: I32
    parent: I32
    parent_rim: I32
    twist: I32
    depth: I32
    symbol: I32
    tree_transforms: F64
    times: list[float | None]
    rig: BoneRig
    joint_rotations: NDArray[np.float32]
    foliage_positions: F64
    foliage_sizes: F64
    foliage_instance: I32
    foliage_bone: I32
    foliage_rest: F64
    foliage_clouds: tuple[LeafCloud, ...]
    """The foliage prototypes, one per cloud model (none for Points foliage)."""
    foliage_model: I32
    """(k,) int32 each cloud's model: an index into foliage_clouds."""
    foliage_yaw: F64
    """(k,) float64 each cloud's turn about +y, radians."""
    foliage_color: NDArray[np.float32]
    """(k, 3) float32 each cloud's linear RGB tint."""

    @property
    def n_instances(self) -> int:
        return len(self.proto_indices)

    _last_palette: dict[int, F64] = field(default_factory=dict, init=False, repr=False)

    @property
    def n_foliage(self) -> int:
        return len(self.foliage_sizes)

    @property
    def n_frames(self) -> int:
        """Palette samples: one per entry of ``times``."""
        return len(self.joint_rotations)

    @property
    def n_bones(self) -> int:
        return len(self.rig)

    def palette(self, frame: int = 0) -> F64:
        """``(b, 4, 4)`` the bone palette (skinning matrices, prototype space -> world) at sample
        ``frame`` (modulo the samples), rebuilt from the rig in float64; the last one asked is
        kept (callers ask the same frame several times). Read-only."""
        f = frame % self.n_frames
        if f not in self._last_palette:
            pal = self.rig.palette(self.joint_rotations[f])
            pal.flags.writeable = False
            self._last_palette.clear()
            self._last_palette[f] = pal
        return self._last_palette[f]

    def foliage_at(self, frame: int = 0) -> F64:
        """``(k, 3)`` leaf-cloud centres at palette sample ``frame``: each cloud's bone applied
        to its rest point (clouds without a bone, ``foliage_bone < 0``, stay where the scene
        puts them)."""
        pal = self.palette(frame)
        bone = np.maximum(self.foliage_bone, 0)
        pos = anchor_positions(pal, bone, self.foliage_rest)
        return np.where((self.foliage_bone >= 0)[:, None], pos, self.foliage_positions)


# pxr's diagnostics name the C++ function and file before the reason
_PXR_ERROR = re.compile(r"Error in '[^']*'(?: at line \d+ in file [^:]*)? : '(.*)'$")


def _get(prim: Usd.Prim, name: str, required: bool = True) -> Any:
    attr = prim.GetAttribute(name)
    if not attr or not attr.HasAuthoredValue():
        if required:
            raise SceneError("missing attribute", path=f"{prim.GetPath()}.{name}")
        return None
    return attr.Get()


def _array(
    prim: Usd.Prim,
    name: str,
    dtype: type,
    shape: tuple[int, ...] = (-1,),
    time: Usd.TimeCode | None = None,
) -> NDArray[Any]:
    attr = prim.GetAttribute(name)
    if not attr or not attr.HasAuthoredValue():
        raise SceneError("missing attribute", path=f"{prim.GetPath()}.{name}")
    value = attr.Get(time if time is not None else Usd.TimeCode.Default())
    try:
        return np.asarray(value, dtype=dtype).reshape(shape)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"unexpected value ({exc})", path=f"{prim.GetPath()}.{name}") from None


def _matrices(prim: Usd.Prim, name: str, time: Usd.TimeCode | None = None) -> F64:
    return np.swapaxes(_array(prim, name, np.float64, (-1, 4, 4), time), -1, -2).copy()


def _read_quads(prim: Usd.Prim, what: str) -> tuple[F64, I32]:
    """A quad-only Mesh's points and ``(q, 4)`` quads, indices checked."""
    pts = _array(prim, "points", np.float64, (-1, 3))
    counts = _array(prim, "faceVertexCounts", np.int32)
    if not (counts == 4).all():
        raise SceneError(f"{what} must be quad-only", path=f"{prim.GetPath()}.faceVertexCounts")
    quads = _array(prim, "faceVertexIndices", np.int32, (-1, 4))
    if quads.size and (quads.max() >= len(pts) or quads.min() < 0):
        raise SceneError("index out of range", path=f"{prim.GetPath()}.faceVertexIndices")
    return pts, quads


def _read_piece(prim: Usd.Prim) -> PieceArrays:
    pts, quads = _read_quads(prim, "piece prototypes")
    building = _matrices(prim, BUILDING)
    leaf = _array(prim, LEAF_RIMS, np.int32, (len(building), 6))
    return PieceArrays(
        name=prim.GetName(),
        positions=pts,
        normals=_array(prim, "normals", np.float64, (-1, 3)),
        quads=quads,
        tile_class=_array(prim, primvar(TILE_CLASS), np.int32),
        joint_indices=_array(prim, primvar(JOINT_INDICES), np.int32, (-1, 4)),
        joint_weights=_array(prim, primvar(JOINT_WEIGHTS), np.float64, (-1, 4)),
        root_rim=_array(prim, ROOT_RIM, np.int32),
        leaf_rims=leaf,
        building=building,
        joint_rest=_matrices(prim, JOINT_REST),
        joint_parents=_array(prim, JOINT_PARENTS, np.int32),
    )


def pxr_reason(exc: BaseException) -> str:
    """The reason in a pxr error, without its C++ location: ``Error in 'pxrInternal_..::
    UsdStage::Open' at line 1287 in file /opt/USD/.../stage.cpp : 'Failed to open layer
    @a.usda@'`` -> ``Failed to open layer a.usda``."""
    text = str(exc).strip()
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    last = lines[-1] if lines else type(exc).__name__
    found = _PXR_ERROR.search(last)
    reason = found.group(1) if found else last
    return reason.replace("@", "").strip() or type(exc).__name__


def open_stage(path: str | Path) -> Usd.Stage:
    p = Path(path)
    if not p.is_file():
        raise SceneError("no such file", path=str(p))
    # a file of another kind is named before pxr opens it (pxr prints its own errors)
    require_usd(p, f"a forest scene is {USD_SUFFIXES}", SceneError)
    try:
        stage = Usd.Stage.Open(str(p))
    except Exception as exc:  # pxr raises Tf.ErrorException for unreadable layers
        raise SceneError(f"not a readable USD file: {pxr_reason(exc)}", path=str(p)) from None
    if stage is None:
        raise SceneError("not a readable USD file", path=str(p))
    return stage


def select_engine(stage: Usd.Stage) -> None:
    """Compose the ``engine`` representation (pieces at their topological transforms, with
    the bone palette), whatever the file's default, in the stage's session layer: the file
    is not touched. Scenes without the variant set (older versions) are left as they are."""
    prim = stage.GetPrimAtPath(FOREST)
    if not prim or not prim.GetVariantSets().HasVariantSet(REPRESENTATION):
        return
    vset = prim.GetVariantSets().GetVariantSet(REPRESENTATION)
    if ENGINE not in vset.GetVariantNames():
        if vset.GetVariantNames() == [SKINNED]:  # a .usdz: ARKit allows no PointInstancer
            raise SceneError(
                f"holds only the {SKINNED!r} trees (a .usdz); read or render the scene "
                "written as .usdc or .usda",
                path=f"{FOREST}.{REPRESENTATION}",
            )
        raise SceneError(f"no {ENGINE!r} variant", path=f"{FOREST}.{REPRESENTATION}")
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        vset.SetVariantSelection(ENGINE)


def read_scene(path: str | Path) -> SceneArrays:
    stage = open_stage(path)
    select_engine(stage)
    forest = stage.GetPrimAtPath(FOREST)
    if not forest:
        raise SceneError("missing prim (not a forest scene)", path=FOREST)
    inst_prim = stage.GetPrimAtPath(PIECES)
    if not inst_prim or not inst_prim.IsA(UsdGeom.PointInstancer):
        raise SceneError("missing PointInstancer", path=PIECES)
    inst = UsdGeom.PointInstancer(inst_prim)
    targets = inst.GetPrototypesRel().GetTargets()
    if not targets:
        raise SceneError("no prototypes", path=f"{PIECES}.prototypes")
    pieces = []
    for t in targets:
        proto = stage.GetPrimAtPath(t)
        if not proto or not proto.IsA(UsdGeom.Mesh):
            raise SceneError("prototype is not a Mesh", path=str(t))
        pieces.append(_read_piece(proto))
    proto_idx = _array(inst_prim, "protoIndices", np.int32)
    n = len(proto_idx)
    if n and (proto_idx.min() < 0 or proto_idx.max() >= len(pieces)):
        raise SceneError("index out of range", path=f"{PIECES}.protoIndices")
    pos = _array(inst_prim, "positions", np.float64, (n, 3))
    quat_name = (
        "orientationsf" if inst.GetOrientationsfAttr().HasAuthoredValue() else "orientations"
    )
    quat = _array(inst_prim, quat_name, np.float64, (n, 4))
    scale = _array(inst_prim, "scales", np.float64, (n, 3))
    transforms = compose_similarity(pos, quat, scale[:, 0])

    def pv(name: str, width: int = 1) -> I32:
        return _array(inst_prim, primvar(name), np.int32, (n, width) if width > 1 else (n,))

    q_max = max(len(p.quads) for p in pieces)
    bone_offset = pv(BONE_OFFSET)
    rig = _read_rig(inst_prim, tuple(pieces), proto_idx, bone_offset)
    times, rotations = _read_rotations(stage, inst_prim, rig)
    foliage = _read_foliage(stage, len(rig))
    try:
        options = json.loads(_get(forest, OPTIONS))
        manifest = TileSetManifest.model_validate_json(_get(forest, TILE_MANIFEST))
    except ValueError as exc:
        raise SceneError(f"invalid JSON ({exc})", path=f"{FOREST}.{OPTIONS}") from None
    return SceneArrays(
        path=str(path),
        grammar_json=_get(forest, GRAMMAR),
        seed=int(_get(forest, SEED)),
        version=_get(forest, VERSION),
        options=options,
        manifest=manifest,
        tile_folder=_tile_folder(stage, Path(path)),
        bark_tile_set=_bark_tile_set(stage),
        pieces=tuple(pieces),
        proto_indices=proto_idx,
        transforms=transforms,
        tree=pv(TREE_ID),
        bone_offset=bone_offset,
        tile_indices=pv(TILE_INDICES, q_max),
        parent=pv(PARENT),
        parent_rim=pv(PARENT_RIM),
        twist=pv(TWIST),
        depth=pv(DEPTH),
        symbol=pv(SYMBOL),
        tree_transforms=_matrices(forest, TREE_TRANSFORMS),
        times=times,
        rig=rig,
        joint_rotations=rotations,
        **foliage,
    )


def _read_rig(
    prim: Usd.Prim, pieces: tuple[PieceArrays, ...], proto: I32, bone_offset: I32
) -> BoneRig:
    """The bones' time-independent part (forest.growth.rig), every array checked against the
    others, so forward kinematics reads nothing outside them."""
    where = prim.GetPath()
    fmt = _get(prim, BONE_FORMAT, required=False)
    if fmt is None and _has(prim, LEGACY_BONE_PALETTE):
        raise SceneError(
            "this scene stores a matrix per bone per frame (an older version's format): "
            "generate it again (its grammar, seed and options are in /World/Forest)",
            path=f"{where}.{LEGACY_BONE_PALETTE}",
        )
    if fmt == 2:  # the rig before 0.7: translations, scales, root rotations in float64
        raise SceneError(
            f"bone format 2 (an older version's, its rig in double precision); this version "
            f"reads format {BONE_FORMAT_VERSION}: generate the scene again (its grammar, seed "
            "and options are in /World/Forest)",
            path=f"{where}.{BONE_FORMAT}",
        )
    if fmt != BONE_FORMAT_VERSION:
        raise SceneError(
            f"bone format {fmt!r}: this version reads format {BONE_FORMAT_VERSION}",
            path=f"{where}.{BONE_FORMAT}",
        )
    parent = _array(prim, BONE_PARENTS, np.int32)
    b, n = len(parent), len(bone_offset)
    n_joints = np.array([p.n_joints for p in pieces], np.int64)[proto]
    owned = np.diff(np.append(bone_offset.astype(np.int64), b))
    bad = np.flatnonzero(owned != n_joints)
    if n and bone_offset[0] != 0:
        raise SceneError(
            f"the first instance's bones start at {bone_offset[0]}, not 0",
            path=f"{where}.{primvar(BONE_OFFSET)}",
        )
    if len(bad):
        i = int(bad[0])
        raise SceneError(
            f"instance {i} owns {owned[i]} of the {b} bones from {bone_offset[i]}, its piece "
            f"has {n_joints[i]} joints",
            path=f"{where}.{primvar(BONE_OFFSET)}",
        )
    rig = BoneRig(
        parent=parent,
        translation=_array(prim, BONE_TRANSLATIONS, np.float64, (b, 3)),
        scale=_array(prim, BONE_SCALES, np.float64, (b,)),
        root=bone_offset,
        root_rotation=_array(prim, ROOT_ROTATIONS, np.float64, (n, 4)),
        rest=rest_rows(proto, bone_offset, b),
        inv_rest=rest_table(pieces),
    )
    for name, arr in (
        (BONE_TRANSLATIONS, rig.translation),
        (BONE_SCALES, rig.scale),
        (ROOT_ROTATIONS, rig.root_rotation),
    ):
        if not np.isfinite(arr).all():
            raise SceneError("non-finite values", path=f"{where}.{name}")
    _check_unit(rig.root_rotation, f"{where}.{ROOT_ROTATIONS}")
    try:
        rig.levels  # noqa: B018  (parents in range, no cycle: checked once here)
    except ValueError as exc:
        raise SceneError(str(exc), path=f"{where}.{BONE_PARENTS}") from None
    return rig


def _check_unit(q: NDArray[Any], path: str) -> None:
    """Quaternions must be unit to float32 precision (a zero or scaled one is no rotation)."""
    norm = np.sqrt(np.einsum("...i,...i->...", q, q, dtype=np.float64))
    if not np.isfinite(norm).all() or (np.abs(norm - 1.0) > 1e-3).any():
        raise SceneError("rotations must be finite unit quaternions", path=path)


def _read_rotations(
    stage: Usd.Stage, prim: Usd.Prim, rig: BoneRig
) -> tuple[list[float | None], NDArray[np.float32]]:
    """Times and ``(f, a, 4)`` float32 joint rotations of every sample (the default value
    alone for a still scene)."""
    attr = prim.GetAttribute(JOINT_ROTATIONS)
    if not attr or not attr.HasAuthoredValue():
        raise SceneError("missing attribute", path=f"{PIECES}.{JOINT_ROTATIONS}")
    samples = attr.GetTimeSamples()
    fps = stage.GetTimeCodesPerSecond()
    times: list[float | None] = [s / fps for s in samples] if samples else [None]
    codes = [Usd.TimeCode(s) for s in samples] or [Usd.TimeCode.Default()]
    a = len(rig.animated)
    out = np.empty((len(codes), a, 4), np.float32)
    for k, code in enumerate(codes):
        out[k] = _array(prim, JOINT_ROTATIONS, np.float32, (a, 4), code)
    _check_unit(out, f"{PIECES}.{JOINT_ROTATIONS}")
    return times, out


def _bark_tile_set(stage: Usd.Stage) -> str:
    prim = stage.GetPrimAtPath(BARK_MATERIAL)
    attr = prim.GetAttribute(BARK_TILE_SET) if prim else None
    if not attr or not attr.HasAuthoredValue():
        return DEFAULT_SET
    name = attr.Get()
    if not isinstance(name, str) or name not in SETS:
        raise SceneError(
            f"no shipped bark tile set {name!r} (shipped: {', '.join(SETS)})",
            path=f"{BARK_MATERIAL}.{BARK_TILE_SET}",
        )
    return name


def _tile_folder(stage: Usd.Stage, path: Path) -> Path | None:
    """The tile folder the bark material names (relative to the scene), or None where it
    names none or only the writer's copy of the shipped set the material's
    ``forest:barkTileSet`` names (``forest:barkTilesShipped``), which the renderer reads
    itself, so a scene handed on without its pictures renders the same. Scenes of 0.4.0
    lack that flag: there a relative ``*.textures`` folder is taken for the copy."""
    prim = stage.GetPrimAtPath(BARK_TILES)
    attr = prim.GetAttribute("inputs:file") if prim else None
    asset = attr.Get() if attr else None
    if asset is None or not asset.path:
        return None
    folder = Path(asset.path).parent
    material = stage.GetPrimAtPath(BARK_MATERIAL)
    shipped = material.GetAttribute(BARK_TILES_SHIPPED) if material else None
    if shipped and shipped.HasAuthoredValue():
        if shipped.Get():
            return None
    elif not folder.is_absolute() and folder.name.endswith(FOLDER_SUFFIX):
        return None
    return folder if folder.is_absolute() else path.parent / folder


def _read_leaf_cloud(prim: Usd.Prim) -> LeafCloud:
    pts, quads = _read_quads(prim, "leaf clouds")
    normals = _array(prim, "normals", np.float64, (-1, 3))
    st = _array(prim, "primvars:st", np.float64, (-1, 2))
    for name, arr in (("normals", normals), ("primvars:st", st)):
        if len(arr) != len(pts):
            raise SceneError(
                f"{len(arr)} values for {len(pts)} points", path=f"{prim.GetPath()}.{name}"
            )
    if not (np.isfinite(pts).all() and np.isfinite(normals).all() and np.isfinite(st).all()):
        raise SceneError("non-finite values", path=f"{prim.GetPath()}.points")
    attr = prim.GetAttribute(LEAF_FAMILY)
    family = str(attr.Get()) if attr and attr.HasAuthoredValue() else "broadleaf"
    if family not in FAMILIES:
        raise SceneError(
            f"leaf family must be one of {FAMILIES}, got {family!r}",
            path=f"{prim.GetPath()}.{LEAF_FAMILY}",
        )
    return LeafCloud(positions=pts, normals=normals, st=st, quads=quads, family=family)


def _has(prim: Usd.Prim, name: str) -> bool:
    attr = prim.GetAttribute(name)
    return bool(attr) and attr.HasAuthoredValue()


def _read_foliage(stage: Usd.Stage, n_bones: int) -> dict[str, Any]:
    """The foliage fields of SceneArrays. A PointInstancer (this version's scenes) gives
    centres, sizes, bones, models, headings, colours and the leaf-cloud meshes (scenes of
    one unturned, uncoloured prototype read as model 0, yaw 0, leaf green); plain Points
    (older scenes) give centres and sizes that do not follow the wind."""
    prim = stage.GetPrimAtPath(FOLIAGE)
    empty_i = np.zeros(0, np.int32)
    out: dict[str, Any] = {
        "foliage_positions": np.zeros((0, 3)),
        "foliage_sizes": np.zeros(0),
        "foliage_instance": empty_i,
        "foliage_bone": empty_i,
        "foliage_rest": np.zeros((0, 3)),
        "foliage_clouds": (),
        "foliage_model": empty_i,
        "foliage_yaw": np.zeros(0),
        "foliage_color": np.zeros((0, 3), np.float32),
    }
    if not prim:
        return out
    if prim.IsA(UsdGeom.Points):
        pos = _array(prim, "points", np.float64, (-1, 3))
        k = len(pos)
        out.update(
            foliage_positions=pos,
            foliage_sizes=_array(prim, "widths", np.float64, (k,)),
            foliage_instance=_array(prim, primvar(INSTANCE), np.int32, (k,)),
            foliage_bone=np.full(k, -1, np.int32),
            foliage_rest=pos.copy(),
            foliage_model=np.zeros(k, np.int32),
            foliage_yaw=np.zeros(k),
            foliage_color=np.tile(np.array(LEAF_GREEN, np.float32), (k, 1)),
        )
        return out
    if not prim.IsA(UsdGeom.PointInstancer):
        raise SceneError("foliage must be a PointInstancer (or Points)", path=FOLIAGE)
    targets = UsdGeom.PointInstancer(prim).GetPrototypesRel().GetTargets()
    protos = [stage.GetPrimAtPath(t) for t in targets]
    if not protos or not all(p and p.IsA(UsdGeom.Mesh) for p in protos):
        raise SceneError("leaf-cloud Mesh prototypes expected", path=f"{FOLIAGE}.prototypes")
    pos = _array(prim, "positions", np.float64, (-1, 3))
    k = len(pos)
    scales = _array(prim, "scales", np.float64, (k, 3))
    offset = _array(prim, primvar(BONE_OFFSET), np.int32, (k,))
    bone = offset + _array(prim, primvar(JOINT), np.int32, (k,))
    if k and (bone.min() < 0 or bone.max() >= n_bones):
        raise SceneError(
            f"bones must lie in [0, {n_bones}) of the palette",
            path=f"{FOLIAGE}.{primvar(BONE_OFFSET)}",
        )
    rest = _array(prim, primvar(REST_POSITION), np.float64, (k, 3))
    if not (np.isfinite(rest).all() and np.isfinite(scales).all()):
        raise SceneError("non-finite values", path=f"{FOLIAGE}.{primvar(REST_POSITION)}")
    model = _array(prim, "protoIndices", np.int32, (k,))
    if k and (model.min() < 0 or model.max() >= len(protos)):
        raise SceneError(
            f"prototype indices must lie in [0, {len(protos)})", path=f"{FOLIAGE}.protoIndices"
        )
    if _has(prim, primvar(YAW)):
        yaw = _array(prim, primvar(YAW), np.float64, (k,))
    elif _has(prim, "orientationsf") or _has(prim, "orientations"):
        name = "orientationsf" if _has(prim, "orientationsf") else "orientations"
        q = _array(prim, name, np.float64, (k, 4))  # xyzw: a turn about +y
        yaw = 2.0 * np.arctan2(q[:, 1], q[:, 3])
    else:
        yaw = np.zeros(k)
    if _has(prim, "primvars:displayColor"):
        color = _array(prim, "primvars:displayColor", np.float32, (k, 3))
    else:
        color = np.tile(np.array(LEAF_GREEN, np.float32), (k, 1))
    if not (np.isfinite(yaw).all() and np.isfinite(color).all()):
        raise SceneError("non-finite values", path=f"{FOLIAGE}.{primvar(YAW)}")
    out.update(
        foliage_positions=pos,
        foliage_sizes=scales[:, 0].copy(),
        foliage_instance=_array(prim, primvar(INSTANCE), np.int32, (k,)),
        foliage_bone=bone.astype(np.int32),
        foliage_rest=rest,
        foliage_clouds=tuple(_read_leaf_cloud(p) for p in protos),
        foliage_model=model,
        foliage_yaw=yaw,
        foliage_color=color,
    )
    return out
