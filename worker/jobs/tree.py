"""The ``tree`` job kind: the one tree of a ``POST /v1/trees``, made in a job's process (under
the job's memory and CPU limits), not in the API process; the API answers with its file."""

from __future__ import annotations

from typing import TYPE_CHECKING

from worker.jobs.context import JobContext, Outcome
from worker.jobs.tileset import request_tiles

if TYPE_CHECKING:
    from schemas.jobs import TreeRequest


def run_tree(ctx: JobContext) -> Outcome:
    """A tree job (``params``: :class:`schemas.jobs.TreeRequest`): generate, write
    ``tree.<format>`` (a .usdz names its inner layer after the stem, as the route always did)."""
    from farm.requests import options_from_request
    from forest.export import single_file, write_forest
    from forest.growth.generate import generate_forest
    from forest.growth.presets import grammar_of
    from schemas.jobs import TreeRequest

    req = TreeRequest.model_validate(ctx.params)
    if req.recipe is not None:
        return run_stand_file(ctx, req)
    grammar = grammar_of(req.preset, req.grammar, req.bark)

    def note(stage: str, done: int, total: int) -> None:
        ctx.report(stage, 0.7 * done / max(total, 1))

    name = f"tree.{req.format}"
    manifest, tiles = request_tiles(ctx, req.tiles, name)
    options = options_from_request(req)
    forest = generate_forest(grammar, req.seed, options, progress=note, manifest=manifest)
    ctx.report("write", 0.7)
    # one file answers: pictures only where the file carries them (.usdz, .glb); a .usda/.usdc
    # keeps flat colours rather than name a folder the client never gets
    out = write_forest(
        forest, ctx.scratch / name, skinned=req.skinned, textures=single_file(name), tiles=tiles
    )
    result = {
        "pieces": forest.n_instances,
        "bones": len(forest.bones),
        "frames": req.frames,
        "scene": name,
    }
    return Outcome({name: out}, result)


def run_stand_file(ctx: JobContext, req: TreeRequest) -> Outcome:
    """A recipe's small stand as the one file a ``POST /v1/trees`` answers: written as a
    root layer and layer files in the scratch folder, then flattened (usda, usdc: flat
    colours) or packaged with its pictures (usdz): ``tree.<format>``."""
    from farm.requests import loaded_recipe, options_from_request, stand_size
    from forest.stand.generate import plan_stand
    from forest.usd.stand import stand_file, write_stand

    ctx.report("place", 0.02)
    loaded = loaded_recipe(req)
    trees, area = stand_size(req, loaded.recipe)
    stand = plan_stand(loaded, trees, area, req.seed)

    def note(stage: str, done: int, total: int) -> None:
        ctx.report(f"layers {done}/{total}", 0.05 + 0.8 * done / max(total, 1))

    parts = ctx.scratch / "stand"
    parts.mkdir()
    textures = req.format == "usdz"
    root = write_stand(
        stand, parts / "stand.usdc", options_from_request(req), skinned=req.skinned,
        textures=textures, progress=note,
    )  # fmt: skip
    ctx.report("one file", 0.9)
    name = f"tree.{req.format}"
    out = stand_file(root, ctx.scratch / name)
    result = {"trees": stand.trees, "frames": req.frames, "scene": name}
    return Outcome({name: out}, result)
