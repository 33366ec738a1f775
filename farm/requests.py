"""What a job's request means to the library: the generation options of a tree or forest
request. The service (synchronous trees, cost checks) and the worker (forest and tile jobs)
read requests through here, so both generate the same forest from the same request."""

from __future__ import annotations

from dataclasses import replace

from forest.errors import ForestError
from forest.growth.generate import ForestOptions
from forest.growth.wind import Wind
from forest.stand.recipes import LoadedRecipe
from schemas.jobs import ForestRequest, TreeRequest
from schemas.recipe import Recipe


def options_from_request(req: TreeRequest) -> ForestOptions:
    """The generation options of an API request (a ForestRequest adds trees, area, placement)."""
    options = ForestOptions(
        frames=req.frames,
        fps=req.fps,
        segments=req.segments,
        wind=Wind(strength_deg=req.wind_deg),
        season=req.season,
    )
    if isinstance(req, ForestRequest):
        options = replace(options, trees=req.trees, area=req.area, placement=req.placement)
    elif req.area is not None:  # a recipe's small stand
        options = replace(options, area=req.area)
    return options


DEFAULT_STAND_AREA = (20.0, 20.0)


def loaded_recipe(req: TreeRequest) -> LoadedRecipe:
    """The recipe a request names: a built-in one by name (its own images beside it), or the
    request's object, whose images can only be ``data:`` URIs (no folder: a path would name a
    file on the server). A ForestError at ``recipe`` for a name that is no built-in one."""
    from forest.stand.recipes import load_recipe, recipe_names

    if req.recipe is None:
        raise ForestError("give a recipe", path="recipe")
    if isinstance(req.recipe, str):
        names = recipe_names()
        if req.recipe not in names:
            raise ForestError(
                f"no built-in recipe {req.recipe!r}; choose one of {', '.join(names)}",
                path="recipe",
            )
        return load_recipe(req.recipe)
    return LoadedRecipe(req.recipe, None)


def stand_size(req: TreeRequest, recipe: Recipe) -> tuple[int, tuple[float, float]]:
    """A recipe request's trees (the layers' shares of them; a forest's ``trees``, a tree
    request's or one per layer) and area (metres)."""
    trees = req.trees if req.trees is not None else len(recipe.layers)
    area = req.area if req.area is not None else DEFAULT_STAND_AREA
    return trees, (float(area[0]), float(area[1]))
