"""The ``forest`` job kind: generate a forest request's trees and write its scene."""

from __future__ import annotations

from typing import TYPE_CHECKING

from worker.jobs.context import JobContext, Outcome
from worker.jobs.tileset import request_tiles

if TYPE_CHECKING:
    from schemas.jobs import TreeRequest


def run_forest(ctx: JobContext) -> Outcome:
    """A forest job: generate, write the scene (``scene.<format>``: USD, or ``scene.glb``)."""
    # the library is imported in the job's process (preloaded there), not by ``--list``
    from farm.requests import options_from_request
    from forest.export import single_file, write_forest
    from forest.growth.generate import generate_forest
    from forest.growth.presets import grammar_of
    from schemas.jobs import ForestRequest

    req = ForestRequest.model_validate(ctx.params)
    if req.recipe is not None:
        return run_stand(ctx, req)
    grammar = grammar_of(req.preset, req.grammar, req.bark)
    options = options_from_request(req)

    def note(stage: str, done: int, total: int) -> None:
        ctx.report(stage, 0.7 * done / max(total, 1))

    name = f"scene.{req.format}"
    manifest, tiles = request_tiles(ctx, req.tiles, name)
    forest = generate_forest(grammar, req.seed, options, progress=note, manifest=manifest)
    ctx.report("write", 0.7)
    # the scene is one artifact: pictures only where it carries them (.usdz, .glb)
    out = write_forest(
        forest, ctx.scratch / name, skinned=req.skinned, textures=single_file(name), tiles=tiles
    )
    result = {
        "trees": req.trees,
        "pieces": forest.n_instances,
        "bones": len(forest.bones),
        "frames": req.frames,
        "scene": name,
    }
    return Outcome({name: out}, result)


def run_stand(ctx: JobContext, req: TreeRequest) -> Outcome:
    """A recipe's forest: place the stand, grow and write each layer (one at a time) beside
    the root layer, flat colours (a texture folder is no artifact): ``scene.<format>`` and
    ``scene_<layer>.usdc``, every one an artifact, so the downloaded files open together."""
    from farm.requests import loaded_recipe, options_from_request, stand_size
    from forest.stand.generate import plan_stand
    from forest.usd.stand import write_stand

    ctx.report("place", 0.02)
    loaded = loaded_recipe(req)
    trees, area = stand_size(req, loaded.recipe)
    stand = plan_stand(loaded, trees, area, req.seed)
    name = f"scene.{req.format}"

    def note(stage: str, done: int, total: int) -> None:
        ctx.report(f"layers {done}/{total}", 0.05 + 0.9 * done / max(total, 1))

    options = options_from_request(req)
    root = write_stand(
        stand, ctx.scratch / name, options, skinned=req.skinned, textures=False,
        progress=note, beside=True,
    )  # fmt: skip
    files = {p.name: p for p in ctx.scratch.glob(f"{root.stem}_*.usdc")}
    files[name] = root
    layers = {
        layer.name: len(t)
        for layer, t in zip(stand.recipe.layers, stand.placement.layers, strict=True)
    }
    # the pieces a render of it is charged for (its quota): expected, as the API estimated
    # them (each layer at its trees' sizes)
    pieces = sum(
        cg.expected_pieces * len(t)
        for cg, t in zip(stand.estimates(), stand.placement.layers, strict=True)
    )
    result = {
        "trees": stand.trees,
        "pieces": round(pieces),
        "layers": layers,
        "frames": req.frames,
        "scene": name,
        "recipe": stand.recipe.name,
    }
    return Outcome(files, result)
