"""The ``forest`` job kind: generate a forest request's trees and write its scene."""

from __future__ import annotations

from worker.jobs.context import JobContext, Outcome


def run_forest(ctx: JobContext) -> Outcome:
    """A forest job: generate, write the scene (``scene.<format>``: USD, or ``scene.glb``)."""
    # the library is imported in the job's process (preloaded there), not by ``--list``
    from farm.requests import options_from_request
    from forest.export import single_file, write_forest
    from forest.growth.generate import generate_forest
    from forest.growth.presets import grammar_of
    from schemas.jobs import ForestRequest

    req = ForestRequest.model_validate(ctx.params)
    grammar = grammar_of(req.preset, req.grammar)
    options = options_from_request(req)

    def note(stage: str, done: int, total: int) -> None:
        ctx.report(stage, 0.7 * done / max(total, 1))

    forest = generate_forest(grammar, req.seed, options, progress=note)
    ctx.report("write", 0.7)
    name = f"scene.{req.format}"
    # the scene is one artifact: pictures only where it carries them (.usdz, .glb)
    out = write_forest(forest, ctx.scratch / name, skinned=req.skinned, textures=single_file(name))
    result = {
        "trees": req.trees,
        "pieces": forest.n_instances,
        "bones": len(forest.bones),
        "frames": req.frames,
        "scene": name,
    }
    return Outcome({name: out}, result)
