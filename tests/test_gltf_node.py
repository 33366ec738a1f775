"""Every GLB passes the Khronos glTF-Validator with 0 errors, and loads in three.js's
GLTFLoader under Node: one scene, per tree a bark and a leaves SkinnedMesh (the tree mesh's two
primitives) with their textures, the Wind clip; their skinned vertices at two frames equal the
library's skinning within 3e-4 of the tree's height in the default (quantized) packing: int16
rotation keys and positions; measured 1.3e-4), 1e-4 in the float one. The meshopt-compressed
file (three.js with its MeshoptDecoder) skins to exactly the quantized file's vertices; every
packing and both profiles pass the validator. The game profile's lower levels of detail
(MSFT_lod, in no scene) load through GLTFLoader's parser on the LOD0 skeleton's own bones and
skin as the file says.

The Node packages are pinned in tests/node/package-lock.json; `npm ci` in tests/node (the CI
script runs it) installs them. A missing install fails these tests, it does not skip them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pygltflib as gl
import pytest
from helpers_gltf import (
    CHECK_FRAMES,
    FPS,
    TREES,
    WHOLE_LOD0,
    expected_tree,
    glb_skinned,
    node_tools,
    run_node,
    small_forest,
    tree_mesh_nodes,
)

from forest.gltf.compress import DEFAULT_PACKING, Packing
from forest.gltf.document import write_glb
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset

pytestmark = pytest.mark.slow  # the glTF-Validator and three.js under Node


@pytest.fixture(scope="module")
def forest() -> Forest:
    return small_forest()


@pytest.fixture(scope="module")
def glb(forest: Forest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    why = node_tools()
    if why:
        pytest.fail(why, pytrace=False)
    return write_glb(
        forest, tmp_path_factory.mktemp("glb") / "forest.glb", lod0_triangles=WHOLE_LOD0
    )


TOLERANCE: dict[Packing, float] = {"float": 1e-4, "quantized": 3e-4, "meshopt": 3e-4}


def validate(path: Path) -> dict[str, Any]:
    report = run_node("validate.mjs", str(path))
    issues = report["issues"]
    errors = [m for m in issues["messages"] if m["severity"] == 0]
    assert issues["numErrors"] == 0, errors[:10]
    return report


def test_validator_finds_no_error_or_warning(glb: Path) -> None:
    report = validate(glb)
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"][:10]
    info = report["info"]
    assert info["hasSkins"] and info["hasTextures"] and info["animationCount"] == 1
    assert info["maxInfluences"] == 4


@pytest.mark.parametrize(
    ("preset", "trees", "frames"),
    [("pine", 1, 0), ("willow", 1, 2), ("birch", 3, 2)],
)
def test_validator_on_other_species_and_still_forests(
    tmp_path: Path, preset: str, trees: int, frames: int
) -> None:
    if why := node_tools():
        pytest.fail(why, pytrace=False)
    f = generate_forest(load_preset(preset), 5, ForestOptions(trees=trees, frames=frames))
    report = validate(write_glb(f, tmp_path / f"{preset}.glb"))
    assert report["info"]["animationCount"] == (1 if frames else 0)


def _skinned(glb: Path, tmp_path: Path) -> tuple[dict[str, Any], np.ndarray]:
    """three.js's report of ``glb`` and its skinned vertices at the check frames."""
    times = [f / FPS for f in CHECK_FRAMES]
    out = tmp_path / f"{glb.stem}-positions.bin"
    report = run_node(
        "three_load.mjs", str(glb), "--times", ",".join(map(repr, times)), "--out", str(out)
    )
    return report, np.fromfile(out, np.float32).astype(np.float64)


def test_three_loads_skinned_trees_with_wind(glb: Path, forest: Forest, tmp_path: Path) -> None:
    report, got = _skinned(glb, tmp_path)
    meshes = report["skinned_meshes"]
    doc = gl.GLTF2.load(str(glb))
    # one glTF mesh per tree, its primitives (bark, runs of leaf cards) SkinnedMeshes on one
    # skeleton
    prims = [len(doc.meshes[doc.nodes[n].mesh].primitives) for n in tree_mesh_nodes(doc)]
    assert [m["name"] for m in meshes] == [
        f"Tree_{k:05d}_LOD0_{p}" for k in range(TREES) for p in range(1, prims[k] + 1)
    ]
    assert all(m["has_texture"] for m in meshes)
    (clip,) = report["animations"]
    assert clip["name"] == "Wind" and clip["tracks"] > 0
    assert report["textures"] == 2  # the repeating bark picture and the leaf texture
    # alpha-tested, double sided
    assert report["leaf_card_meshes"] == sum(prims) - TREES
    assert report["scenes"] == ["Forest"]
    at = 0
    for f in CHECK_FRAMES:
        expected = expected_tree(forest, doc, f / FPS)
        for k, tree in enumerate(expected):
            height = float(np.ptp(tree[0][:, 1]))
            for p, want in enumerate(tree):
                assert meshes[sum(prims[:k]) + p]["vertices"] == len(want)
                points = got[at : at + want.size].reshape(-1, 3)
                at += want.size
                err = np.abs(points - want).max()
                assert err <= TOLERANCE[DEFAULT_PACKING] * height, (f, k, p, err, height)
    assert at == got.size


@pytest.mark.parametrize("packing", ["float", "meshopt"])
def test_other_packings_validate_and_skin_alike(
    packing: Packing, glb: Path, forest: Forest, tmp_path: Path
) -> None:
    """The float file skins as the library does within 1e-4 of the height; the meshopt file
    decodes to the quantized file's data, so three.js skins it to the very same vertices (and
    bounds, within the quantization's error of the float file's)."""
    other = write_glb(
        forest, tmp_path / f"{packing}.glb", packing=packing, lod0_triangles=WHOLE_LOD0
    )
    report = validate(other)
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"][:10]
    used = report["info"].get("extensionsUsed", [])
    assert ("EXT_meshopt_compression" in used) == (packing == "meshopt")
    _, got = _skinned(other, tmp_path)
    _, quantized = _skinned(glb, tmp_path)
    doc = gl.GLTF2.load(str(glb))  # the vertex order is the same in every packing
    expected = [expected_tree(forest, doc, f / FPS) for f in CHECK_FRAMES]
    height = max(float(np.ptp(tree[0][:, 1])) for tree in expected[0])
    want = np.concatenate([p.ravel() for frame in expected for tree in frame for p in tree])
    assert np.abs(got - want).max() <= TOLERANCE[packing] * height
    if packing == "meshopt":
        assert np.array_equal(got, quantized)
    else:
        lo, hi = got.reshape(-1, 3).min(axis=0), got.reshape(-1, 3).max(axis=0)
        qpts = quantized.reshape(-1, 3)
        assert np.abs(qpts.min(axis=0) - lo).max() <= TOLERANCE["quantized"] * height
        assert np.abs(qpts.max(axis=0) - hi).max() <= TOLERANCE["quantized"] * height


def test_validator_on_the_film_profile(forest: Forest, tmp_path: Path) -> None:
    if why := node_tools():
        pytest.fail(why, pytrace=False)
    report = validate(write_glb(forest, tmp_path / "film.glb", profile="film"))
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"][:10]
    assert "MSFT_lod" not in report["info"].get("extensionsUsed", [])


def test_three_loads_every_level(glb: Path, tmp_path: Path) -> None:
    """Each tree's LOD1-LOD3 (nodes in no scene) load as SkinnedMeshes on the bones of its
    LOD0, textured (leaves and the impostor cut by alpha), and three.js skins them where the
    file's own skinning (helpers_gltf.glb_skinned) puts them at the last check frame."""
    out = tmp_path / "lods.bin"
    frame = CHECK_FRAMES[-1]
    report = run_node(
        "three_load.mjs", str(glb), "--lods", "--times", repr(frame / FPS), "--out", str(out)
    )
    doc = gl.GLTF2.load(str(glb))
    by_name = {n.name: i for i, n in enumerate(doc.nodes)}
    lods = report["lods"]
    levels = 4 if doc.materials[-1].name == "Impostor" else 3
    assert [(x["of"], x["name"]) for x in lods] == [
        (f"Tree_{k:05d}_LOD0", f"Tree_{k:05d}_LOD{lv}")
        for k in range(TREES)
        for lv in range(1, levels)
    ]
    got = np.fromfile(out, np.float32).astype(np.float64).reshape(-1, 3)
    at = sum(m["vertices"] for m in report["skinned_meshes"])
    for lod in lods:
        assert not lod["in_scene"]
        want = glb_skinned(doc, by_name[lod["name"]], frame)
        assert [m["vertices"] for m in lod["skinned_meshes"]] == [len(w) for w in want]
        for m, w in zip(lod["skinned_meshes"], want, strict=True):
            assert m["shares_bones"] and m["has_texture"]
            points = got[at : at + len(w)]
            at += len(w)
            # both from int16 keys and positions, three.js in float32: measured 4e-5
            height = float(np.ptp(w[:, 1]))  # the impostor's cards span the tree too
            assert np.abs(points - w).max() <= 1e-4 * height, lod["name"]
        if lod["name"].endswith("LOD3"):
            (cards,) = lod["skinned_meshes"]
            assert cards["vertices"] == 8 and cards["alpha_test"] == 0.5
    assert at == len(got)
