"""A forest as one glTF 2.0 binary (.glb): per tree one skinned mesh on its skeleton (a bark
primitive and a leaves primitive), the wind as one animation; written atomically,
byte-identical for the same forest.

Scene layout (y up, metres, as the USD scenes): one scene; for tree k a root node
``Tree_<k>`` (the tree transform) holding the joint hierarchy, and a root node
``Tree_<k>_Mesh`` with the skinned mesh (glTF skins ignore a skinned node's own transform, so
it stays at the root with none). The meshes are those of the USD skinned form
(:mod:`forest.usd.skinned`): the welded bark and the leaf cards, in the bind pose.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
import pygltflib as gl

from forest.atomic import replaced_when_written
from forest.bark.atlas import atlas_uv, make_atlas, read_slices, tile_folder
from forest.bark.lattice import (
    bark_tiles,
    lattice_st,
    lattice_uv,
    lower_quads,
    lower_tint,
    super_tile,
)
from forest.caps import MAX_VERTICES, glb_vertices
from forest.errors import ForestError, LimitError, OutputError
from forest.geometry.transforms import F64, invert_similarity
from forest.gltf.bark import add_bark_material
from forest.gltf.buffer import Blob
from forest.gltf.compress import DEFAULT_PACKING, Packing, glb_parts, pack
from forest.gltf.leaves import LeafMaterials
from forest.gltf.lod import (
    IMPOSTOR_LEVEL,
    ImpostorSheet,
    add_impostor_material,
    add_levels,
    bark_quads,
    chain_levels,
    impostor_quads,
    leaf_chunks,
    leaf_quads,
)
from forest.gltf.primitive import SkinnedQuads, find_rows, skinned_primitive
from forest.gltf.skin import (
    TreeSkin,
    add_tree_skeleton,
    add_wind,
    rest_trs,
    sample_pose,
    similarity_trs,
)
from forest.growth.generate import Forest, foliage_or_none
from forest.growth.joint_budget import GAME_JOINTS
from forest.lod.levels import tree_levels
from forest.lod.select import BarkMesh, LeavesMesh
from forest.lod.targets import GAME_LOD0, TARGETS, LodTarget
from forest.usd.skinned import joint_frames, leaves_mesh, tree_mesh, tree_slices

if TYPE_CHECKING:
    from forest.lod.impostor import Impostor

Progress = Callable[[str, int, int], None]


def baked_vertices(forest: Forest, profile: str = "film", lod0_triangles: int | None = None) -> int:
    """Vertices the .glb's meshes will have, counted before baking, tree by tree
    (:func:`forest.caps.glb_vertices` of each tree's bark quads and leaf cards): film, 4
    per bark quad (every quad maps a whole tile of the atlas) and every leaf spray's own;
    game, the levels of detail within their budgets."""
    trees = forest.options.trees
    tree = forest.graph.tree
    per_piece = np.array([len(p.quads) for p in forest.pieces])
    quads = np.bincount(tree, per_piece[forest.graph.piece], minlength=trees)
    leaf_vertices = leaf_triangles = np.zeros(trees, np.int64)
    anchors = foliage_or_none(forest)
    if anchors is not None:
        models = anchors.models()
        of_spray = tree[anchors.instance]
        per_model = np.array([len(c.positions) for c in models])
        leaf_vertices = np.bincount(of_spray, per_model[anchors.model], minlength=trees)
        cards = np.array([2 * c.n_cards for c in models])
        leaf_triangles = np.bincount(of_spray, cards[anchors.model], minlength=trees)
    return int(
        sum(
            glb_vertices(q, v, t, profile, lod0_triangles)
            for q, v, t in zip(
                quads.tolist(), leaf_vertices.tolist(), leaf_triangles.tolist(), strict=True
            )
        )
    )


def check_size(forest: Forest, profile: str = "film", lod0_triangles: int | None = None) -> None:
    n = baked_vertices(forest, profile, lod0_triangles)
    if n > MAX_VERTICES:
        raise LimitError(
            f"{forest.options.trees} trees bake to {n} vertices in a {profile} .glb, over the "
            f"glTF cap of {MAX_VERTICES}; use fewer trees (or USD, which instances the pieces)",
            path="trees",
            limit=MAX_VERTICES,
        )


Profile = Literal["game", "film"]
PROFILES: tuple[Profile, ...] = ("game", "film")
DEFAULT_PROFILE: Profile = "game"
# a game LOD0 under LOD1's budget would keep fewer pieces than LOD1; over the top it is the
# full tree anyway
MIN_LOD0_TRIANGLES = TARGETS[1].budget
MAX_LOD0_TRIANGLES = 100_000_000


def game_lod0(triangles: int, profile: Profile) -> LodTarget:
    """The game profile's LOD0 target for a budget of ``triangles`` (refused for film, which
    keeps the full tree, and under :data:`MIN_LOD0_TRIANGLES`)."""
    if profile != "game":
        raise ForestError(
            "--lod0-triangles applies to the game profile (film keeps the full tree)",
            path="lod0_triangles",
        )
    if not MIN_LOD0_TRIANGLES <= triangles <= MAX_LOD0_TRIANGLES:
        raise ForestError(
            f"LOD0 budget must be {MIN_LOD0_TRIANGLES:,} to {MAX_LOD0_TRIANGLES:,} triangles, "
            f"got {triangles:,}",
            path="lod0_triangles",
        )
    return LodTarget(1.0, triangles)


def profile_joints(profile: Profile) -> int | None:
    """A profile's joints per tree: a game engine's skin limit, or one per bone (film)."""
    return GAME_JOINTS if profile == "game" else None


def forest_gltf(
    forest: Forest,
    tiles: Path | None = None,
    progress: Progress | None = None,
    joint_budget: int | Literal["profile"] | None = "profile",
    *,
    profile: Profile = DEFAULT_PROFILE,
    impostor: bool | None = None,
    lod0_triangles: int | None = None,
) -> gl.GLTF2:
    """The forest as a glTF document with its binary blob set. ``tiles``: a tile-set folder
    whose ``bark.<UDIM>.png`` make the atlas, instead of the shipped set of the grammar's
    ``bark``. ``profile``: ``game`` (per tree the levels of detail of :mod:`forest.gltf.lod`
    on at most :data:`GAME_JOINTS` joints, one leaf material for all trees) or ``film`` (one
    mesh per tree, the full tree on a joint per bone, a leaf material tinted per tree).
    ``joint_budget``: joints per tree's skin (:mod:`forest.growth.joint_budget`, None for one
    per bone), the profile's by default. ``impostor``: the game profile's LOD3 (True, False,
    or None: where the render extra's GL is present). ``lod0_triangles``: the game profile's
    LOD0 budget (:data:`forest.lod.select.GAME_LOD0`'s by default): a tree over it drops its
    thinnest pieces and thins its leaf cards down to it."""
    if profile not in PROFILES:
        raise ForestError(
            f"unknown glTF profile {profile!r}; one of {', '.join(PROFILES)}", path="profile"
        )
    lod0 = GAME_LOD0 if lod0_triangles is None else game_lod0(lod0_triangles, profile)
    if joint_budget == "profile":
        joint_budget = profile_joints(profile)
    game = profile == "game"
    if game and impostor is None:
        from forest.lod.impostor import gl_missing

        impostor = gl_missing() is None
    check_size(forest, profile, lod0.budget)
    opts = forest.options
    gltf = document(
        forest.version,
        {
            "grammar": json.dumps(forest.grammar.model_dump(mode="json"), sort_keys=True),
            "seed": int(forest.seed),
            "version": forest.version,
            "trees": opts.trees,
            "frames": opts.frames,
            "fps": opts.fps,
            "profile": profile,
        },
    )
    blob = Blob(gltf)
    add_forest(gltf, blob, forest, tiles, progress, joint_budget, game, bool(impostor), lod0)
    blob.finish()
    return gltf


def document(version: str, extras: dict[str, object]) -> gl.GLTF2:
    """An empty glTF document: one scene, ``extras`` under ``asset.extras.forest``."""
    return gl.GLTF2(
        asset=gl.Asset(
            version="2.0", generator=f"interlocking-forest {version}", extras={"forest": extras}
        ),
        scene=0,
        scenes=[gl.Scene(name="Forest", nodes=[])],
    )


def add_forest(
    gltf: gl.GLTF2,
    blob: Blob,
    forest: Forest,
    tiles: Path | None,
    progress: Progress | None,
    joint_budget: int | None,
    game: bool,
    impostor: bool,
    lod0: LodTarget,
) -> None:
    """Every tree of ``forest`` into ``gltf`` (its materials, skins, meshes, levels and wind
    channels; the scene's root nodes), in the profile ``game`` or film."""
    slices = read_slices(tile_folder(forest.grammar.bark, tiles), forest.manifest.n_slices)
    n_slices, size = len(slices), slices.shape[1]
    if game:
        # welded bark: the bark class's tiles as one repeating picture (forest.bark.lattice)
        bark_class = bark_tiles(forest.manifest)
        n_bark = bark_class.stop - bark_class.start
        picture = super_tile(slices[bark_class])
        bark = add_bark_material(gltf, blob, picture, forest.grammar.bark, repeat=True)
        tint = lower_tint(slices, forest.manifest)
    else:
        bark = add_bark_material(gltf, blob, make_atlas(slices), forest.grammar.bark)
        tint = None  # the atlas holds the lower trunk's own tiles
    frames = joint_frames(forest, joint_budget)
    pose = sample_pose(forest, frames)
    anchors = foliage_or_none(forest)
    leaf_materials = LeafMaterials(gltf, blob, anchors.family) if anchors is not None else None
    shared_leaves = None
    if game and leaf_materials is not None:
        shared_leaves = leaf_materials.tree_material(None, np.ones(3))
    tints: list[tuple[F64, int]] = []
    skins: list[tuple[TreeSkin, slice]] = []
    impostors: list[tuple[int, Impostor]] = []
    chains: list[list[int]] = []  # per tree (game): its level nodes
    slices_ = tree_slices(forest, joint_budget)
    if progress:
        progress("glTF trees", 0, len(slices_))
    # every tree's and joint's node transform decomposed in one call for the forest
    tree_trs = similarity_trs(forest.tree_transforms)
    joint_trs = rest_trs(pose)
    for k, (inst, bones) in enumerate(slices_):
        skin = add_tree_skeleton(
            gltf,
            blob,
            forest,
            frames,
            k,
            inst,
            bones,
            joint_budget,
            tree_trs=tree_trs[k],
            joint_trs=joint_trs,
        )
        skins.append((skin, bones))
        n_joints = bones.stop - bones.start
        to_tree = invert_similarity(forest.tree_transforms[k])
        full_bark = BarkMesh(
            *tree_mesh(forest, inst, bones, to_tree, frames.still, weld=True, budget=joint_budget)
        )
        made = None
        if anchors is not None:
            made = leaves_mesh(forest, anchors, inst, bones, to_tree, frames.still, joint_budget)
        full_leaves = None if made is None else LeavesMesh(*made)
        if not game:
            prims = [
                skinned_primitive(
                    blob,
                    bark_quads(full_bark, atlas_uv(full_bark.st, n_slices, size)),
                    n_joints,
                    bark,
                )[0]
            ]
            if full_leaves is not None and leaf_materials is not None:
                colour = full_leaves.colour.astype(np.float64).mean(axis=0)
                material = leaf_materials.tree_material(k, colour)
                prims.append(
                    skinned_primitive(blob, leaf_quads(full_leaves), n_joints, material)[0]
                )
            gltf.meshes.append(gl.Mesh(name=f"Tree_{k:05d}", primitives=prims))
            gltf.nodes.append(
                gl.Node(name=f"Tree_{k:05d}_Mesh", mesh=len(gltf.meshes) - 1, skin=skin.skin)
            )
            gltf.scenes[0].nodes.append(len(gltf.nodes) - 1)
        else:
            # the lower trunk's colour, per LOD0 vertex (levels keep LOD0's vertices)
            lower_colour = None
            if tint is not None:
                lower = np.zeros(len(full_bark.points), bool)
                lower[full_bark.quads[lower_quads(full_bark.st, forest.manifest)].ravel()] = True
                lower_colour = np.where(lower[:, None], tint, 1.0)
            levels = tree_levels(
                forest,
                anchors,
                inst,
                bones,
                to_tree,
                frames.still,
                full_bark._replace(st=lattice_st(full_bark.quads)),
                full_leaves,
                joint_budget,
                lod0,
            )
            meshes: list[list[tuple[SkinnedQuads, int]]] = []
            for level in levels:
                uv = lattice_uv(level.bark.st, n_bark)
                tinted = None
                if lower_colour is not None:
                    tinted = lower_colour[find_rows(full_bark.points, level.bark.points)]
                prims_ = [(bark_quads(level.bark, uv, tinted), bark)]
                if level.leaves is not None and shared_leaves is not None:
                    prims_ += [(c, shared_leaves) for c in leaf_chunks(level.leaves, flat=True)]
                meshes.append(prims_)
            if full_leaves is not None:
                tints.append(
                    (full_leaves.colour.astype(np.float64).mean(axis=0), len(full_leaves.quads))
                )
            if impostor:
                from forest.lod.impostor import bake_tree_impostor

                impostors.append((k, bake_tree_impostor(forest, anchors, full_bark, full_leaves)))
            chains.append(add_levels(gltf, blob, k, 0, skin.skin, n_joints, meshes))
        if progress:
            progress("glTF trees", k + 1, len(slices_))
    if game:
        if shared_leaves is not None and tints:
            colour = np.average([c for c, _ in tints], axis=0, weights=[n for _, n in tints])
            gltf.materials[shared_leaves].pbrMetallicRoughness.baseColorFactor = [
                *(float(c) for c in colour),
                1.0,
            ]
        if impostors:
            # every tree's cards in one picture: one impostor material for the forest
            sheet = ImpostorSheet.of(len(impostors))
            material = add_impostor_material(
                gltf, blob, sheet.picture([imp.cards for _, imp in impostors])
            )
            for i, (k, imp) in enumerate(impostors):
                skin, bones = skins[k]
                card = [(impostor_quads(imp, sheet, i), material)]
                n_joints = bones.stop - bones.start
                chains[k] += add_levels(gltf, blob, k, IMPOSTOR_LEVEL, skin.skin, n_joints, [card])
        for chain in chains:
            chain_levels(gltf, chain)
    add_wind(gltf, blob, pose, skins)


def write_glb(
    forest: Forest,
    path: str | Path,
    *,
    tiles: Path | None = None,
    progress: Progress | None = None,
    packing: Packing = DEFAULT_PACKING,
    profile: Profile = DEFAULT_PROFILE,
    impostor: bool | None = None,
    lod0_triangles: int | None = None,
) -> Path:
    """Write ``forest`` to ``path`` (.glb) atomically; returns the path. ``packing``: how
    the binary data is stored (:mod:`forest.gltf.compress`); ``profile``, ``impostor`` and
    ``lod0_triangles``: as :func:`forest_gltf`'s."""
    doc = forest_gltf(
        forest,
        tiles,
        progress,
        profile=profile,
        impostor=impostor,
        lod0_triangles=lod0_triangles,
    )
    return save_glb(doc, path, packing, progress)


def save_glb(
    doc: gl.GLTF2, path: str | Path, packing: Packing, progress: Progress | None = None
) -> Path:
    """Pack ``doc`` (:mod:`forest.gltf.compress`) and write it to ``path`` atomically."""
    out = Path(path)
    gltf = pack(doc, packing)
    # one step: the container and its JSON are made in one call
    if progress:
        progress("save", 0, 1)
    parts = glb_parts(gltf)
    try:
        with replaced_when_written(out) as tmp, tmp.open("wb") as f:
            f.writelines(parts)
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", path=str(out)) from None
    if progress:
        progress("save", 1, 1)
    return out
