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
    i, j = req.tile
    grammar = grammar_of(req.preset, req.grammar)
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
