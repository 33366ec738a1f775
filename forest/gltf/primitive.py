"""A skinned glTF primitive from a quad mesh whose UVs are per face corner (as the USD forms
write them, faceVarying): glTF holds one UV per vertex, so a vertex is split where the
corners that share it have different UVs, and only there.

Every bark quad maps a whole tile (:func:`forest.usd.materials.tile_udim_st`), so the quads
around a welded bark vertex read it at different corners of their tiles and it splits into
one vertex per quad corner; welding still shares points, normals and skin across the rims of
joined pieces, as USD's (no crease and no crack at a seam). Leaf cards keep their vertices.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pygltflib as gl
from numpy.typing import NDArray

from forest.geometry.transforms import F64
from forest.gltf.buffer import Blob

QUAD_TRIS = np.array([0, 1, 2, 0, 2, 3], np.intp)  # a quad's corners as two triangles


@dataclass(frozen=True, eq=False)
class SkinnedQuads:
    """A quad mesh bound to a skin, in the skin's bind space.

    points, normals : (v, 3) float64; normals None for flat faces (glTF readers then compute
        each triangle's own: a leaf card's normal, at no bytes)
    quads : (q, 4) int vertex indices
    joints : (v, k) int joint of each influence (into the skin's joints)
    weights : (v, k) float64 weights (rows summing to a positive number)
    uv : (q, 4, 2) float32 glTF UVs of every quad corner
    colour : (v, 3) linear RGB in [0, 1] each vertex multiplies the base colour by (glTF's
        COLOR_0), or None
    """

    points: F64
    normals: F64 | None
    quads: NDArray[np.integer]
    joints: NDArray[np.integer]
    weights: F64
    uv: NDArray[np.float32]
    colour: F64 | None = None


def split_corners(
    quads: NDArray[np.integer], uv: NDArray[np.float32]
) -> tuple[NDArray[np.intp], NDArray[np.float32], NDArray[np.intp]]:
    """One output vertex per distinct (vertex, UV) of the quad corners: the source vertex of
    each ``(n,)``, its UV ``(n, 2)`` and each corner's output vertex ``(q * 4,)``, ordered by
    source vertex, then UV bits (deterministic)."""
    source = np.asarray(quads, np.int64).ravel()
    # a corner's UV as one 64-bit key (its two float32 as stored): a 1-D unique per vertex
    bits = np.ascontiguousarray(uv.reshape(-1, 2), dtype=np.float32).view(np.uint64).ravel()
    order = np.lexsort((bits, source))
    new = np.ones(len(order), bool)
    new[1:] = (source[order[1:]] != source[order[:-1]]) | (bits[order[1:]] != bits[order[:-1]])
    corner_vertex = np.empty(len(order), np.intp)
    corner_vertex[order] = np.cumsum(new) - 1
    first = order[new]
    return source[first].astype(np.intp), uv.reshape(-1, 2)[first], corner_vertex


@dataclass(frozen=True, eq=False)
class VertexSet:
    """A primitive's vertex accessors and each vertex's values (position, normal, UV, joints,
    weights as written, as float32 bits ``(n, 16)``): a lower level whose vertices are all
    among them draws them with an index buffer of its own, and the file holds them once."""

    attributes: gl.Attributes
    keys: NDArray[np.uint32]

    def find(self, keys: NDArray[np.uint32]) -> NDArray[np.int64]:
        """Each row of ``keys``' vertex in this set, -1 where it has none."""
        return find_rows(self.keys, keys)


def find_rows(base: NDArray[Any], rows: NDArray[Any]) -> NDArray[np.int64]:
    """Each of ``rows``' index among ``base``'s rows (equal values), -1 where it has none: one
    ``np.unique`` over both, each row as one opaque item of its bytes (``unique(axis=0)``
    compares rows field by field, 3-4x slower; floats have -0.0 made 0.0 first, so that equal
    bytes are equal values)."""
    both = np.concatenate([base, rows])
    if both.dtype.kind == "f":
        both = both + 0.0
    both = np.ascontiguousarray(both.reshape(len(both), -1))
    items = both.view(np.dtype((np.void, both.shape[1] * both.dtype.itemsize))).ravel()
    _, inverse = np.unique(items, return_inverse=True)
    inverse = inverse.ravel()
    where = np.full(int(inverse.max(initial=-1)) + 1, -1, np.int64)
    where[inverse[: len(base)]] = np.arange(len(base))
    return where[inverse[len(base) :]]


def _vertex_keys(*columns: NDArray[np.generic]) -> NDArray[np.uint32]:
    """Each vertex's attribute values (float32 and int columns) as one row of float32 bits."""
    table = np.concatenate([np.asarray(c, np.float32).reshape(len(c), -1) for c in columns], 1)
    return np.ascontiguousarray(table).view(np.uint32)


def skinned_primitive(
    blob: Blob,
    mesh: SkinnedQuads,
    n_joints: int,
    material: int,
    *,
    base: VertexSet | None = None,
    share: bool = False,
) -> tuple[gl.Primitive, VertexSet | None]:
    """The mesh as an indexed triangle primitive (two per quad, in quad order) with
    POSITION, NORMAL, TEXCOORD_0, JOINTS_0 and WEIGHTS_0 (four influences, normalised;
    unused ones name joint 0) for a skin of ``n_joints`` joints, and (``share``) its
    :class:`VertexSet`. Where every vertex is one of ``base``'s, the primitive reads
    ``base``'s accessors (and ``base`` is returned)."""
    src, uv, corner = split_corners(mesh.quads, mesh.uv)
    k = mesh.joints.shape[1]
    w = np.zeros((len(src), 4))
    w[:, :k] = mesh.weights[src]
    w /= w.sum(axis=1, keepdims=True)
    j = np.zeros((len(src), 4), np.int64)
    j[:, :k] = np.where(w[:, :k] > 0, mesh.joints[src], 0)
    tris = corner.reshape(-1, 4)[:, QUAD_TRIS].ravel()
    points = mesh.points[src].astype(np.float32)
    normals = None if mesh.normals is None else mesh.normals[src].astype(np.float32)
    # vertex colour as glTF reads it: unsigned bytes, normalised (alpha 1)
    colour = None
    if mesh.colour is not None:
        rgb = np.round(np.clip(mesh.colour[src], 0.0, 1.0) * 255)
        colour = np.concatenate([rgb, np.full((len(src), 1), 255.0)], axis=1).astype(np.uint8)
    columns: list[NDArray[np.generic]] = [points, uv, j, w]
    if normals is not None:
        columns.insert(1, normals)
    if colour is not None:
        columns.append(colour)
    keys = _vertex_keys(*columns) if (base is not None or share) else None
    if base is not None and keys is not None and len(keys):
        found = base.find(keys)
        if found.min() >= 0:
            where = found[tris]
            index = where.astype(np.uint16 if len(base.keys) <= 65535 else np.uint32)
            prim = gl.Primitive(
                attributes=base.attributes,
                indices=blob.accessor(index, gl.ELEMENT_ARRAY_BUFFER),
                material=material,
            )
            return prim, base
    # core glTF reads UVs and weights as normalised integers too: UVs in 1/65535 steps (far
    # under a texel of any atlas) and rigid weights (all 0 or 1) as bytes, exactly
    uv_data: NDArray[np.float32] | NDArray[np.uint16] = uv
    if uv.min() >= 0 and uv.max() <= 1:
        uv_data = np.round(uv.astype(np.float64) * 65535).astype(np.uint16)
    rigid = bool(np.all((w == 0) | (w == 1)))
    attrs = gl.Attributes(
        POSITION=blob.accessor(points, gl.ARRAY_BUFFER, bounds=True),
        NORMAL=None if normals is None else blob.accessor(normals, gl.ARRAY_BUFFER),
        TEXCOORD_0=blob.accessor(uv_data, gl.ARRAY_BUFFER, normalized=uv_data.dtype == np.uint16),
        JOINTS_0=blob.accessor(
            j.astype(np.uint8 if n_joints <= 256 else np.uint16), gl.ARRAY_BUFFER
        ),
        WEIGHTS_0=blob.accessor(
            (w * 255).astype(np.uint8) if rigid else w.astype(np.float32),
            gl.ARRAY_BUFFER,
            normalized=rigid,
        ),
        COLOR_0=None if colour is None else blob.accessor(colour, gl.ARRAY_BUFFER, normalized=True),
    )
    # 65535 is the primitive restart value, no index of a uint16 buffer
    index = tris.astype(np.uint16 if len(src) <= 65535 else np.uint32)
    prim = gl.Primitive(
        attributes=attrs,
        indices=blob.accessor(index, gl.ELEMENT_ARRAY_BUFFER),
        material=material,
    )
    return prim, VertexSet(attrs, keys) if share and keys is not None else None
