"""glTF export (forest.gltf) on its own: determinism, the document's structure (one scene, a
skinned mesh of bark and leaves per tree, the wind animation without constant channels, bark
atlas and leaf cards), the file's own skinning against the library's, the atlas UVs, caps and
bad input."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pygltflib as gl
import pytest
from helpers_gltf import (
    FPS,
    FRAMES,
    TREES,
    expected_tree,
    glb_skinned,
    quad_corners,
    read,
    small_forest,
)
from helpers_skin import usd_skinned_points
from pxr import Usd, UsdGeom

from forest.bark.atlas import atlas_layout, atlas_uv, make_atlas, read_slices
from forest.bark.images import read_pixels
from forest.bark.tilesets import set_dir
from forest.errors import ForestError, LimitError
from forest.gltf import document
from forest.gltf.compress import glb
from forest.gltf.document import Profile, forest_gltf, write_glb
from forest.gltf.skin import CONSTANT_TOL, sample_pose
from forest.growth.generate import Forest
from forest.growth.joint_budget import GAME_JOINTS
from forest.usd.materials import tile_udim_st
from forest.usd.scene import write_scene
from forest.usd.skinned import joint_frames, tree_mesh, tree_slices

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def forest() -> Forest:
    return small_forest()


@pytest.fixture(scope="module")
def doc(forest: Forest) -> gl.GLTF2:
    """The film profile's layout (one mesh per tree) on the game's joints: what the skinning
    checks below compare with USD's form on the same joints."""
    return forest_gltf(forest, joint_budget=GAME_JOINTS, profile="film")


def test_same_forest_same_bytes(forest: Forest, tmp_path: Path) -> None:
    a = write_glb(forest, tmp_path / "a.glb").read_bytes()
    b = write_glb(small_forest(), tmp_path / "b.glb").read_bytes()
    assert a == b
    assert a[:4] == b"glTF"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.glb", "b.glb"]  # nothing else


def test_one_scene_one_skinned_mesh_per_tree(forest: Forest, doc: gl.GLTF2) -> None:
    assert doc.scene == 0 and len(doc.scenes) == 1
    assert not doc.extensionsUsed and not doc.extensionsRequired
    assert len(doc.skins) == TREES and len(doc.meshes) == TREES
    slices = tree_slices(forest, GAME_JOINTS)
    parent_of = {c: i for i, n in enumerate(doc.nodes) for c in n.children}
    for skin, (_inst, bones) in zip(doc.skins, slices, strict=True):
        assert len(skin.joints) == bones.stop - bones.start == GAME_JOINTS  # an almond has more
        assert skin.skeleton == skin.joints[0]
        # joints are parent-first: each joint's parent joint comes earlier
        index = {n: j for j, n in enumerate(skin.joints)}
        for j, n in enumerate(skin.joints[1:], 1):
            assert index[parent_of[n]] < j
    skinned = [n for n in doc.nodes if n.skin is not None]
    assert [n.name for n in skinned] == [f"Tree_{k:05d}_Mesh" for k in range(TREES)]
    roots = set(doc.scenes[0].nodes)
    assert all(doc.nodes.index(n) in roots for n in skinned)  # skinned nodes stay at the root
    # every node is a tree, a joint or a tree's mesh: no node per leaf spray
    assert len(doc.nodes) == 2 * TREES + sum(len(s.joints) for s in doc.skins)
    for n in skinned:
        bark, leaves = doc.meshes[n.mesh].primitives
        for prim in (bark, leaves):
            for attr in ("POSITION", "NORMAL", "TEXCOORD_0", "JOINTS_0", "WEIGHTS_0"):
                assert getattr(prim.attributes, attr) is not None, attr
        assert doc.accessors[bark.attributes.JOINTS_0].componentType == gl.UNSIGNED_BYTE


def test_wind_animation_drops_constant_channels(forest: Forest, doc: gl.GLTF2) -> None:
    """A channel per joint and path whose keys change; a path left out is constant over the
    clip, and its node holds that value."""
    (anim,) = doc.animations
    assert anim.name == "Wind"
    times = doc.accessors[anim.samplers[0].input]
    assert times.count == FRAMES
    assert times.min == [0.0] and times.max[0] == pytest.approx((FRAMES - 1) / FPS)
    pose = sample_pose(forest, joint_frames(forest, GAME_JOINTS))
    targeted = {(c.target.node, c.target.path) for c in anim.channels}
    assert {p for _, p in targeted} == {"rotation"}  # wind turns joints; roots stay still
    default = {"translation": [0.0] * 3, "rotation": [0.0, 0.0, 0.0, 1.0], "scale": [1.0] * 3}
    kept = 0
    for skin, (_inst, bones) in zip(doc.skins, tree_slices(forest, GAME_JOINTS), strict=True):
        for j, node in enumerate(skin.joints):
            b = bones.start + j
            for path, keys in (("translation", pose.t), ("rotation", pose.q), ("scale", pose.s)):
                k = keys[:, b]
                if (node, path) in targeted:
                    kept += 1
                    assert np.abs(k - k[0]).max() > CONSTANT_TOL
                    continue
                value = getattr(doc.nodes[node], path) or default[path]
                np.testing.assert_allclose(k, np.broadcast_to(value, k.shape), atol=CONSTANT_TOL)
    assert kept == len(anim.channels) > 0


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
        assert m.alphaMode == gl.MASK and m.alphaCutoff == 0.5 and m.doubleSided
        assert m.pbrMetallicRoughness.baseColorTexture is not None
    assert all(im.mimeType == "image/png" for im in doc.images)
    for mesh in doc.meshes:
        assert doc.materials[mesh.primitives[0].material].name == "Bark"
        assert doc.materials[mesh.primitives[1].material].alphaMode == gl.MASK


def test_bark_is_welded_as_in_usd(forest: Forest, doc: gl.GLTF2) -> None:
    """The bark's points and normals are the USD skinned form's welded ones: a vertex splits
    only where its corners' UVs differ, and corners at one welded point share its normal."""
    inst, bones = tree_slices(forest, GAME_JOINTS)[0]
    still = joint_frames(forest).still
    to_tree = np.linalg.inv(forest.tree_transforms[0])
    pts, nrm, quads, *_ = tree_mesh(
        forest, inst, bones, to_tree, still, weld=True, budget=GAME_JOINTS
    )
    prim = doc.meshes[0].primitives[0]
    p, n = read(doc, prim.attributes.POSITION), read(doc, prim.attributes.NORMAL)
    uv = read(doc, prim.attributes.TEXCOORD_0)
    corner = read(doc, prim.indices).reshape(-1, 6)[:, [0, 1, 2, 5]]
    np.testing.assert_allclose(p[corner], pts[quads], atol=1e-5)
    np.testing.assert_allclose(n[corner], nrm[quads], atol=1e-6)
    # no two vertices share a welded point and a UV
    key = np.concatenate([quads.reshape(-1, 1), uv[corner.ravel()]], axis=1)
    assert len(np.unique(key, axis=0)) == len(p)


def test_file_skinning_is_the_librarys(forest: Forest, doc: gl.GLTF2) -> None:
    """Bark and leaves as glTF skins them from the file (joints, inverse binds, weights, the
    animation's keys or the nodes' own TRS) land where the generator's palette puts the
    pieces' corners and the leaf cards, at the first and the last frame, within 1e-4 of the
    tree's height (the two skin from different bind poses: see test_usd)."""
    nodes = [i for i, n in enumerate(doc.nodes) if n.skin is not None]
    for frame in (0, FRAMES - 1):
        want = expected_tree(forest, doc, frame / FPS)
        for k, node in enumerate(nodes):
            got = glb_skinned(doc, node, frame)
            height = np.ptp(want[k][0][:, 1])
            assert len(got) == len(want[k]) == 2
            for g, w in zip(got, want[k], strict=True):
                assert g.shape == w.shape
                assert np.abs(g - w).max() <= 1e-4 * height, (frame, k)


def test_surface_equals_the_usd_skinned_form(forest: Forest, doc: gl.GLTF2, tmp_path: Path) -> None:
    """Every corner of bark and leaves, skinned by glTF's rules from the file, is where USD's
    own skinning (UsdSkel) of the skinned form's Bark and Leaves puts that corner, at three
    frames, within 1e-6 of the tree's height (float32 points in both; measured 4e-7). Both
    forms on the same joints: the game's budget."""
    usd = write_scene(forest, tmp_path / "f.usdc", skinned=True, joint_budget=GAME_JOINTS)
    stage = Usd.Stage.Open(str(usd))
    nodes = [i for i, n in enumerate(doc.nodes) if n.skin is not None]
    for frame in (0, 3, FRAMES - 1):
        for k, node in enumerate(nodes):
            root = stage.GetPrimAtPath(f"/World/Forest/Trees/Tree_{k:05d}")
            got = glb_skinned(doc, node, frame)
            for p, name in enumerate(("Bark", "Leaves")):
                usd = usd_skinned_points(root, name, frame)
                mesh = UsdGeom.Mesh(root.GetChild(name))
                faces = np.array(mesh.GetFaceVertexIndicesAttr().Get())
                corners = quad_corners(doc, doc.meshes[k].primitives[p])
                err = np.abs(got[p][corners] - usd[faces]).max()
                assert err <= 1e-6 * np.ptp(usd[:, 1]), (frame, k, name, err)


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


@pytest.mark.parametrize("profile", ["film", "game"])
def test_species_tile_set_is_baked(profile: Profile, tmp_path: Path) -> None:
    """The bark picture holds the grammar's set: the first tile of birch's set sits in cell 0
    of the film profile's atlas (inside its border) and of the game profile's super tile of
    the bark class's 8 tiles (4 x 2 cells, no border: it repeats)."""
    from forest.growth.generate import ForestOptions, generate_forest
    from forest.growth.presets import load_preset

    f = generate_forest(load_preset("birch"), 1, ForestOptions(trees=1))
    doc = forest_gltf(f, profile=profile, impostor=False)
    blob = doc.binary_blob()
    view = doc.bufferViews[doc.images[0].bufferView]
    png = blob[view.byteOffset : view.byteOffset + view.byteLength]
    path = tmp_path / "bark.png"
    path.write_bytes(png)
    picture = read_pixels(path)
    first = read_pixels(set_dir("birch") / "bark.1001.png")[..., :3]
    size = first.shape[0]
    if profile == "film":
        pad = atlas_layout(f.manifest.n_slices, size)[3]
    else:
        pad = 0
        assert picture.shape[:2] == (2 * size, 4 * size)
        last = read_pixels(set_dir("birch") / "bark.1008.png")[..., :3]
        assert np.array_equal(picture[size:, 3 * size :], last)
    assert np.array_equal(picture[pad : pad + size, pad : pad + size], first)


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
    data = glb(doc)
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
    assert "MSFT_lod" in doc.extensionsUsed  # the game profile: levels of detail


def test_cli_profile_film(tmp_path: Path) -> None:
    r = cli("generate", "--preset", "almond", "--seed", "2", "--frames", "2", "--profile",
            "film", "-o", "t.glb", cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    doc = gl.GLTF2.load(str(tmp_path / "t.glb"))
    assert not doc.extensionsUsed or "MSFT_lod" not in doc.extensionsUsed
    assert [n.name for n in doc.nodes if n.mesh is not None] == ["Tree_00000_Mesh"]


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (["-o", "t.gltf"], "t.gltf"),
        (["-o", "missing/t.glb"], "missing"),
        (["--trees", "0", "-o", "t.glb"], "trees"),
        (["--tiles", "nowhere", "-o", "t.glb"], "nowhere"),
        (["--profile", "film", "-o", "t.usdc"], "profile"),
        (["--lod", "-o", "t.glb"], "--profile"),
    ],
)
def test_cli_bad_input_is_one_line(tmp_path: Path, args: list[str], field: str) -> None:
    r = cli("generate", "--preset", "almond", *args, cwd=tmp_path)
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and field in lines[0], r.stderr
    assert not any(p.suffix == ".glb" for p in tmp_path.rglob("*"))
