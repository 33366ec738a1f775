"""``GET /v1/recipes``: the built-in forest recipes (mixed stands), public like the presets
(a page lists them before a key is pasted); a forest job or ``POST /v1/trees`` names one in
``recipe``."""

from __future__ import annotations

import functools

from fastapi import APIRouter, Depends

from forest.stand.recipes import builtin_summaries
from schemas.recipe import RecipeList
from service.security import public

router = APIRouter(prefix="/v1/recipes", tags=["recipes"], dependencies=[Depends(public)])


@functools.cache
def _recipes() -> RecipeList:
    # the shipped recipes do not change while the process runs: read once
    return RecipeList(recipes=builtin_summaries())


@router.get("", response_model=RecipeList)
def list_recipes() -> RecipeList:
    return _recipes()
