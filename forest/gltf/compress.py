"""Game-weight packing of a finished glTF document, after gltfpack's recipe:
``KHR_mesh_quantization`` (vertex data as small integers, rotation keys as normalized int16)
and ``EXT_meshopt_compression`` (each buffer view compressed with meshoptimizer's codecs).

Packings (:data:`PACKINGS`), lightest last:

- ``float``: the document as written (float32 everywhere), for exact comparisons.
- ``quantized``: positions int16 (the dequantisation scale and offset go into the skin's
  inverse bind matrices, or the node of an unskinned mesh), normals int8, texture
  coordinates in [0, 1] uint16, weights uint8 summing to 255, joints uint8 where a skin
  has at most 256; animated rotations int16. Every glTF importer we test reads it
  (Blender 4.2 included).
- ``meshopt``: quantized, then every buffer view but the images compressed (vertex codec
  version 0, the one the extension specifies); the uncompressed views live in a data-less
  ``fallback`` buffer, so the extension is required: three.js (with its MeshoptDecoder),
  Babylon.js, Unity's glTFast read it, Blender 4.2's importer refuses it.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import struct
from collections import defaultdict
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import pygltflib as gl
from numpy.typing import NDArray

from forest.errors import OutputError
from forest.geometry.transforms import quat_to_matrix

Packing = Literal["float", "quantized", "meshopt"]
PACKINGS: tuple[Packing, ...] = ("float", "quantized", "meshopt")
DEFAULT_PACKING: Packing = "quantized"
QUANTIZATION = "KHR_mesh_quantization"
MESHOPT = "EXT_meshopt_compression"
INSTANCING = "EXT_mesh_gpu_instancing"
POSITION_LIMIT = 32767  # int16 positions span [-limit, limit] around the bounds' centre

_DTYPE = {
    gl.BYTE: np.int8,
    gl.UNSIGNED_BYTE: np.uint8,
    gl.SHORT: np.int16,
    gl.UNSIGNED_SHORT: np.uint16,
    gl.UNSIGNED_INT: np.uint32,
    gl.FLOAT: np.float32,
}
_COMPONENT = {np.dtype(v): k for k, v in _DTYPE.items()}
_WIDTH = {gl.SCALAR: 1, gl.VEC2: 2, gl.VEC3: 3, gl.VEC4: 4, gl.MAT4: 16}


def read_accessor(gltf: gl.GLTF2, index: int, blob: bytes | None = None) -> NDArray[Any]:
    """Accessor ``index`` as stored: ``(count, width)`` of its component type (strided views
    read element by element); ``blob`` defaults to the document's binary blob."""
    acc = gltf.accessors[index]
    if acc.bufferView is None or acc.sparse is not None:
        raise OutputError(f"accessor {index} has no plain buffer view", path="accessors")
    view = gltf.bufferViews[acc.bufferView]
    data = gltf.binary_blob() if blob is None else blob
    dtype = np.dtype(_DTYPE[acc.componentType])
    width = _WIDTH[acc.type]
    size = dtype.itemsize * width
    stride = view.byteStride or size
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    raw = np.frombuffer(data, np.uint8, count=stride * (acc.count - 1) + size, offset=start)
    rows = np.lib.stride_tricks.as_strided(raw, (acc.count, size), (stride, 1))
    return np.ascontiguousarray(rows).view(dtype).reshape(acc.count, width)


@dataclass
class _Data:
    """One accessor's new contents: ``array`` ``(count, columns)``, whether it is
    ``normalized``, and its ``width`` where ``array`` carries a padding column."""

    array: NDArray[Any]
    normalized: bool = False
    width: int | None = None  # the accessor's width, when ``array`` carries padding


def _pad4(a: NDArray[Any]) -> NDArray[Any]:
    """A vec3 of 1- or 2-byte components padded to four: each vertex element then starts on
    4 bytes, as glTF asks of vertex attributes."""
    return np.concatenate([a, np.zeros((len(a), 1), a.dtype)], axis=1)


def _unorm(a: NDArray[Any], dtype: type[np.unsignedinteger[Any]]) -> NDArray[Any]:
    top = np.iinfo(dtype).max
    return np.asarray(np.round(np.clip(np.asarray(a, np.float64), 0.0, 1.0) * top), dtype)


def _snorm(a: NDArray[Any], dtype: type[np.signedinteger[Any]]) -> NDArray[Any]:
    top = np.iinfo(dtype).max
    return np.asarray(np.round(np.clip(np.asarray(a, np.float64), -1.0, 1.0) * top), dtype)


def quantize_weights(w: NDArray[Any]) -> NDArray[np.uint8]:
    """Skin weights ``(n, 4)`` as uint8 summing to exactly 255 per vertex (largest remainders
    get the rounding's leftover units)."""
    w = np.asarray(w, np.float64)
    total = w.sum(axis=1, keepdims=True)
    scaled = 255.0 * w / np.where(total > 0, total, 1.0)
    base = np.floor(scaled)
    short = (255 - base.sum(axis=1)).astype(np.int64)
    short[total[:, 0] <= 0] = 0
    order = np.argsort(-(scaled - base), axis=1, kind="stable")
    rank = np.argsort(order, axis=1, kind="stable")
    return (base + (rank < short[:, None])).astype(np.uint8)


@dataclass(frozen=True)
class Dequant:
    """Positions stored as ``q`` stand for ``offset + scale * q`` (one scale for the three
    axes, so normals and rotations stay as they are)."""

    offset: NDArray[np.float64]
    scale: float

    @classmethod
    def of_bounds(cls, lo: NDArray[Any], hi: NDArray[Any]) -> Dequant:
        extent = float(np.max(hi - lo))
        return cls((lo + hi) / 2.0, extent / (2 * POSITION_LIMIT) if extent > 0 else 1.0)

    def matrix(self) -> NDArray[np.float64]:
        m = np.eye(4)
        m[:3, :3] *= self.scale
        m[:3, 3] = self.offset
        return m

    def quantize(self, p: NDArray[Any]) -> NDArray[np.int16]:
        q = np.round((np.asarray(p, np.float64) - self.offset) / self.scale)
        return np.clip(q, -POSITION_LIMIT, POSITION_LIMIT).astype(np.int16)


def _position_plan(gltf: gl.GLTF2) -> tuple[dict[int, Dequant], dict[int, Dequant]]:
    """Which meshes get int16 positions and how: ``(by_mesh, by_skin)``. A skinned mesh
    shares its skin's dequantisation (it goes into the inverse binds, since a skinned node's
    own transform is ignored); an unskinned one gets its own (on its node). Meshes drawn with
    GPU instancing (the instance transform applies before the node's), or bound in ways one
    transform cannot serve, keep float positions."""
    users: dict[int, set[tuple[str, int]]] = defaultdict(set)
    for n, node in enumerate(gltf.nodes):
        if node.mesh is None:
            continue
        if INSTANCING in (node.extensions or {}):
            users[node.mesh].add(("instanced", n))
        elif node.skin is not None:
            users[node.mesh].add(("skin", node.skin))
        else:
            users[node.mesh].add(("node", n))
    bounds: dict[int, list[NDArray[np.float64]]] = {}
    skin_meshes: dict[int, list[int]] = defaultdict(list)
    by_mesh: dict[int, Dequant] = {}
    # meshes drawing the same positions (one leaf spray in each tree's material) share one
    by_positions: dict[tuple[int, ...], Dequant] = {}
    for m, who in users.items():
        kinds = {k for k, _ in who}
        positions = [p.attributes.POSITION for p in gltf.meshes[m].primitives]
        if "instanced" in kinds or len(kinds) > 1 or None in positions:
            continue
        lo = np.min([gltf.accessors[a].min for a in positions], axis=0)
        hi = np.max([gltf.accessors[a].max for a in positions], axis=0)
        bounds[m] = [np.asarray(lo, np.float64), np.asarray(hi, np.float64)]
        if kinds == {"skin"}:
            if len(who) == 1:
                skin_meshes[next(iter(who))[1]].append(m)
        else:
            key = tuple(sorted(positions))
            by_mesh[m] = by_positions.setdefault(key, Dequant.of_bounds(*bounds[m]))
    ibm_users: dict[int | None, int] = defaultdict(int)
    for skin in gltf.skins:
        ibm_users[skin.inverseBindMatrices] += 1
    by_skin: dict[int, Dequant] = {}
    for s, meshes in skin_meshes.items():
        ibm = gltf.skins[s].inverseBindMatrices
        if ibm is None or ibm_users[ibm] > 1:  # no inverse binds of its own to carry it
            continue
        lo = np.min([bounds[m][0] for m in meshes], axis=0)
        hi = np.max([bounds[m][1] for m in meshes], axis=0)
        by_skin[s] = Dequant.of_bounds(lo, hi)
        for m in meshes:
            by_mesh[m] = by_skin[s]
    # a POSITION accessor shared by meshes of different dequantisations (or none) keeps
    # all of them float, with every other mesh of their skins
    owner: dict[int, Dequant | None] = {}
    clash: set[int] = set()
    for m, mesh in enumerate(gltf.meshes):
        for p in mesh.primitives:
            a = p.attributes.POSITION
            if a is not None and owner.setdefault(a, by_mesh.get(m)) is not by_mesh.get(m):
                clash.add(a)
    if clash:
        bad = {
            m
            for m in by_mesh
            if any(p.attributes.POSITION in clash for p in gltf.meshes[m].primitives)
        }
        for s, meshes in skin_meshes.items():
            if s in by_skin and bad & set(meshes):
                del by_skin[s]
                bad |= set(meshes)
        for m in bad:
            del by_mesh[m]
    return by_mesh, by_skin


def _animated_nodes(gltf: gl.GLTF2) -> set[int]:
    return {c.target.node for a in gltf.animations for c in a.channels if c.target.node is not None}


def _place_dequant(gltf: gl.GLTF2, by_mesh: dict[int, Dequant]) -> None:
    """Put each unskinned quantized mesh's dequantisation on its node: folded into the node's
    own transform where nothing else hangs off it or moves it, else on a new child node that
    takes over the mesh."""
    animated = _animated_nodes(gltf)
    for n in range(len(gltf.nodes)):
        node = gltf.nodes[n]
        if node.mesh is None or node.mesh not in by_mesh or node.skin is not None:
            continue  # a skinned mesh's dequantisation is in its skin
        d = by_mesh[node.mesh]
        if node.children or n in animated:
            child = gl.Node(
                name=f"{node.name or 'Node'}_Mesh",
                mesh=node.mesh,
                translation=[float(v) for v in d.offset],
                scale=[d.scale] * 3,
            )
            node.mesh = None
            gltf.nodes.append(child)
            node.children.append(len(gltf.nodes) - 1)
        elif node.matrix is not None:
            m = np.asarray(node.matrix, np.float64).reshape(4, 4).T @ d.matrix()
            node.matrix = [float(v) for v in m.T.ravel()]
        else:
            # T R S (offset, scale): the offset turns with R and S, the scales multiply
            s = np.asarray(node.scale or (1.0, 1.0, 1.0), np.float64)
            r = quat_to_matrix(node.rotation or (0.0, 0.0, 0.0, 1.0))[:3, :3]
            t = np.asarray(node.translation or (0.0, 0.0, 0.0), np.float64)
            node.translation = [float(v) for v in t + r @ (s * d.offset)]
            node.scale = [float(v) for v in s * d.scale]


def _quantized(gltf: gl.GLTF2) -> dict[int, _Data]:
    """The new contents of every accessor that quantization changes (the rest keep theirs);
    moves the positions' dequantisation into the skins and nodes."""
    by_mesh, by_skin = _position_plan(gltf)
    out: dict[int, _Data] = {}
    joint_limit: dict[int, int] = {}
    for node in gltf.nodes:
        if node.mesh is not None and node.skin is not None:
            n = len(gltf.skins[node.skin].joints)
            joint_limit[node.mesh] = max(joint_limit.get(node.mesh, 0), n)
    for m, mesh in enumerate(gltf.meshes):
        for prim in mesh.primitives:
            for name, a in vars(prim.attributes).items():
                if a is None or a in out or gltf.accessors[a].componentType != gl.FLOAT:
                    continue
                x = read_accessor(gltf, a)
                if name == "POSITION" and m in by_mesh:
                    out[a] = _Data(_pad4(by_mesh[m].quantize(x)), width=3)
                elif name == "NORMAL":
                    out[a] = _Data(_pad4(_snorm(x, np.int8)), normalized=True, width=3)
                elif name.startswith("TEXCOORD_") and x.min() >= 0 and x.max() <= 1:
                    out[a] = _Data(_unorm(x, np.uint16), normalized=True)
                elif name.startswith("WEIGHTS_") and x.shape[1] == 4:
                    out[a] = _Data(quantize_weights(x), normalized=True)
            for name, a in vars(prim.attributes).items():
                if name.startswith("JOINTS_") and a is not None and a not in out:
                    acc = gltf.accessors[a]
                    if acc.componentType != gl.UNSIGNED_BYTE and joint_limit.get(m, 257) <= 256:
                        out[a] = _Data(read_accessor(gltf, a).astype(np.uint8))
    for anim in gltf.animations:
        for ch in anim.channels:
            a = anim.samplers[ch.sampler].output
            rotation = ch.target.path == "rotation" and a not in out
            if rotation and gltf.accessors[a].componentType == gl.FLOAT:
                out[a] = _Data(_snorm(read_accessor(gltf, a), np.int16), normalized=True)
    for s, d in by_skin.items():
        a = gltf.skins[s].inverseBindMatrices
        ibm = np.swapaxes(read_accessor(gltf, a).astype(np.float64).reshape(-1, 4, 4), 1, 2)
        out[a] = _Data(np.swapaxes(ibm @ d.matrix(), 1, 2).reshape(-1, 16).astype(np.float32))
    _place_dequant(gltf, by_mesh)
    for a, data in out.items():
        acc = gltf.accessors[a]
        acc.componentType = _COMPONENT[data.array.dtype]
        if data.normalized:
            acc.normalized = True
        if acc.min or acc.max:  # POSITION's bounds, now in steps
            body = data.array[:, : data.width or data.array.shape[1]]
            acc.min = [int(v) for v in body.min(axis=0)]
            acc.max = [int(v) for v in body.max(axis=0)]
    return out


@dataclass
class _View:
    data: bytes
    stride: int | None  # the bufferView's byteStride (vertex attributes only)
    target: int | None
    element: int  # bytes per element, for the codec
    mode: str | None  # the meshopt mode, or None: stays uncompressed


def _relayout(gltf: gl.GLTF2, new: dict[int, _Data]) -> list[_View]:
    """Every buffer view's new bytes, accessor by accessor: views keep their accessors
    together (the wind's keys share a view per path), converted accessors take their new
    element size (a padded vertex element sets the view's byteStride)."""
    blob = gltf.binary_blob()
    members: dict[int, list[int]] = defaultdict(list)
    for a, acc in enumerate(gltf.accessors):
        if acc.sparse is not None:
            raise OutputError(f"accessor {a} is sparse, which packing does not handle")
        if acc.bufferView is not None:
            members[acc.bufferView].append(a)
    index_views = {
        gltf.accessors[p.indices].bufferView: p.mode in (None, gl.TRIANGLES)
        for m in gltf.meshes
        for p in m.primitives
        if p.indices is not None
    }
    images = {im.bufferView for im in gltf.images if im.bufferView is not None}
    views: list[_View] = []
    for v, view in enumerate(gltf.bufferViews):
        accs = sorted(members.get(v, []), key=lambda a: gltf.accessors[a].byteOffset or 0)
        start = view.byteOffset or 0
        # copied (the pictures: small), so that nothing holds the float blob once laid out
        raw = bytes(blob[start : start + view.byteLength])
        if v in images or not accs:
            views.append(_View(raw, view.byteStride, view.target, 1, None))
            continue
        if view.byteStride and len(accs) > 1:  # interleaved: left as it is, uncompressed
            views.append(_View(raw, view.byteStride, view.target, 1, None))
            continue
        parts: list[bytes] = []
        sizes: set[int] = set()
        offset = 0
        for a in accs:
            array = new[a].array if a in new else read_accessor(gltf, a)
            chunk = np.ascontiguousarray(array).tobytes()
            sizes.add(array.dtype.itemsize * array.shape[1])
            gltf.accessors[a].byteOffset = offset or None
            parts.append(chunk)
            offset += len(chunk)
        data = b"".join(parts)
        element = sizes.pop() if len(sizes) == 1 else 0
        stride = None
        if view.target == gl.ARRAY_BUFFER and any(
            a in new and new[a].width for a in accs
        ):  # padded vec3 of small components
            stride = element
        elif view.byteStride:
            stride = view.byteStride
        mode: str | None = None
        if v in index_views:
            if element in (2, 4):  # the index codecs take 16- and 32-bit indices
                triangles = index_views[v] and (len(data) // element) % 3 == 0
                mode = "TRIANGLES" if triangles else "INDICES"
        else:
            mode = "ATTRIBUTES" if element and element % 4 == 0 and element <= 256 else None
        views.append(_View(data, stride, view.target, element, mode))
    return views


def _encode(view: _View) -> bytes:
    import meshoptimizer as mo

    count = len(view.data) // view.element
    if view.mode == "ATTRIBUTES":
        mo.encode_vertex_version(0)  # the extension specifies the version-0 vertex bitstream
        rows = np.frombuffer(view.data, np.uint8).reshape(count, view.element)
        return bytes(mo.encode_vertex_buffer(rows, count, view.element))
    indices = np.frombuffer(view.data, np.uint16 if view.element == 2 else np.uint32)
    indices = indices.astype(np.uint32)
    vertices = int(indices.max()) + 1 if len(indices) else 0
    if view.mode == "TRIANGLES":
        return bytes(mo.encode_index_buffer(indices, count, vertices))
    return bytes(mo.encode_index_sequence(indices, count, vertices))


def _assemble(gltf: gl.GLTF2, views: list[_View], meshopt: bool) -> None:
    """Lay the views out: plain ones (and the compressed bytes) in the GLB's buffer 0; with
    meshopt, the compressed views' uncompressed layout in buffer 1, the data-less fallback.
    A view the codec does not shrink (a few animation times) stays plain."""
    # one growing buffer, each view's bytes let go once copied in: the packed data is held
    # about once beside the document's float blob, not three times (views, parts, join)
    out = bytearray()
    fallback = 0

    def put(data: bytes) -> int:
        out.extend(b"\0" * (-len(out) % 4))
        at = len(out)
        out.extend(data)
        return at

    for v, view in enumerate(views):
        bv = gltf.bufferViews[v]
        bv.byteStride = view.stride
        bv.target = view.target
        bv.byteLength = len(view.data)
        bv.extensions = {k: e for k, e in (bv.extensions or {}).items() if k != MESHOPT}
        packed = _encode(view) if meshopt and view.mode is not None else None
        if packed is not None and len(packed) < len(view.data):  # else plainly stored
            fallback += -fallback % 4
            bv.buffer, bv.byteOffset = 1, fallback
            fallback += len(view.data)
            bv.extensions[MESHOPT] = {
                "buffer": 0,
                "byteOffset": put(packed),
                "byteLength": len(packed),
                "byteStride": view.element,
                "count": len(view.data) // view.element,
                "mode": view.mode,
            }
        else:
            bv.buffer, bv.byteOffset = 0, put(view.data)
        bv.extensions = bv.extensions or None
        view.data = b""
    out.extend(b"\0" * (-len(out) % 4))
    blob = out
    gltf.buffers = [gl.Buffer(byteLength=len(blob))]
    if fallback:
        gltf.buffers.append(
            gl.Buffer(byteLength=fallback, extensions={MESHOPT: {"fallback": True}})
        )
    gltf.set_binary_blob(blob)


def _use(gltf: gl.GLTF2, extension: str, required: bool) -> None:
    if extension not in gltf.extensionsUsed:
        gltf.extensionsUsed.append(extension)
    if required and extension not in gltf.extensionsRequired:
        gltf.extensionsRequired.append(extension)


def pack(gltf: gl.GLTF2, packing: Packing = DEFAULT_PACKING) -> gl.GLTF2:
    """Pack ``gltf`` (its binary blob set, one buffer) in place as ``packing``; returns it."""
    if packing not in PACKINGS:
        raise OutputError(f"unknown glTF packing {packing!r}; one of {', '.join(PACKINGS)}")
    if packing == "float":
        return gltf
    if len(gltf.buffers) != 1 or gltf.binary_blob() is None:
        raise OutputError("packing needs a document with one buffer and its binary blob")
    views = _relayout(gltf, _quantized(gltf))  # the converted arrays let go once laid out
    # every view's bytes are in ``views`` now: the float blob goes before the packed one is
    # laid out (at 100 oaks the two side by side were the writer's peak, 2.2 GB)
    gltf.set_binary_blob(b"")
    _assemble(gltf, views, meshopt=packing == "meshopt")
    _use(gltf, QUANTIZATION, required=True)
    if packing == "meshopt":
        _use(gltf, MESHOPT, required=True)
    return gltf


def glb_parts(gltf: gl.GLTF2) -> list[bytes]:
    """The GLB container of ``gltf`` in pieces to write one after the other: its header, its
    JSON chunk and its binary blob as buffer 0 (pygltflib's own writer would merge every
    buffer into one, the meshopt fallback buffer included). The blob is not copied: joined,
    the container cost the file's size three more times at the writer's peak."""
    blob = gltf.binary_blob() or b""
    text = document_json(gltf).encode("utf-8")
    text += b" " * (-len(text) % 4)
    parts = [struct.pack("<I4s", len(text), b"JSON"), text]
    if blob:
        pad = -len(blob) % 4
        parts += [struct.pack("<I4s", len(blob) + pad, b"BIN\0"), blob, b"\0" * pad]
    total = 12 + sum(len(p) for p in parts)
    return [struct.pack("<4sII", b"glTF", 2, total), *parts]


def glb(gltf: gl.GLTF2) -> bytes:
    """The GLB container of ``gltf`` (:func:`glb_parts`, joined)."""
    return b"".join(glb_parts(gltf))


# immutable leaves: pygltflib deep-copies every leaf, a no-op for these
_SCALARS = (str, int, float, bool, type(None))
_FIELDS: dict[type, tuple[str, ...]] = {}


def _plain(obj: Any) -> Any:
    """``obj`` as pygltflib's ``gltf_asdict`` makes it (dataclasses as dicts of their
    fields, in order; ``Attributes`` as its ``__dict__``), with the field names cached per
    class: pygltflib asks ``dataclasses.fields`` again for each of a forest's 10^4-10^5
    nodes, accessors and channels."""
    kind = type(obj)
    if kind in _SCALARS:
        return obj
    if kind is list:
        return [_plain(v) for v in obj]
    if kind is gl.Attributes:
        return copy.deepcopy(obj.__dict__)
    names = _fields(obj)
    if names is not None:
        return {n: _plain(getattr(obj, n)) for n in names}
    if isinstance(obj, tuple) and hasattr(obj, "_fields"):
        return kind(*[_plain(v) for v in obj])
    if isinstance(obj, (list, tuple)):
        return kind(_plain(v) for v in obj)
    if isinstance(obj, dict):
        return kind((_plain(k), _plain(v)) for k, v in obj.items())
    return copy.deepcopy(obj)


def _drop_empty(d: dict[Any, Any]) -> dict[Any, Any]:
    """pygltflib's ``delete_empty_keys``, as a copy: no None, no empty string, list or dict,
    recursively through dicts (not into an extension's own dict) and the dicts of lists."""
    out = {}
    for key, value in d.items():
        if value is None or (hasattr(value, "__iter__") and len(value) == 0):
            continue
        if isinstance(value, dict) and key != "extensions":
            value = _drop_empty(value)
        elif isinstance(value, list):
            value = [_drop_empty(v) if isinstance(v, dict) else v for v in value]
        out[key] = value
    return out


def _fields(obj: Any) -> tuple[str, ...] | None:
    """A dataclass instance's field names (cached per class), else None."""
    kind = type(obj)
    names = _FIELDS.get(kind)
    if names is None and dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        names = _FIELDS[kind] = tuple(f.name for f in dataclasses.fields(obj))
    return names


def _clean(obj: Any) -> dict[Any, Any]:
    """``_drop_empty(_plain(obj))`` for a dataclass, ``Attributes`` or dict ``obj`` in one
    pass (most fields of a node or an accessor are None: skipped before any copy)."""
    names = _fields(obj) if type(obj) is not gl.Attributes else None
    if names is not None:
        items: Any = ((n, getattr(obj, n)) for n in names)
    elif isinstance(obj, dict):
        items = obj.items()
    else:
        items = obj.__dict__.items()
    out: dict[Any, Any] = {}
    for key, raw in items:
        kind = type(raw)
        if raw is None:
            continue
        if kind is int or kind is float or kind is bool:
            out[key] = raw
        elif kind is str:
            if raw:
                out[key] = raw
        elif kind is list:
            if raw:
                # most lists are numbers (children, joints, bounds): kept as they are
                out[key] = [
                    v if type(v) in _SCALARS else _clean(v) if _mapping(v) else _plain(v)
                    for v in raw
                ]
        elif _mapping(raw):
            # a dataclass always has fields, so only an empty dict is dropped here
            if len(raw) if isinstance(raw, dict) else True:
                out[_plain(key)] = _plain(raw) if key == "extensions" else _clean(raw)
        else:
            value = _plain(raw)
            if hasattr(value, "__iter__") and len(value) == 0:
                continue
            if isinstance(value, list):
                value = [_drop_empty(v) if isinstance(v, dict) else v for v in value]
            out[_plain(key)] = value
    return out


def _mapping(obj: Any) -> bool:
    """Whether ``_plain(obj)`` is a dict (``delete_empty_keys`` cleans those)."""
    if isinstance(obj, dict) or type(obj) is gl.Attributes:
        return True
    return _fields(obj) is not None


def document_json(gltf: gl.GLTF2) -> str:
    """``gltf``'s JSON, compact: the same text as pygltflib's ``gltf_to_json(separators=(",",
    ":"), indent=None)`` (the tests compare them), in a fraction of its time; pygltflib's
    generic conversion was a quarter of writing a large forest."""
    return json.dumps(_clean(gltf), separators=(",", ":"), allow_nan=False, skipkeys=True)
