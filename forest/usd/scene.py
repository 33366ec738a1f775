"""Writing a forest as a USD scene (its layout: :mod:`forest.usd.contract`): the stage and
``/World/Forest`` with what makes the scene again, the ``representation`` variants, the bark
material, the pieces' instancer (:mod:`forest.usd.instancer`), the leaf clouds
(:mod:`forest.usd.leaves`) and, when asked or small enough, the skinned trees
(:mod:`forest.usd.skinned`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from pxr import Sdf, Usd

from forest.geometry.transforms import F64
from forest.growth.generate import Forest, foliage_or_none
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
from forest.usd.leaves import write_foliage
from forest.usd.materials import bark_material, write_leaf_texture
from forest.usd.prims import define_world, row_major, set_attr, set_frames

if TYPE_CHECKING:
    from forest.lod.usd import LodOptions

# Forests of up to this many trees and pieces get the skinned representation (exact: USD's
# own skinning) unless the caller asks otherwise; larger ones are posed only (rigid best fit
# per piece, docs/usd.md "Representations"): a skinned tree costs 2.5x the file and 9-19x the
# write time of its instanced pieces (4 oaks, 14k pieces, 24 frames: 374 MB, 64 s).
SKINNED_MAX_TREES = 64
SKINNED_MAX_PIECES = 20_000


def setup_stage(stage: Usd.Stage, forest: Forest) -> None:
    """``/World/Forest`` with what makes the scene again, the documentation and frames."""
    _, group = define_world(stage, FOREST)
    prim = group.GetPrim()
    stage.GetRootLayer().documentation = (
        f"interlocking-forest {forest.version}: {forest.options.trees} trees from grammar "
        f"{forest.grammar.name or '(unnamed)'} (axiom {forest.grammar.axiom}), seed "
        f"{int(forest.seed)}; {FOREST}.{GRAMMAR} holds the grammar, "
        f"{OPTIONS} the options. Variant set '{REPRESENTATION}' on {FOREST}: "
        f"{ENGINE} (pieces at rest + the bone rig, {JOINT_ROTATIONS}), {POSED} (pieces at "
        "posed transforms), "
        f"{SKINNED} (UsdSkel trees, when written)."
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
    progress: Progress | None = None,
    lod: bool = False,
    impostor: bool | None = None,
) -> Path:
    """Write ``forest`` to ``path`` (.usda, .usdc or .usdz); returns the path.

    ``skinned``: True writes the skinned trees (then the composed default), False only the
    posed and engine representations, None (default) decides by size: skinned for up to
    :data:`SKINNED_MAX_TREES` trees and :data:`SKINNED_MAX_PIECES` pieces. A .usdz always
    carries the skinned trees and composes them by default (ARKit allows no PointInstancer),
    so ``skinned`` is implied there. ``lod`` adds each skinned tree's levels of detail
    (:mod:`forest.lod`: a variant set ``lod`` on its SkelRoot, ``lod0`` the default) and,
    with ``impostor`` (None: where GL is available, :func:`forest.lod.impostor.gl_missing`),
    its baked impostor as ``lod3``, the pictures in ``<stem>.lod/`` beside a .usda/.usdc."""
    out = check_output_path(path)
    skinned = wants_skinned(forest, out, skinned)
    if not (lod and skinned):
        return _write_scene(forest, out, skinned, tiles, progress, None)
    from forest.lod.usd import lod_pictures

    with lod_pictures(out, impostor) as lod_options:
        return _write_scene(forest, out, skinned, tiles, progress, lod_options)


def _write_scene(
    forest: Forest,
    out: Path,
    skinned: bool,
    tiles: str | None,
    progress: Progress | None,
    lod: LodOptions | None,
) -> Path:
    stage, tmp = new_stage_layer(out)
    try:
        setup_stage(stage, forest)
        vset, targets = representation_variants(stage, skinned)
        anchors = foliage_or_none(forest)
        leaf_file = None
        if out.suffix.lower() == ".usdz" and anchors is not None:
            # the leaf picture goes inside: written beside the layer (an absolute path: the
            # packager embeds it under a name of its own). Bark tiles only from a given
            # folder: Blender 4.2 finds no UDIM tile inside a package (magenta bark)
            leaf_file = write_leaf_texture(tmp.parent, anchors.family).resolve().as_posix()
        material = bark_material(stage, tiles, forest.grammar.bark)
        samples: list[tuple[float | None, F64]] = []

        def foliage_sample(time: float | None, palette: F64) -> None:
            if anchors is not None:
                samples.append((time, anchors.positions(palette, row_vectors=True)))

        write_instancer(stage, forest, material, targets, progress, foliage_sample)
        if anchors is not None:
            write_foliage(stage, forest, anchors, samples, leaf_file)
        if skinned:
            from forest.usd.skinned import write_skinned_trees

            vset.SetVariantSelection(SKINNED)  # its extents are computed on the composed trees
            with Usd.EditContext(stage, targets[SKINNED]):
                write_skinned_trees(
                    stage, forest, material, anchors, progress, leaf_file,
                    lod=lod,
                )  # fmt: skip
                # the skinned trees carry the leaves: each tree is shown once
                for where in (PIECES, FOLIAGE):
                    if stage.GetPrimAtPath(where):
                        stage.GetPrimAtPath(where).SetActive(False)
        vset.SetVariantSelection(SKINNED if skinned else POSED)
        # one step: the layer is encoded and written in one call that holds the GIL
        if progress:
            progress("save", 0, 1)
        finish(stage, tmp, out)
        if progress:
            progress("save", 1, 1)
    finally:
        del stage
        discard(tmp)  # the private folder, with whatever a failed write left in it
    return out


def wants_skinned(forest: Forest, path: Path, skinned: bool | None = None) -> bool:
    """Whether :func:`write_scene` writes (and composes) the skinned trees: always in a
    .usdz, else ``skinned`` when given, else for forests of at most
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
    stage: Usd.Stage, skinned: bool
) -> tuple[Usd.VariantSet, dict[str, Usd.EditTarget]]:
    """The ``representation`` variant set on /World/Forest and an edit target per variant."""
    vset = stage.GetPrimAtPath(FOREST).GetVariantSets().AddVariantSet(REPRESENTATION)
    targets = {}
    for name in (ENGINE, POSED, SKINNED) if skinned else (ENGINE, POSED):
        vset.AddVariant(name)
        vset.SetVariantSelection(name)
        targets[name] = vset.GetVariantEditTarget()
    return vset, targets
