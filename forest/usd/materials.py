"""The scene's materials: UsdPreviewSurface bark (a flat colour, UDIM tiles or a .usdz's atlas)
and leaves (flat and tinted, cut to leaf shapes by the leaf picture), with the st helpers they
read: UDIM texture coordinates of the bark's quads and texture asset paths. Which pictures a
scene carries and where: :mod:`forest.usd.textures`."""

from __future__ import annotations

import posixpath
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

from forest.bark.tilesets import DEFAULT_SET, mean_colour
from forest.geometry.pieces import QUAD_ST
from forest.geometry.transforms import F64
from forest.growth.foliage import LEAF_GREEN, Family, leaf_texture
from forest.usd.contract import (
    BARK_MATERIAL,
    BARK_TILE_SET,
    BARK_TILES,
    BARK_TILES_SHIPPED,
    DISPLAY_COLOR_READER,
    LEAF_CUTOUT,
    LEAF_MATERIAL,
    LEAF_TINTED_MATERIAL,
    LOOKS,
    ST_READER,
    SURFACE,
)
from forest.usd.prims import set_attr
from schemas.tileset import UDIM_PATTERN


def tile_udim_st(tile_indices: NDArray[np.integer]) -> F64:
    """``(q, 4, 2)`` faceVarying st placing each quad's corners in the UDIM tile of its
    slice: tile ``1001 + k`` spans u in [k % 10, k % 10 + 1], v in [k // 10, k // 10 + 1]."""
    k = np.maximum(tile_indices, 0)
    offset = np.stack([k % 10, k // 10], axis=-1).astype(np.float64)
    return QUAD_ST[None] + offset[:, None]


_URL = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*://")  # RFC 3986 scheme, then an authority


def tile_asset_path(tiles: str) -> str:
    """The UDIM asset path of the tile folder ``tiles`` (given relative to the scene):
    ``./tiles/bark.<UDIM>.png``. The ``./`` anchors it to the layer, which USD resolves
    against the layer's folder, where a bare ``tiles/...`` is a search path that Blender's
    importer resolves against the working directory. Absolute and ``../`` paths and URLs
    (``scheme://...``, resolved by an asset resolver, not against the layer) are kept."""
    folder = tiles.rstrip("/") or "/"
    if not (
        posixpath.isabs(folder)
        or folder in (".", "..")
        or folder.startswith(("./", "../"))
        or _URL.match(folder)
    ):
        folder = f"./{folder}"
    return posixpath.join(folder, UDIM_PATTERN)


def st_texture(
    stage: Usd.Stage,
    path: str,
    asset: str,
    color_space: str,
    fallback: tuple[float, ...],
    wrap: str | None = None,
) -> UsdShade.Shader:
    """A UsdUVTexture at ``path`` reading ``asset`` through an ``st`` primvar reader beside it
    (``StReader``, in the same material); the caller adds the outputs it uses."""
    reader = UsdShade.Shader.Define(stage, f"{posixpath.dirname(path)}/{ST_READER}")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    tex = UsdShade.Shader.Define(stage, path)
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(asset))
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(color_space)
    if wrap is not None:
        tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set(wrap)
        tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set(wrap)
    tex.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*fallback))
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.ConnectableAPI(), "result"
    )
    return tex


def bark_material(
    stage: Usd.Stage,
    texture: str | None = None,
    bark: str = DEFAULT_SET,
    *,
    shipped_copy: bool = False,
) -> UsdShade.Material:
    """UsdPreviewSurface bark. ``forest:barkTileSet`` names the shipped tile set ``bark``
    (``forest.bark.tilesets``), which the renderer uses when the scene names no tile folder.
    With ``texture`` (an asset path: the UDIM tiles ``.../bark.<UDIM>.png`` of
    :func:`tile_asset_path`, or a .usdz's atlas) the colour comes from it through ``st``;
    without, a flat colour, the mean of the set's tiles (also the texture's fallback), so a
    DCC shows the species' colour. ``shipped_copy``: ``texture`` is this writer's copy of
    the set ``bark`` (``forest:barkTilesShipped``), not a folder the user named."""
    UsdGeom.Scope.Define(stage, LOOKS)
    mat = UsdShade.Material.Define(stage, BARK_MATERIAL)
    set_attr(mat.GetPrim(), BARK_TILE_SET, Sdf.ValueTypeNames.String, bark)
    if texture is not None:
        set_attr(mat.GetPrim(), BARK_TILES_SHIPPED, Sdf.ValueTypeNames.Bool, shipped_copy)
    colour = mean_colour(bark)
    pbr = UsdShade.Shader.Define(stage, f"{BARK_MATERIAL}/{SURFACE}")
    pbr.CreateIdAttr("UsdPreviewSurface")
    pbr.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.9)
    if texture is None:
        pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*colour))
    else:
        tex = st_texture(stage, BARK_TILES, texture, "sRGB", (*colour, 1.0))
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
            tex.ConnectableAPI(), "rgb"
        )
    mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
    return mat


@dataclass(frozen=True)
class LeafMaterials:
    """The leaves' two materials. ``flat``, bound for all purposes, is one colour: what every
    DCC shows (Blender 4.2 and Maya's importers turn a ``UsdPrimvarReader_float3`` into
    nothing, which rendered the leaves white). ``tinted``, bound for the ``preview`` purpose,
    reads ``displayColor`` per cloud: what Hydra Storm (usdview, Houdini's viewport) shows."""

    flat: UsdShade.Material
    tinted: UsdShade.Material

    def bind(self, prim: Usd.Prim) -> None:
        api = UsdShade.MaterialBindingAPI.Apply(prim)
        api.Bind(self.flat)
        api.Bind(self.tinted, materialPurpose=UsdShade.Tokens.preview)


def leaf_texture_name(family: Family) -> str:
    """The file name of the leaf family's picture: ``leaf-<family>.png``."""
    return f"leaf-{family}.png"


def write_leaf_texture(folder: Path, family: Family) -> Path:
    """The leaf family's picture (:func:`forest.growth.foliage.leaf_texture`) as
    ``folder/leaf-<family>.png``, its rows turned so that USD's ``st`` (t up from the image's
    bottom row) reads it as the leaf cards do: the stem end at t = 0."""
    from forest.bark.images import write_png

    path = folder / leaf_texture_name(family)
    write_png(path, np.ascontiguousarray(leaf_texture(family)[::-1]))
    return path


def leaf_material(
    stage: Usd.Stage, colors: NDArray[np.floating] | None = None, texture: str | None = None
) -> LeafMaterials:
    """UsdPreviewSurface leaves: the flat one in the mean of the clouds' linear RGB ``colors``
    (leaf green where there are none), the tinted one reading the ``displayColor`` primvar
    (the instancer's per-instance colour, the skinned leaves' per-face one) with that mean as
    its fallback. With ``texture`` (an asset path to :func:`write_leaf_texture`'s picture,
    beside the scene or in its package) both cut each card to its leaf: ``opacity`` from the
    picture's alpha through ``st``, ``opacityThreshold`` 0.5, so a DCC shows leaves, not
    square cards; without (``--no-textures``), uncut cards of one colour."""
    mean = (
        tuple(float(c) for c in np.asarray(colors, np.float64).mean(axis=0))
        if colors is not None and len(colors)
        else LEAF_GREEN
    )
    UsdGeom.Scope.Define(stage, LOOKS)

    def surface(path: str) -> tuple[UsdShade.Material, UsdShade.Shader]:
        mat = UsdShade.Material.Define(stage, path)
        pbr = UsdShade.Shader.Define(stage, f"{path}/{SURFACE}")
        pbr.CreateIdAttr("UsdPreviewSurface")
        pbr.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.7)
        if texture is not None:
            cutout = st_texture(
                stage, f"{path}/{LEAF_CUTOUT}", texture, "raw", (1.0, 1.0, 1.0, 1.0), "clamp"
            )
            cutout.CreateOutput("a", Sdf.ValueTypeNames.Float)
            pbr.CreateInput("opacity", Sdf.ValueTypeNames.Float).ConnectToSource(
                cutout.ConnectableAPI(), "a"
            )
            pbr.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
        mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
        return mat, pbr

    flat, pbr = surface(LEAF_MATERIAL)
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*mean))
    tinted, pbr = surface(LEAF_TINTED_MATERIAL)
    color = UsdShade.Shader.Define(stage, f"{LEAF_TINTED_MATERIAL}/{DISPLAY_COLOR_READER}")
    color.CreateIdAttr("UsdPrimvarReader_float3")
    color.CreateInput("varname", Sdf.ValueTypeNames.String).Set("displayColor")
    color.CreateInput("fallback", Sdf.ValueTypeNames.Float3).Set(Gf.Vec3f(*mean))
    out = color.CreateOutput("result", Sdf.ValueTypeNames.Float3)
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(out)
    return LeafMaterials(flat, tinted)
