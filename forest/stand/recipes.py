"""Forest recipes: the built-in ones (``builtin/*.json`` beside this module, with the density
maps they name) and recipe files; each read into a :class:`schemas.recipe.Recipe` with its
errors named by field."""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from pydantic import ValidationError

from forest.errors import ForestError
from schemas.base import FieldValueError
from schemas.recipe import Recipe, RecipeSummary

MAX_RECIPE_BYTES = 50 * 1024 * 1024


@dataclass(frozen=True)
class LoadedRecipe:
    """A recipe and the folder its image paths are relative to (None: only ``data:`` URIs,
    as from the API)."""

    recipe: Recipe
    folder: Path | None


def _builtin_folder() -> Path:
    return Path(str(resources.files(__package__).joinpath("builtin")))


def recipe_names() -> list[str]:
    return sorted(p.stem for p in _builtin_folder().glob("*.json"))


def recipe_from_json(text: str | bytes, source: str) -> Recipe:
    """A recipe from JSON text; a ForestError naming the first field at fault."""
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ForestError(f"{source} is not JSON ({exc})", path="recipe") from None
    return recipe_from_object(data)


def recipe_from_object(data: object) -> Recipe:
    try:
        return Recipe.model_validate(data)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        found = (err.get("ctx") or {}).get("error")
        loc = ".".join(str(p) for p in err["loc"])
        reason = err["msg"]
        if isinstance(found, FieldValueError):
            loc = ".".join(p for p in (loc, found.path) if p)
            reason = found.reason
        more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
        raise ForestError(f"{reason}{more}", path=f"recipe.{loc}" if loc else "recipe") from None


def load_recipe(name_or_path: str | Path) -> LoadedRecipe:
    """A built-in recipe by name, or a recipe JSON file (its image paths relative to it)."""
    if str(name_or_path) in recipe_names():
        path = _builtin_folder() / f"{name_or_path}.json"
        return LoadedRecipe(
            recipe_from_json(path.read_bytes(), f"recipe {name_or_path}"), path.parent
        )
    path = Path(name_or_path)
    if not path.is_file():
        raise ForestError(
            f"no built-in recipe or recipe file {str(name_or_path)!r}; built-in: "
            + ", ".join(recipe_names()),
            path="recipe",
        )
    if path.stat().st_size > MAX_RECIPE_BYTES:
        raise ForestError(f"the recipe file is over {MAX_RECIPE_BYTES:,} bytes", path="recipe")
    return LoadedRecipe(recipe_from_json(path.read_bytes(), str(path)), path.parent)


def summary(recipe: Recipe) -> RecipeSummary:
    return RecipeSummary(
        name=recipe.name,
        description=recipe.description,
        layers=[f"{layer.name}: {layer.species} ({layer.role})" for layer in recipe.layers],
    )


def builtin_summaries() -> list[RecipeSummary]:
    return [summary(load_recipe(n).recipe) for n in recipe_names()]
