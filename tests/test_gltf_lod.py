"""The glTF game profile's levels of detail, read back from the written file of a mature oak
(seed 3, 24 wind frames): each level within its triangle budget (LOD0 <= 150 k, LOD1 <= 40 k,
LOD2 <= 8 k, LOD3 <= 4), one skin of at most 256 joints per tree, the MSFT_lod chain (LOD0 in
the scene, the lower levels in none), one material per kind, the meshopt file within 6 MB,
and every level's bark skinned at the last wind frame exactly where LOD0's is (the same
vertices on the same joints). The film profile keeps the full tree on every joint."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as gl
import pytest
from helpers_gltf import glb_skinned, read

from forest.gltf.document import write_glb
from forest.gltf.lod import COVERAGE, MSFT_LOD, SCREEN_COVERAGE
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.joint_budget import GAME_JOINTS
from forest.growth.presets import load_preset
from forest.lod.impostor import gl_missing
from forest.lod.targets import GAME_LOD0

FRAMES = 24
BUDGETS = (150_000, 40_000, 8_000, 4)  # triangles of LOD0..LOD3 (issue 24's game budgets)
FILE_BYTES = 6_000_000  # a mature oak's game .glb with 24 wind frames (issue 24's budget)


@pytest.fixture(scope="module")
def oak() -> Forest:
    return generate_forest(load_preset("oak"), 3, ForestOptions(trees=1, frames=FRAMES))


@pytest.fixture(scope="module")
def glb(oak: Forest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_glb(oak, tmp_path_factory.mktemp("oak") / "oak.glb")


def _triangles(doc: gl.GLTF2, mesh: int) -> int:
    return sum(doc.accessors[p.indices].count // 3 for p in doc.meshes[mesh].primitives)


def test_levels_within_their_budgets(glb: Path) -> None:
    doc = gl.GLTF2.load(str(glb))
    baked = gl_missing() is None
    by_name = {n.name: i for i, n in enumerate(doc.nodes)}
    lod0 = doc.nodes[by_name["Tree_00000_LOD0"]]
    levels = 4 if baked else 3
    ids = lod0.extensions[MSFT_LOD]["ids"]
    assert [doc.nodes[i].name for i in ids] == [f"Tree_00000_LOD{k}" for k in range(1, levels)]
    assert lod0.extras[SCREEN_COVERAGE] == list(COVERAGE[:levels])
    assert doc.extensionsUsed.count(MSFT_LOD) == 1 and MSFT_LOD not in doc.extensionsRequired
    scene = set(doc.scenes[0].nodes)
    assert by_name["Tree_00000_LOD0"] in scene and not scene & set(ids)
    tris = []
    for k in range(levels):
        node = doc.nodes[by_name[f"Tree_00000_LOD{k}"]]
        assert node.skin == lod0.skin and doc.meshes[node.mesh].name == node.name
        tris.append(_triangles(doc, node.mesh))
    print("triangles per level", tris, "bytes", glb.stat().st_size)
    for k, (n, budget) in enumerate(zip(tris, BUDGETS, strict=False)):
        assert 0 < n <= budget, (k, n, budget)
    # the full oak is heavier: LOD0 is cut to the profile's default budget
    assert 0.95 * GAME_LOD0.budget <= tris[0] <= GAME_LOD0.budget
    assert len(doc.skins) == 1 and len(doc.skins[0].joints) <= GAME_JOINTS
    names = sorted(m.name for m in doc.materials)
    assert names == sorted(["Bark", "Leaves", *(["Impostor"] if baked else [])])
    if baked:
        impostor = next(m for m in doc.materials if m.name == "Impostor")
        assert impostor.alphaMode == gl.MASK and impostor.pbrMetallicRoughness.baseColorTexture
    (anim,) = doc.animations
    assert anim.name == "Wind"


def test_default_file_within_six_megabytes(glb: Path, oak: Forest, tmp_path: Path) -> None:
    """The default file (quantized, read by every importer) meets the budget; meshopt is
    smaller still."""
    assert glb.stat().st_size <= FILE_BYTES, glb.stat().st_size
    path = write_glb(oak, tmp_path / "oak.glb", packing="meshopt")
    assert path.stat().st_size <= 0.5 * glb.stat().st_size, path.stat().st_size


def test_bark_is_welded_on_a_repeating_picture(glb: Path) -> None:
    """LOD0's bark shares vertices across quads (an atlas splits every quad corner: 4 per
    quad): at most 1.6 per quad, read from a REPEAT-wrapped bark picture; the leaf cards are
    flat (no NORMAL: a reader's face normal is the card's) in runs a 16-bit index reaches."""
    doc = gl.GLTF2.load(str(glb))
    lod0 = next(n for n in doc.nodes if n.name == "Tree_00000_LOD0")
    bark, *leaves = doc.meshes[lod0.mesh].primitives
    quads = doc.accessors[bark.indices].count // 6
    assert doc.accessors[bark.attributes.POSITION].count <= 1.6 * quads
    texture = doc.materials[bark.material].pbrMetallicRoughness.baseColorTexture.index
    sampler = doc.samplers[doc.textures[texture].sampler]
    assert sampler.wrapS == sampler.wrapT == gl.REPEAT
    assert leaves and all(p.attributes.NORMAL is None for p in leaves)
    assert all(doc.accessors[p.indices].componentType == gl.UNSIGNED_SHORT for p in leaves)


def test_each_levels_bark_is_lod0s_at_the_last_frame(glb: Path) -> None:
    """Every bark vertex of LOD1 and LOD2 is one of LOD0's (the same quantized rest point,
    joints and weights) and glTF's skinning from the file puts it where LOD0's is at the last
    wind frame; the impostor's cards stay inside LOD0's bounds grown by 2 % of the height."""
    doc = gl.GLTF2.load(str(glb))
    by_name = {n.name: i for i, n in enumerate(doc.nodes)}
    last = FRAMES - 1
    lod0 = by_name["Tree_00000_LOD0"]
    prim0 = doc.meshes[doc.nodes[lod0].mesh].primitives[0]
    rest0 = read(doc, prim0.attributes.POSITION)
    joints0 = read(doc, prim0.attributes.JOINTS_0)
    posed0 = glb_skinned(doc, lod0, last)
    height = float(np.ptp(np.concatenate(posed0)[:, 1]))
    where = {row.tobytes(): i for i, row in enumerate(rest0)}
    for k in (1, 2):
        node = by_name[f"Tree_00000_LOD{k}"]
        prim = doc.meshes[doc.nodes[node].mesh].primitives[0]
        # the file holds LOD0's bark vertices once: lower levels index into them
        assert vars(prim.attributes) == vars(prim0.attributes), k
        rest = read(doc, prim.attributes.POSITION)
        index = np.array([where[row.tobytes()] for row in rest])
        assert np.array_equal(read(doc, prim.attributes.JOINTS_0), joints0[index])
        posed = glb_skinned(doc, node, last)[0]
        assert np.abs(posed - posed0[0][index]).max() <= 1e-6 * height, k
    if "Tree_00000_LOD3" in by_name:
        (cards,) = glb_skinned(doc, by_name["Tree_00000_LOD3"], last)
        every = np.concatenate(posed0)
        lo, hi = every.min(axis=0) - 0.02 * height, every.max(axis=0) + 0.02 * height
        assert np.all((cards >= lo) & (cards <= hi))


def test_film_profile_keeps_the_full_tree(oak: Forest, tmp_path: Path) -> None:
    doc = gl.GLTF2.load(str(write_glb(oak, tmp_path / "film.glb", profile="film")))
    assert MSFT_LOD not in (doc.extensionsUsed or [])
    (node,) = [n for n in doc.nodes if n.mesh is not None]
    assert node.name == "Tree_00000_Mesh" and node.extensions in (None, {})
    assert _triangles(doc, node.mesh) > BUDGETS[0]  # the full oak (about 265 k)
    assert len(doc.skins[0].joints) > GAME_JOINTS  # a joint per bone


@pytest.mark.skipif(gl_missing() is not None, reason="needs the render extra's GL")
def test_capped_lod0_keeps_the_crowns_coverage(oak: Forest) -> None:
    """The game LOD0 (fewer leaf cards, each grown by the area it stands for) covers what the
    full oak covers from the front, the side and above, within 5 % (measured within 1.3 %)."""
    from forest.bark.tilesets import mean_colour
    from forest.geometry.transforms import invert_similarity
    from forest.growth.foliage import leaf_texture
    from forest.growth.generate import foliage_or_none
    from forest.lod.levels import tree_levels
    from forest.lod.select import BarkMesh, LeavesMesh
    from forest.lod.views import draw_views
    from forest.usd.skinned import joint_frames, leaves_mesh, tree_mesh, tree_slices

    anchors = foliage_or_none(oak)
    assert anchors is not None
    inst, bones = tree_slices(oak, GAME_JOINTS)[0]
    still = joint_frames(oak, GAME_JOINTS).still
    to_tree = invert_similarity(oak.tree_transforms[0])
    bark = BarkMesh(*tree_mesh(oak, inst, bones, to_tree, still, weld=True, budget=GAME_JOINTS))
    made = leaves_mesh(oak, anchors, inst, bones, to_tree, still, GAME_JOINTS)
    assert made is not None
    leaves = LeavesMesh(*made)
    full, lod0 = (
        tree_levels(oak, anchors, inst, bones, to_tree, still, bark, leaves, GAME_JOINTS, cap)[0]
        for cap in (None, GAME_LOD0)
    )
    assert sum(lod0.triangles) <= GAME_LOD0.budget < sum(full.triangles)
    dirs = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1e-4]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    picture, colour = leaf_texture(anchors.family), mean_colour(oak.grammar.bark)
    a = draw_views(full.bark, full.leaves, picture, dirs, 512, colour)
    b = draw_views(
        lod0.bark, lod0.leaves, picture, dirs, 512, colour, centre=a.centre, radius=a.radius
    )
    for x, y in zip(a.albedo, b.albedo, strict=True):
        cover_a, cover_b = (x[..., 3] > 0).mean(), (y[..., 3] > 0).mean()
        assert abs(cover_b / cover_a - 1.0) <= 0.05, (cover_a, cover_b)


def test_lower_trunk_keeps_its_colour(tmp_path: Path) -> None:
    """The repeating picture holds the bark class's tiles only; a set with a lower trunk
    (birch's black foot) tints those vertices with COLOR_0 (multiplied into the base colour
    by glTF readers), shared by every level; a set without one writes no COLOR_0."""
    birch = generate_forest(load_preset("birch"), 1, ForestOptions(trees=1))
    doc = gl.GLTF2.load(str(write_glb(birch, tmp_path / "birch.glb", impostor=False)))
    lod0 = next(n for n in doc.nodes if n.name == "Tree_00000_LOD0")
    bark = doc.meshes[lod0.mesh].primitives[0]
    assert bark.attributes.COLOR_0 is not None
    acc = doc.accessors[bark.attributes.COLOR_0]
    assert acc.componentType == gl.UNSIGNED_BYTE and acc.normalized and acc.type == gl.VEC4
    colour = read(doc, bark.attributes.COLOR_0)  # as a reader sees it, in [0, 1]
    assert (colour[:, 3] == 1).all()
    tinted = (colour[:, :3] < 1).any(axis=1)
    assert 0 < tinted.mean() < 0.2  # the foot, not the tree
    assert colour[tinted, :3].max() < 0.5  # darker: birch's foot is nearly black
    for name in ("Tree_00000_LOD1", "Tree_00000_LOD2"):
        node = next(n for n in doc.nodes if n.name == name)
        assert doc.meshes[node.mesh].primitives[0].attributes.COLOR_0 == bark.attributes.COLOR_0
    oak = generate_forest(load_preset("oak"), 1, ForestOptions(trees=1))
    doc = gl.GLTF2.load(str(write_glb(oak, tmp_path / "oak.glb", impostor=False)))
    assert all(p.attributes.COLOR_0 is None for m in doc.meshes for p in m.primitives)
