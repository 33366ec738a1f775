"""glTF export (forest.gltf) on its own: determinism, the document's structure (a skin per
tree, the wind animation, bark atlas and leaf cards), the atlas UVs, caps and bad input."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pygltflib as gl
import pytest
from helpers_gltf import FPS, FRAMES, TREES, small_forest

from forest.bark.atlas import atlas_layout, atlas_uv, make_atlas, read_slices
from forest.bark.images import read_pixels
from forest.bark.tilesets import set_dir
from forest.errors import ForestError, LimitError
from forest.gltf import document
from forest.gltf.document import forest_gltf, glb_bytes, write_glb
from forest.growth.generate import Forest
from forest.usd.materials import tile_udim_st
from forest.usd.skinned import tree_slices

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def forest() -> Forest:
    return small_forest()


@pytest.fixture(scope="module")
def doc(forest: Forest) -> gl.GLTF2:
    return forest_gltf(forest)


def test_same_forest_same_bytes(forest: Forest, tmp_path: Path) -> None:
    a = write_glb(forest, tmp_path / "a.glb").read_bytes()
    b = write_glb(small_forest(), tmp_path / "b.glb").read_bytes()
    assert a == b
    assert a[:4] == b"glTF"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.glb", "b.glb"]  # nothing else


def test_one_skin_per_tree_with_every_bone(forest: Forest, doc: gl.GLTF2) -> None:
    assert len(doc.skins) == TREES
    slices = tree_slices(forest)
    for skin, (_inst, bones) in zip(doc.skins, slices, strict=True):
        assert len(skin.joints) == bones.stop - bones.start
        assert skin.skeleton == skin.joints[0]
        # joints are parent-first: each joint's parent joint comes earlier
        parent_of = {c: i for i, n in enumerate(doc.nodes) for c in n.children}
        index = {n: j for j, n in enumerate(skin.joints)}
        for j, n in enumerate(skin.joints[1:], 1):
            assert index[parent_of[n]] < j
    bark = [n for n in doc.nodes if n.skin is not None]
    assert len(bark) == TREES
    roots = set(doc.scenes[0].nodes)
    assert all(doc.nodes.index(n) in roots for n in bark)  # skinned nodes stay at the root
    prim = doc.meshes[bark[0].mesh].primitives[0]
    for attr in ("POSITION", "NORMAL", "TEXCOORD_0", "JOINTS_0", "WEIGHTS_0"):
        assert getattr(prim.attributes, attr) is not None, attr


def test_wind_animation_in_seconds(forest: Forest, doc: gl.GLTF2) -> None:
    (anim,) = doc.animations
    assert anim.name == "Wind"
    paths = {c.target.path for c in anim.channels}
    assert paths == {"translation", "rotation", "scale"}
    joints = sum(len(s.joints) for s in doc.skins)
    assert len(anim.channels) == 3 * joints
    times = doc.accessors[anim.samplers[0].input]
    assert times.count == FRAMES
    assert times.min == [0.0] and times.max[0] == pytest.approx((FRAMES - 1) / FPS)


def test_still_forest_has_no_animation(tmp_path: Path) -> None:
    doc = forest_gltf(small_forest(frames=0))
    assert doc.animations == []
    assert len(doc.skins) == TREES


def test_bark_and_leaf_materials(forest: Forest, doc: gl.GLTF2) -> None:
    bark = doc.materials[0]
    assert bark.name == "Bark" and bark.alphaMode in (None, gl.OPAQUE)
    assert bark.pbrMetallicRoughness.baseColorTexture is not None
    leaves = [m for m in doc.materials if m.name.startswith("Leaves_")]
    assert len(leaves) == TREES
    for m in leaves:
        assert m.alphaMode == gl.MASK and m.doubleSided
        assert m.pbrMetallicRoughness.baseColorTexture is not None
    assert all(im.mimeType == "image/png" for im in doc.images)
    # every leaf cloud hangs under a joint of its tree
    clouds = [i for i, n in enumerate(doc.nodes) if n.name and n.name.startswith("Leaves_")]
    assert len(clouds) == len(forest.foliage_anchors())
    joints = {j for s in doc.skins for j in s.joints}
    parent_of = {c: i for i, n in enumerate(doc.nodes) for c in n.children}
    assert all(parent_of[c] in joints for c in clouds)


def test_atlas_uvs_land_in_each_quads_tile(forest: Forest) -> None:
    """A quad's UV centre in the atlas shows the centre pixel of its own tile slice."""
    slices = read_slices(set_dir(forest.grammar.bark), forest.manifest.n_slices)
    n, size = len(slices), slices.shape[1]
    atlas = make_atlas(slices)
    columns, rows, cell, _pad = atlas_layout(n, size)
    assert atlas.shape == (rows * cell, columns * cell, 3)
    tiles = forest.tile_indices[0, : len(forest.pieces[forest.graph.piece[0]].quads)]
    uv = atlas_uv(tile_udim_st(tiles), n, size)
    assert uv.min() >= 0 and uv.max() <= 1
    # the point at st (0.3, 0.3) inside each quad's tile (corner 0 is st 0, corner 2 st 1),
    # off the texel boundaries so float rounding cannot move it to a neighbouring texel
    point = (0.7 * uv[:, 0] + 0.3 * uv[:, 2]) * np.array([atlas.shape[1], atlas.shape[0]])
    got = atlas[point[:, 1].astype(int), point[:, 0].astype(int)]
    want = slices[np.maximum(tiles, 0), int(0.7 * size), int(0.3 * size)]
    assert np.array_equal(got, want)
    # v runs down the image: a quad corner at t = 1 (its tile's top) lies above one at t = 0
    assert (uv[:, 1, 1] < uv[:, 0, 1]).all()


def test_species_tile_set_is_baked(tmp_path: Path) -> None:
    """The atlas holds the grammar's set: the first tile of oak's set sits in cell 0."""
    from forest.growth.generate import ForestOptions, generate_forest
    from forest.growth.presets import load_preset

    f = generate_forest(load_preset("birch"), 1, ForestOptions(trees=1))
    doc = forest_gltf(f)
    blob = doc.binary_blob()
    view = doc.bufferViews[doc.images[0].bufferView]
    png = blob[view.byteOffset : view.byteOffset + view.byteLength]
    path = tmp_path / "atlas.png"
    path.write_bytes(png)
    atlas = read_pixels(path)
    first = read_pixels(set_dir("birch") / "bark.1001.png")[..., :3]
    pad = atlas_layout(f.manifest.n_slices, first.shape[0])[3]
    assert np.array_equal(atlas[pad : pad + first.shape[0], pad : pad + first.shape[1]], first)


def test_size_cap_is_a_limit_error(forest: Forest, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(document, "MAX_VERTICES", 1000)
    with pytest.raises(LimitError) as err:
        forest_gltf(forest)
    assert err.value.path == "trees"


def test_missing_tiles_name_the_folder(forest: Forest, tmp_path: Path) -> None:
    with pytest.raises(ForestError) as err:
        forest_gltf(forest, tiles=tmp_path)
    assert err.value.path == str(tmp_path)


def test_glb_round_trips_through_pygltflib(doc: gl.GLTF2) -> None:
    data = glb_bytes(doc)
    again = gl.GLTF2.load_from_bytes(data)
    assert len(again.nodes) == len(doc.nodes)
    assert again.binary_blob() == doc.binary_blob()
    assert len(io.BytesIO(data).getvalue()) % 4 == 0


def cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "cli", *args],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip


def test_cli_writes_glb_by_suffix(tmp_path: Path) -> None:
    r = cli("generate", "--preset", "almond", "--seed", "2", "--frames", "3", "-o", "t.glb",
            cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "skinned" in r.stdout
    doc = gl.GLTF2.load(str(tmp_path / "t.glb"))
    assert len(doc.skins) == 1 and len(doc.animations) == 1


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (["-o", "t.gltf"], "t.gltf"),
        (["-o", "missing/t.glb"], "missing"),
        (["--trees", "0", "-o", "t.glb"], "trees"),
        (["--tiles", "nowhere", "-o", "t.glb"], "nowhere"),
    ],
)
def test_cli_bad_input_is_one_line(tmp_path: Path, args: list[str], field: str) -> None:
    r = cli("generate", "--preset", "almond", *args, cwd=tmp_path)
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and field in lines[0], r.stderr
    assert not any(p.suffix == ".glb" for p in tmp_path.rglob("*"))


def test_pieces_instanced_in_a_second_scene(forest: Forest, doc: gl.GLTF2) -> None:
    """Scene 1 instances every piece at its rest transform; scene 0 stays the default."""
    from forest.geometry.transforms import decompose_similarity

    assert doc.scene == 0 and len(doc.scenes) == 2
    assert doc.extensionsUsed == ["EXT_mesh_gpu_instancing"]
    assert not doc.extensionsRequired
    total = 0
    t_all = decompose_similarity(forest.transforms)[0]
    blob = doc.binary_blob()
    for n in doc.scenes[1].nodes:
        node = doc.nodes[n]
        attrs = node.extensions["EXT_mesh_gpu_instancing"]["attributes"]
        acc = doc.accessors[attrs["TRANSLATION"]]
        view = doc.bufferViews[acc.bufferView]
        t = np.frombuffer(blob, np.float32, acc.count * 3, view.byteOffset).reshape(-1, 3)
        name = node.name.removeprefix("Pieces_")
        pid = [p.name for p in forest.pieces].index(name)
        assert np.allclose(t, t_all[forest.graph.piece == pid], atol=1e-5)
        total += acc.count
    assert total == forest.n_instances


def _node_world(doc: gl.GLTF2) -> dict[int, np.ndarray]:
    """World matrix of every node from the nodes' own TRS (the file's first sample)."""
    from forest.geometry.transforms import compose_similarity

    parent = {c: i for i, n in enumerate(doc.nodes) for c in (n.children or [])}

    def local(n: gl.Node) -> np.ndarray:
        s = (n.scale or [1.0, 1.0, 1.0])[0]
        return compose_similarity(n.translation or [0.0] * 3, n.rotation or [0, 0, 0, 1], s)

    out: dict[int, np.ndarray] = {}
    for i in range(len(doc.nodes)):
        m, j = local(doc.nodes[i]), i
        while j in parent:
            j = parent[j]
            m = local(doc.nodes[j]) @ m
        out[i] = m
    return out


def test_leaf_clouds_sit_where_the_forest_puts_them(forest: Forest, doc: gl.GLTF2) -> None:
    """Each cloud node, composed through its joint's first-sample frame, has the cloud's posed
    centre and diameter (a node under a joint inherits the joint's whole transform)."""
    world = _node_world(doc)
    clouds = [i for i, n in enumerate(doc.nodes) if (n.name or "").startswith("Leaves_")]
    a = forest.foliage_anchors()
    assert len(clouds) == len(a)
    pick = np.array([int(doc.nodes[i].name.split("_")[1]) for i in clouds])
    m = np.array([world[i] for i in clouds])
    centre = a.positions(forest.palette(0.0 if forest.animated else None))[pick]
    size = np.ptp(centre, axis=0).max()
    np.testing.assert_allclose(m[:, :3, 3], centre, atol=1e-5 * size)
    np.testing.assert_allclose(np.cbrt(np.linalg.det(m[:, :3, :3])), a.size[pick], rtol=1e-5)
