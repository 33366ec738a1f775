"""The ``tree`` job kind: the one tree of a ``POST /v1/trees``, made in a job's process (under
the job's memory and CPU limits), not in the API process; the API answers with its file."""

from __future__ import annotations

from worker.jobs.context import JobContext, Outcome


def run_tree(ctx: JobContext) -> Outcome:
    """A tree job (``params``: :class:`schemas.jobs.TreeRequest`): generate, write
    ``tree.<format>`` (a .usdz names its inner layer after the stem, as the route always did)."""
    from farm.requests import options_from_request
    from forest.export import single_file, write_forest
    from forest.growth.generate import generate_forest
    from forest.growth.presets import grammar_of
    from schemas.jobs import TreeRequest

    req = TreeRequest.model_validate(ctx.params)
    grammar = grammar_of(req.preset, req.grammar)

    def note(stage: str, done: int, total: int) -> None:
        ctx.report(stage, 0.7 * done / max(total, 1))

    forest = generate_forest(grammar, req.seed, options_from_request(req), progress=note)
    ctx.report("write", 0.7)
    name = f"tree.{req.format}"
    # one file answers: pictures only where the file carries them (.usdz, .glb); a .usda/.usdc
    # keeps flat colours rather than name a folder the client never gets
    out = write_forest(forest, ctx.scratch / name, skinned=req.skinned, textures=single_file(name))
    result = {
        "pieces": forest.n_instances,
        "bones": len(forest.bones),
        "frames": req.frames,
        "scene": name,
    }
    return Outcome({name: out}, result)
