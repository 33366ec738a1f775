"""Writing a forest as a USD scene (its layout: :mod:`forest.usd.contract`): the stage and
``/World/Forest`` with what makes the scene again, the ``representation`` variants, the bark
material, the pieces' instancer (:mod:`forest.usd.instancer`), the leaf clouds
(:mod:`forest.usd.leaves`) and, when asked or small enough, the skinned trees
(:mod:`forest.usd.skinned`).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pxr import Sdf, Usd, UsdShade

from forest.geometry.transforms import F64
from forest.growth.foliage import FoliageAnchors
from forest.growth.generate import Forest, foliage_or_none
from forest.growth.joint_budget import DCC_JOINTS
from forest.growth.rig import F32
from forest.usd.contract import (
    ENGINE,
    FOLIAGE,
    FOREST,
    GRAMMAR,
    JOINT_ROTATIONS,
    OPTIONS,
    PIECES,
    POSED,
    REPRESENTATION,
    SEED,
    SKINNED,
    TILE_MANIFEST,
    TREE_TRANSFORMS,
    VERSION,
)
from forest.usd.files import check_output_path, discard, finish, new_stage_layer
from forest.usd.instancer import Progress, write_instancer
from forest.usd.leaves import clouds_bound, write_foliage
from forest.usd.materials import bark_material
from forest.usd.prims import define_world, row_major, set_attr, set_frames
from forest.usd.textures import PACKAGE_FOLDER, scene_textures, texture_folder

if TYPE_CHECKING:
    from forest.usd.lod import ImpostorFiles, LodOptions

# Forests of up to this many trees and pieces get the skinned representation (exact: USD's
# own skinning) unless the caller asks otherwise; larger ones are posed only (rigid best fit
# per piece, docs/usd.md "Representations"): a skinned tree costs 2.5x the file and 9-19x the
# write time of its instanced pieces (4 oaks, 14k pieces, 24 frames: 374 MB, 64 s).
SKINNED_MAX_TREES = 64
SKINNED_MAX_PIECES = 20_000
# Forests of up to this many trees get their impostors (lod3) baked by default: the bake draws
# each tree 18 times on the CPU's GL (llvmpipe), 0.7-1.6 s a tree (almond, oak), which
# doubled the write of 20 almonds (18,922 pieces, 24 frames: 16.7 s without levels, 19.2 s
# with lod0-2, 32.0 s with the impostors)
IMPOSTOR_MAX_TREES = 16


def setup_stage(stage: Usd.Stage, forest: Forest, instanced: bool = True) -> None:
    """``/World/Forest`` with what makes the scene again, the documentation and frames
    (``instanced``: the layer holds the engine and posed forms, as all but a .usdz)."""
    _, group = define_world(stage, FOREST)
    prim = group.GetPrim()
    forms = (
        f"{ENGINE} (pieces at rest + the bone rig, {JOINT_ROTATIONS}), {POSED} (pieces at "
        f"posed transforms), {SKINNED} (UsdSkel trees, when written)."
        if instanced
        else f"{SKINNED} (UsdSkel trees) only: a .usdz holds no instanced form."
    )
    stage.GetRootLayer().documentation = (
        f"interlocking-forest {forest.version}: {forest.options.trees} trees from grammar "
        f"{forest.grammar.name or '(unnamed)'} (axiom {forest.grammar.axiom}), seed "
        f"{int(forest.seed)}; {FOREST}.{GRAMMAR} holds the grammar, "
        f"{OPTIONS} the options. Variant set '{REPRESENTATION}' on {FOREST}: {forms}"
    )
    # everything needed to make the scene again
    grammar_json = json.dumps(forest.grammar.model_dump(mode="json"), sort_keys=True)
    set_attr(prim, GRAMMAR, Sdf.ValueTypeNames.String, grammar_json)
    set_attr(prim, SEED, Sdf.ValueTypeNames.Int64, int(forest.seed))
    set_attr(prim, VERSION, Sdf.ValueTypeNames.String, forest.version)
    opts = forest.options
    set_attr(
        prim,
        OPTIONS,
        Sdf.ValueTypeNames.String,
        json.dumps(
            {
                "trees": opts.trees,
                "area": list(opts.area),
                "frames": opts.frames,
                "fps": opts.fps,
                "placement": opts.placement,
                "segments": opts.segments,
                "wind": vars(opts.wind),
                "season": opts.season,
            },
            sort_keys=True,
        ),
    )
    set_attr(prim, TILE_MANIFEST, Sdf.ValueTypeNames.String, forest.manifest.model_dump_json())
    set_attr(
        prim,
        TREE_TRANSFORMS,
        Sdf.ValueTypeNames.Matrix4dArray,
        row_major(forest.tree_transforms),
    )
    if forest.animated:
        set_frames(stage, opts.frames, opts.fps)


def write_scene(
    forest: Forest,
    path: str | Path,
    *,
    skinned: bool | None = None,
    tiles: str | None = None,
    textures: bool = True,
    progress: Progress | None = None,
    joint_budget: int | None = DCC_JOINTS,
    lod: bool = True,
    impostor: bool | None = None,
) -> Path:
    """Write ``forest`` to ``path`` (.usda, .usdc or .usdz); returns the path.

    ``skinned``: True writes the skinned trees (then the composed default), False only the
    posed and engine representations, None (default) decides by size: skinned for up to
    :data:`SKINNED_MAX_TREES` trees and :data:`SKINNED_MAX_PIECES` pieces. A .usdz holds
    the skinned trees only (ARKit allows no PointInstancer: no engine or posed form), so
    ``skinned`` is implied there. ``joint_budget``: the skinned trees' joints per tree
    (:mod:`forest.growth.joint_budget`), None for one per bone.

    ``textures`` (default): the materials read the grammar's shipped bark tiles (or those of
    the folder ``tiles``, relative to the scene) and the leaf picture, which cuts the leaf
    cards; a .usda/.usdc finds them in ``<stem>.textures/`` beside it
    (:mod:`forest.usd.textures`), a .usdz carries them. Without, flat colours and no
    picture (but a given ``tiles`` is still read).

    ``lod`` (default) adds each skinned tree's levels of detail (:mod:`forest.lod`: a
    variant set ``lod`` on its SkelRoot, ``lod0`` the default) and, with ``impostor`` (None:
    unless :func:`impostor_skipped` says why not), its baked impostor as ``lod3``, the
    pictures beside the others: in ``<stem>.textures/`` beside a .usda/.usdc, under
    ``./textures/`` in a .usdz."""
    out = check_output_path(path)
    skinned = wants_skinned(forest, out, skinned)
    lod_options = None
    if lod and skinned:
        from forest.usd.lod import LodOptions

        lod_options = LodOptions()
        if impostor is None:
            impostor = impostor_skipped(forest, textures) is None
    return _write_scene(
        forest, out, skinned, tiles, textures, progress, joint_budget, lod_options, bool(impostor)
    )


def impostor_available() -> bool:
    """Whether the impostors can be baked here: the render extra's GL is there
    (:func:`forest.lod.impostor.gl_missing`)."""
    from forest.lod.impostor import gl_missing

    return gl_missing() is None


def impostor_skipped(forest: Forest, textures: bool = True) -> str | None:
    """Why :func:`write_scene` bakes no impostor by default for ``forest``, or None when it
    does: the scene writes no pictures, has over :data:`IMPOSTOR_MAX_TREES` trees, or GL is
    missing."""
    from forest.lod.impostor import gl_missing

    if not textures:
        return "the scene has no pictures (--no-textures)"
    if len(forest.tree_transforms) > IMPOSTOR_MAX_TREES:
        return f"over {IMPOSTOR_MAX_TREES} trees (each takes a second or so to bake)"
    return gl_missing()


def _write_scene(
    forest: Forest,
    out: Path,
    skinned: bool,
    tiles: str | None,
    textures: bool,
    progress: Progress | None,
    joint_budget: int | None,
    lod: LodOptions | None,
    impostor: bool,
) -> Path:
    package = out.suffix.lower() == ".usdz"
    anchors = foliage_or_none(forest)
    stage, tmp = new_stage_layer(out)
    made_folder = False
    try:
        pictures = scene_textures(
            out,
            tmp.parent,
            forest.grammar.bark,
            forest.manifest.n_slices,
            None if anchors is None else anchors.family,
            tiles=tiles,
            textures=textures,
        )
        if lod is not None and impostor:
            lod = replace(lod, impostors=impostor_files(out, tmp.parent))
        setup_stage(stage, forest, instanced=not package)
        vset, targets = representation_variants(stage, skinned, instanced=not package)
        material = bark_material(
            stage, pictures.bark, forest.grammar.bark, shipped_copy=pictures.shipped_bark
        )
        if not package:
            _write_instanced(stage, forest, material, targets, anchors, pictures.leaf, progress)
        if skinned:
            from forest.usd.skinned import write_skinned_trees

            vset.SetVariantSelection(SKINNED)  # its extents are computed on the composed trees
            with Usd.EditContext(stage, targets[SKINNED]):
                write_skinned_trees(
                    stage,
                    forest,
                    material,
                    anchors,
                    progress,
                    pictures.leaf,
                    pictures.bark_st,
                    joint_budget,
                    lod,
                )
                # the skinned trees carry the leaves: each tree is shown once
                for where in (PIECES, FOLIAGE):
                    if stage.GetPrimAtPath(where):
                        stage.GetPrimAtPath(where).SetActive(False)
        vset.SetVariantSelection(SKINNED if skinned else POSED)
        if lod is not None and lod.impostors is not None and not package:
            pictures = pictures.with_files(lod.impostors.written(), texture_folder(out))
        # the pictures before the scene that names them: a reader never finds a scene
        # whose pictures are not there yet
        made_folder = pictures.write(staged=not package)
        # one step: the layer is encoded and written in one call that holds the GIL
        if progress:
            progress("save", 0, 1)
        finish(stage, tmp, out)
        pictures.prune()
        if progress:
            progress("save", 1, 1)
    except BaseException:
        if made_folder and pictures.folder is not None:  # a first write leaves no trace
            shutil.rmtree(pictures.folder, ignore_errors=True)
        raise
    finally:
        del stage
        discard(tmp)  # the private folder, with whatever a failed write left in it
    return out


def impostor_files(out: Path, layer_folder: Path) -> ImpostorFiles:
    """Where the impostors of the scene ``out``, whose layer is written in ``layer_folder``,
    go: beside the package's other pictures (named ``./textures/...``: the packager keeps
    such paths, where Blender resolves its renamed ones to nothing), or staged beside the
    layer, to join the other pictures in ``<stem>.textures/`` when those are written."""
    from forest.usd.lod import ImpostorFiles

    if out.suffix.lower() == ".usdz":
        return ImpostorFiles(layer_folder / PACKAGE_FOLDER, f"./{PACKAGE_FOLDER}", packed=True)
    return ImpostorFiles(layer_folder / "impostors", f"./{texture_folder(out).name}")


def _write_instanced(
    stage: Usd.Stage,
    forest: Forest,
    material: UsdShade.Material,
    targets: dict[str, Usd.EditTarget],
    anchors: FoliageAnchors | None,
    leaf_file: str | None,
    progress: Progress | None,
) -> None:
    """The engine and posed forms: the pieces' instancer and the leaf clouds' one."""
    # each sample's cloud centres kept as they are written (float32) and their bound joined
    # at once: float64 centres of every frame stacked for the extent took 4x the memory
    samples: list[tuple[float | None, F32]] = []
    bound: F64 | None = None

    def foliage_sample(time: float | None, palette: F64) -> None:
        nonlocal bound
        if anchors is not None:
            positions = anchors.positions(palette, row_vectors=True)
            bound = clouds_bound(anchors, positions, bound)
            samples.append((time, positions.astype(np.float32)))

    write_instancer(stage, forest, material, targets, progress, foliage_sample)
    if anchors is not None and bound is not None:
        write_foliage(stage, forest, anchors, samples, bound, leaf_file)


def wants_skinned(forest: Forest, path: Path, skinned: bool | None = None) -> bool:
    """Whether :func:`write_scene` writes (and composes) the skinned trees: always in a
    .usdz (its only form), else ``skinned`` when given, else for forests of at most
    :data:`SKINNED_MAX_TREES` trees and :data:`SKINNED_MAX_PIECES` pieces."""
    if path.suffix.lower() == ".usdz":
        return True
    if skinned is not None:
        return skinned
    return (
        len(forest.tree_transforms) <= SKINNED_MAX_TREES
        and forest.n_instances <= SKINNED_MAX_PIECES
    )


def representation_variants(
    stage: Usd.Stage, skinned: bool, instanced: bool = True
) -> tuple[Usd.VariantSet, dict[str, Usd.EditTarget]]:
    """The ``representation`` variant set on /World/Forest and an edit target per variant:
    the ``instanced`` forms (engine, posed) and, when ``skinned``, the skinned trees."""
    vset = stage.GetPrimAtPath(FOREST).GetVariantSets().AddVariantSet(REPRESENTATION)
    targets = {}
    names = ((ENGINE, POSED) if instanced else ()) + ((SKINNED,) if skinned else ())
    for name in names:
        vset.AddVariant(name)
        vset.SetVariantSelection(name)
        targets[name] = vset.GetVariantEditTarget()
    return vset, targets
