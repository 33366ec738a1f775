"""The .glb's packings (forest.gltf.compress): quantized data stands for the float document
within its steps (positions through the skin's inverse binds), meshopt's compressed views
decode (with meshoptimizer's own decoder) to exactly the quantized views, the extensions and
the fallback buffer are declared as their specifications ask, and the bytes are the same for
the same forest."""

from __future__ import annotations

import copy
import struct

import meshoptimizer as mo
import numpy as np
import pygltflib as gl
import pytest
from helpers_gltf import small_forest

from forest.errors import OutputError
from forest.geometry.transforms import quat_to_matrix
from forest.gltf.buffer import Blob
from forest.gltf.compress import (
    MESHOPT,
    QUANTIZATION,
    Dequant,
    document_json,
    glb,
    pack,
    quantize_weights,
    read_accessor,
)
from forest.gltf.document import forest_gltf


@pytest.fixture(scope="module")
def float_doc() -> gl.GLTF2:
    return forest_gltf(small_forest())


@pytest.fixture(scope="module")
def quantized(float_doc: gl.GLTF2) -> gl.GLTF2:
    return pack(copy.deepcopy(float_doc), "quantized")


@pytest.fixture(scope="module")
def meshopt(float_doc: gl.GLTF2) -> gl.GLTF2:
    return pack(copy.deepcopy(float_doc), "meshopt")


def _value(doc: gl.GLTF2, a: int) -> np.ndarray:
    """Accessor ``a`` as the numbers it stands for (normalized integers divided out)."""
    acc = doc.accessors[a]
    x = read_accessor(doc, a).astype(np.float64)
    if acc.normalized:
        x = x / np.iinfo(read_accessor(doc, a).dtype).max
    return x


def test_weights_sum_to_255_and_round_to_nearest() -> None:
    rng = np.random.default_rng(1)
    w = rng.random((1000, 4)) ** 3
    w[::7, 2:] = 0  # vertices with two influences
    w /= w.sum(axis=1, keepdims=True)
    q = quantize_weights(w)
    assert q.dtype == np.uint8
    assert (q.astype(int).sum(axis=1) == 255).all()
    assert np.abs(q / 255 - w).max() < 1.0 / 255
    assert (q[::7, 2:] == 0).all()  # an unused influence stays unused


def test_dequantized_positions_within_half_a_step() -> None:
    rng = np.random.default_rng(2)
    p = rng.normal(size=(500, 3)) * [3.0, 20.0, 3.0] + [1.0, 10.0, -2.0]
    d = Dequant.of_bounds(p.min(axis=0), p.max(axis=0))
    q = d.quantize(p)
    assert q.dtype == np.int16 and np.abs(q).max() == 32767
    back = (d.matrix() @ np.c_[q, np.ones(len(q))].T).T[:, :3]
    assert np.abs(back - p).max() <= d.scale / 2 * (1 + 1e-9)


def test_quantized_attributes_stand_for_the_float_ones(
    float_doc: gl.GLTF2, quantized: gl.GLTF2
) -> None:
    assert quantized.extensionsRequired == [QUANTIZATION]
    checked = set()
    for node in quantized.nodes:
        if node.skin is None:
            continue
        skin_f, skin_q = float_doc.skins[node.skin], quantized.skins[node.skin]
        ibm_f = _value(float_doc, skin_f.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
        ibm_q = _value(quantized, skin_q.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
        prims = zip(
            float_doc.meshes[node.mesh].primitives,
            quantized.meshes[node.mesh].primitives,
            strict=True,
        )
        height = max(
            float(np.ptp(_value(float_doc, p.attributes.POSITION)[:, 1]))
            for p in float_doc.meshes[node.mesh].primitives
        )
        for prim_f, prim_q in prims:
            _check_primitive(float_doc, quantized, prim_f, prim_q, ibm_f, ibm_q, height)
        checked.add(node.skin)
    assert len(checked) == len(quantized.skins)


def _check_primitive(
    float_doc: gl.GLTF2,
    quantized: gl.GLTF2,
    prim_f: gl.Primitive,
    prim_q: gl.Primitive,
    ibm_f: np.ndarray,
    ibm_q: np.ndarray,
    height: float,
) -> None:
    """One primitive's quantized data stands for its float data (``height``: the mesh's,
    whose bounds the positions are quantized over)."""
    pos_f = _value(float_doc, prim_f.attributes.POSITION)
    pos_q = read_accessor(quantized, prim_q.attributes.POSITION)
    assert pos_q.dtype == np.int16
    acc = quantized.accessors[prim_q.attributes.POSITION]
    assert acc.min == pos_q.min(axis=0).tolist() and acc.max == pos_q.max(axis=0).tolist()
    # every joint sees the same point: IBM_q (q, 1) == IBM_f (p, 1)
    j = read_accessor(quantized, prim_q.attributes.JOINTS_0)[:, 0]
    via_q = np.einsum("nij,nj->ni", ibm_q[j], np.c_[pos_q, np.ones(len(pos_q))])
    via_f = np.einsum("nij,nj->ni", ibm_f[j], np.c_[pos_f, np.ones(len(pos_f))])
    assert np.abs(via_q - via_f).max() <= 2e-5 * height
    assert (prim_q.attributes.NORMAL is None) == (prim_f.attributes.NORMAL is None)
    if prim_q.attributes.NORMAL is not None:  # leaf cards are flat: they have none
        nrm = _value(quantized, prim_q.attributes.NORMAL)
        assert read_accessor(quantized, prim_q.attributes.NORMAL).dtype == np.int8
        want = _value(float_doc, prim_f.attributes.NORMAL)
        assert np.abs(nrm - want).max() <= 0.5 / 127 + 1e-9
    uv = _value(quantized, prim_q.attributes.TEXCOORD_0)
    # UVs in [0, 1] (leaves) are uint16; the bark's repeating ones stay float
    assert np.abs(uv - _value(float_doc, prim_f.attributes.TEXCOORD_0)).max() <= 0.5 / 65535
    w = read_accessor(quantized, prim_q.attributes.WEIGHTS_0)
    assert w.dtype == np.uint8 and (w.astype(int).sum(axis=1) == 255).all()


def _card_document() -> gl.GLTF2:
    """A document of two unskinned cards on posed nodes (an impostor's is such a card)."""
    doc = gl.GLTF2(asset=gl.Asset(version="2.0"), scene=0, scenes=[gl.Scene(nodes=[])])
    blob = Blob(doc)
    rng = np.random.default_rng(3)
    for k in range(2):
        pts = (rng.normal(size=(4, 3)) * [2.0, 5.0, 0.1] + [0.0, 5.0, 0.0]).astype(np.float32)
        prim = gl.Primitive(
            attributes=gl.Attributes(
                POSITION=blob.accessor(pts, gl.ARRAY_BUFFER, bounds=True),
                NORMAL=blob.accessor(np.tile(np.float32([0, 0, 1]), (4, 1)), gl.ARRAY_BUFFER),
            ),
            indices=blob.accessor(np.uint16([0, 1, 2, 0, 2, 3]), gl.ELEMENT_ARRAY_BUFFER),
        )
        doc.meshes.append(gl.Mesh(primitives=[prim]))
        doc.nodes.append(
            gl.Node(mesh=k, translation=[3.0 * k, 0.5, -1.0], rotation=[0, 0.6, 0, 0.8])
        )
        doc.scenes[0].nodes.append(k)
    blob.finish()
    return doc


def test_unskinned_meshes_carry_their_dequantisation_on_the_node() -> None:
    """A card's corners in its parent's space: the float document's node transform of the
    float corners equals the packed node transform of the int16 corners."""

    def local(doc: gl.GLTF2, n: int) -> np.ndarray:
        node = doc.nodes[n]
        t = np.asarray(node.translation or (0, 0, 0), np.float64)
        r = quat_to_matrix(node.rotation or (0, 0, 0, 1))[:3, :3]
        (prim,) = doc.meshes[node.mesh].primitives
        p = read_accessor(doc, prim.attributes.POSITION).astype(np.float64)
        return (r @ (np.asarray(node.scale or (1, 1, 1)) * p).T).T + t

    float_doc = _card_document()
    quantized = pack(_card_document(), "quantized")
    for n in range(len(float_doc.nodes)):
        want = local(float_doc, n)
        (prim,) = quantized.meshes[quantized.nodes[n].mesh].primitives
        assert quantized.accessors[prim.attributes.POSITION].componentType == gl.SHORT
        assert np.abs(local(quantized, n) - want).max() <= 1e-4 * np.ptp(want, axis=0).max()


def test_rotation_keys_are_normalized_int16(float_doc: gl.GLTF2, quantized: gl.GLTF2) -> None:
    (anim,) = quantized.animations
    rotations = [
        anim.samplers[c.sampler].output for c in anim.channels if c.target.path == "rotation"
    ]
    for a in rotations[:50]:
        acc = quantized.accessors[a]
        assert acc.componentType == gl.SHORT and acc.normalized
        assert np.abs(_value(quantized, a) - _value(float_doc, a)).max() <= 0.5 / 32767 + 1e-9


def _decode(doc: gl.GLTF2, v: int) -> bytes:
    ext = doc.bufferViews[v].extensions[MESHOPT]
    start = ext["byteOffset"]
    src = doc.binary_blob()[start : start + ext["byteLength"]]
    count, stride = ext["count"], ext["byteStride"]
    if ext["mode"] == "ATTRIBUTES":
        assert src[0] == 0xA0  # the vertex codec's version 0, the extension's bitstream
        return bytes(mo.decode_vertex_buffer(count, stride, src, dtype=np.dtype((np.void, stride))))
    decode = mo.decode_index_buffer if ext["mode"] == "TRIANGLES" else mo.decode_index_sequence
    # the binding decodes into a uint32 array whatever the index size: 2-byte indices come
    # packed in its first half
    return bytes(decode(count, stride, src).tobytes()[: count * stride])


def _canonical(tris: np.ndarray) -> np.ndarray:
    """Each triangle rotated to start at its smallest corner."""
    first = np.argmin(tris, axis=1)[:, None]
    return np.take_along_axis(tris, (first + np.arange(3)) % 3, axis=1)


def test_meshopt_views_decode_to_the_quantized_views(
    quantized: gl.GLTF2, meshopt: gl.GLTF2
) -> None:
    assert meshopt.extensionsRequired == [QUANTIZATION, MESHOPT]
    assert set(meshopt.extensionsUsed) >= {QUANTIZATION, MESHOPT}
    main, fallback = meshopt.buffers
    assert main.byteLength == len(meshopt.binary_blob()) and main.uri is None
    assert fallback.uri is None and fallback.extensions == {MESHOPT: {"fallback": True}}
    images = {im.bufferView for im in meshopt.images}
    qblob = quantized.binary_blob()
    modes = set()
    for v, (bq, bm) in enumerate(zip(quantized.bufferViews, meshopt.bufferViews, strict=True)):
        raw = qblob[bq.byteOffset : bq.byteOffset + bq.byteLength]
        if v in images or not bm.extensions:  # images, and views the codec cannot shrink
            assert bm.buffer == 0 and bm.byteLength == len(raw)
            assert meshopt.binary_blob()[bm.byteOffset : bm.byteOffset + len(raw)] == raw
            continue
        ext = bm.extensions[MESHOPT]
        modes.add(ext["mode"])
        assert bm.buffer == 1 and ext["buffer"] == 0
        assert bm.byteOffset + bm.byteLength <= fallback.byteLength
        assert bm.byteLength == ext["count"] * ext["byteStride"] == len(raw)
        assert bm.byteStride in (None, ext["byteStride"])
        if ext["mode"] == "TRIANGLES":
            # the triangle codec may rotate a triangle's corners (same triangle, same winding)
            dtype = np.uint16 if ext["byteStride"] == 2 else np.uint32
            got, want = (np.frombuffer(b, dtype).reshape(-1, 3) for b in (_decode(meshopt, v), raw))
            assert np.array_equal(_canonical(got), _canonical(want)), v
        else:
            assert _decode(meshopt, v) == raw, v
    assert modes == {"ATTRIBUTES", "TRIANGLES"}
    # every mesh attribute and index view is compressed, but an impostor card pair's (8
    # vertices, 12 indices: the codec's header outweighs them, so they stay plain)
    for mesh in meshopt.meshes:
        for prim in mesh.primitives:
            for a in [*vars(prim.attributes).values(), prim.indices]:
                if a is not None and meshopt.accessors[a].count > 12:
                    assert meshopt.bufferViews[meshopt.accessors[a].bufferView].extensions
    # the accessors are the quantized ones: only where their bytes lie changed
    assert [a.componentType for a in meshopt.accessors] == [
        a.componentType for a in quantized.accessors
    ]


def test_glb_container_and_same_bytes(float_doc: gl.GLTF2, meshopt: gl.GLTF2) -> None:
    data = glb(meshopt)
    magic, version, length = struct.unpack_from("<4sII", data)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_len, kind = struct.unpack_from("<I4s", data, 12)
    assert kind == b"JSON" and json_len % 4 == 0
    bin_len, kind = struct.unpack_from("<I4s", data, 20 + json_len)
    assert kind == b"BIN\0" and bin_len == meshopt.buffers[0].byteLength
    assert glb(pack(copy.deepcopy(float_doc), "meshopt")) == data
    assert len(data) < 0.6 * len(glb(float_doc))


def test_document_json_is_pygltflibs(
    float_doc: gl.GLTF2, quantized: gl.GLTF2, meshopt: gl.GLTF2
) -> None:
    """The fast JSON writer gives pygltflib's text exactly: the forest's documents, and the
    corners of pygltflib's empty-key rule (None, empty strings, lists and dicts dropped,
    recursively, but not inside an extension's own dict, nor in a list of lists)."""
    odd = gl.GLTF2(
        asset=gl.Asset(version="2.0", extras={"a": None, "b": "", "c": {"d": [], "e": 1}}),
        nodes=[
            gl.Node(name="", extras={"x": [{"y": None, "z": [[{"w": None}]]}]}),
            gl.Node(extensions={"EXT_x": {"k": None, "e": {}}}, children=[1], scale=[1.0] * 3),
        ],
        meshes=[gl.Mesh(primitives=[gl.Primitive(attributes=gl.Attributes(POSITION=0))])],
    )
    for doc in (float_doc, quantized, meshopt, odd):
        assert document_json(doc) == doc.gltf_to_json(separators=(",", ":"), indent=None)


def test_unknown_packing_is_refused(float_doc: gl.GLTF2) -> None:
    with pytest.raises(OutputError, match="unknown glTF packing 'zip'"):
        pack(copy.deepcopy(float_doc), "zip")  # type: ignore[arg-type]
