"""The ``forest_tile`` job kind: one tile of a tiled forest job (:mod:`farm.tiles` makes the
tile jobs and joins their files into the root layer)."""

from __future__ import annotations

from worker.jobs.context import JobContext, Outcome


def run_tile(ctx: JobContext) -> Outcome:
    """One tile (``params``: :class:`schemas.jobs.TileJob`): generate its trees and write
    ``scene_tile_<i>_<j>.usdc``, published into the parent job's artifacts; the result
    carries the tile's entry of the root layer."""
    from farm.requests import options_from_request
    from farm.tiles import tile_artifact
    from forest.growth.presets import grammar_of
    from forest.growth.tiling import TilePlan, generate_tile
    from forest.usd.tiled import write_tile_file
    from schemas.jobs import TileJob

    req = TileJob.model_validate(ctx.params)
    assert req.tile_size is not None
    if req.recipe is not None:
        return run_stand_tile(ctx, req)
    i, j = req.tile
    grammar = grammar_of(req.preset, req.grammar, req.bark)
    plan = TilePlan(req.trees, req.area, req.tile_size, req.seed)

    def note(stage: str, done: int, total: int) -> None:
        ctx.report(stage, 0.7 * done / max(total, 1))

    forest = generate_tile(grammar, plan, i, j, options_from_request(req), progress=note)
    ctx.report("write", 0.7)
    name = tile_artifact(i, j)
    skinned = bool(req.skinned)  # tiles stay posed unless asked
    entry = write_tile_file(forest, ctx.scratch / name, f"./{name}", i, j, skinned=skinned)
    pieces = 0 if forest is None else forest.n_instances
    return Outcome({name: ctx.scratch / name}, {"tile": entry.to_json(), "pieces": pieces})


def run_stand_tile(ctx: JobContext, req: object) -> Outcome:
    """One tile of a recipe's tiled forest: the stand placed over the whole area (so every
    tile agrees), then each layer's trees in this tile grown and written as
    ``scene_tile_<i>_<j>_<layer>.usdc`` (none where the layer has no tree here); the result
    carries their entries of the root layer."""
    from farm.requests import loaded_recipe, options_from_request, stand_size
    from farm.tiles import stand_tile_artifact
    from forest.stand.generate import plan_stand
    from forest.usd.stand import write_layer_file
    from schemas.jobs import TileJob

    assert isinstance(req, TileJob) and req.tile_size is not None
    i, j = req.tile
    loaded = loaded_recipe(req)
    trees, area = stand_size(req, loaded.recipe)
    stand = plan_stand(loaded, trees, area, req.seed)
    options = options_from_request(req)
    files, entries, pieces = {}, [], 0
    n = len(stand.recipe.layers)
    for k, layer in enumerate(stand.recipe.layers):
        ctx.report(f"layer {k + 1}/{n}", 0.9 * k / n)
        name = stand_tile_artifact(i, j, layer.name)
        made = write_layer_file(
            stand, k, ctx.scratch / name, options, (i, j), req.tile_size, bool(req.skinned)
        )
        if made is not None:
            files[name] = ctx.scratch / name
            entries.append(made.to_json())
            pieces += made.pieces
    return Outcome(files, {"stand_tile": entries, "pieces": pieces})
