"""Checks of tree and forest requests beyond their schema: exactly one of preset/grammar,
a grammar that compiles, and the service's caps. Errors name the request field (422)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

from farm.requests import loaded_recipe, stand_size
from forest.bark.images import check_grey
from forest.caps import check_glb_vertices, check_palette, layer_estimates
from forest.cost import BASE_MEMORY, USDA_FACTOR, forest_cost
from forest.errors import ForestError, GrammarError, LimitError
from forest.growth.compile import compile_grammar
from forest.growth.grammar import CompiledGrammar
from forest.growth.presets import PresetOrGrammarError, grammar_of, load_preset
from forest.settings import ForestSettings, get_settings
from forest.stand.place import MAX_STAND_TREES, MIN_SPACING_M, crown_radius, layer_counts
from forest.stand.recipes import LoadedRecipe
from forest.stand.terrain import image_bytes
from schemas.grammar import Grammar
from schemas.jobs import TreeRequest
from schemas.recipe import SIZE_MIN, Recipe
from service.errors import field_error, forest_error
from service.settings import ServiceSettings


def library_settings(settings: ServiceSettings, max_pieces: int) -> ForestSettings:
    return _library_settings(max_pieces, settings.max_frames)


@functools.lru_cache(maxsize=16)
def _library_settings(max_pieces: int, max_frames: int) -> ForestSettings:
    # frozen, so one per cap pair is shared; building one reads the environment (~0.2 ms),
    # which a request paid twice
    return ForestSettings(max_pieces_per_forest=max_pieces, max_frames=max_frames)


def check_frames(req: TreeRequest, settings: ServiceSettings) -> None:
    if req.frames > settings.max_frames:
        raise field_error(["frames"], f"at most {settings.max_frames} frames", "limit_error")


ONE_SOURCE = "give exactly one of preset (a name), grammar (an object) or recipe"


def resolve_grammar(
    req: TreeRequest, settings: ServiceSettings, trees: int, max_pieces: int
) -> tuple[Grammar, CompiledGrammar]:
    try:
        grammar = grammar_of(req.preset, req.grammar, req.bark)
    except PresetOrGrammarError:
        raise field_error(["preset"], ONE_SOURCE) from None
    except GrammarError as exc:  # no such preset: named after the frame cap, as always
        check_frames(req, settings)
        raise forest_error(exc) from None
    check_frames(req, settings)
    # a grammar object's errors name its fields under "grammar"; a preset's name the preset
    prefix: list[str | int] = ["grammar"] if req.grammar is not None else []
    try:
        cg = compile_grammar(grammar, library_settings(settings, max_pieces))
    except GrammarError as exc:
        raise forest_error(exc, [] if exc.path == "preset" else prefix) from None
    except ForestError as exc:
        raise forest_error(exc) from None
    expected = cg.expected_pieces * trees
    if expected > max_pieces:
        raise field_error(
            ["trees"] if trees > 1 else ["grammar" if req.grammar is not None else "preset"],
            f"about {expected:.0f} pieces expected; the cap is {max_pieces}",
            "limit_error",
        )
    return grammar, cg


def check_cost(
    req: TreeRequest, settings: ServiceSettings, cg: CompiledGrammar, trees: int, where: str = ""
) -> None:
    """The request's estimated peak memory and scene bytes (:func:`forest.cost.forest_cost`)
    within the settings' caps, and its palette (bones x frames) and a .glb's baked vertices
    within the library's (:mod:`forest.caps`): 422 naming the cap before any work
    (``where``: " per tile")."""
    cost = forest_cost(
        cg.expected_pieces * trees, trees, req.frames, req.segments, req.format, req.skinned
    )
    field: list[str | int] = ["trees"] if trees > 1 else ["grammar" if req.grammar else "preset"]
    if cost.memory_bytes > settings.max_forest_memory_mb << 20:
        raise field_error(
            field,
            f"about {cost.memory_bytes >> 20} MiB of memory{where} to generate and write; the "
            f"cap is {settings.max_forest_memory_mb} MiB (max_forest_memory_mb): fewer trees, "
            "frames or segments",
            "limit_error",
        )
    if cost.scene_bytes > settings.max_scene_bytes:
        raise field_error(
            field,
            f"a scene of about {cost.scene_bytes >> 20} MiB{where}; the cap is "
            f"{settings.max_scene_bytes >> 20} MiB (max_scene_bytes): fewer trees, frames or "
            "segments",
            "limit_error",
        )
    # the caps the worker's generation and writer hold (the worker's own settings)
    try:
        check_palette(cg, trees, req.frames, get_settings())
        if req.format == "glb":
            check_glb_vertices(cg, trees, req.segments)
    except LimitError as exc:
        palette = exc.path == "max_palette_matrices"
        raise field_error(
            ["frames"] if palette and req.frames > 1 else field,
            f"{exc.message} ({exc.path}{where})" if palette else exc.message,
            "limit_error",
        ) from None


FLATTEN_FACTOR = 3
"""A stand answered as one file (``POST /v1/trees``) is flattened: the composed stage and the
flat layer are held at once, about this many times the layer files' bytes."""


@dataclass(frozen=True)
class StandPlan:
    """What a recipe request will make, estimated before any work: each layer's trees and
    compiled grammar, the expected pieces of them all and the files' bytes."""

    loaded: LoadedRecipe
    counts: tuple[int, ...]
    compiled: tuple[CompiledGrammar, ...]
    pieces: float
    scene_bytes: int


def _check_images(loaded: LoadedRecipe) -> None:
    """Every image of an inline recipe decodes (a band of rows at a time: memory stays small
    whatever the image) within the map caps; a built-in recipe's are shipped and read."""
    if loaded.folder is not None:
        return
    recipe = loaded.recipe
    refs = [
        (f"recipe.layers[{k}].density_map", layer.density_map)
        for k, layer in enumerate(recipe.layers)
    ]
    if recipe.terrain is not None:
        refs.append(("recipe.terrain.image", recipe.terrain.image))
    for field, ref in refs:
        if ref is None:
            continue
        try:
            check_grey(image_bytes(ref, None, field), field)
        except ForestError as exc:
            raise forest_error(exc) from None


def _layer_grammar(
    req: TreeRequest, k: int, settings: ServiceSettings, max_pieces: int
) -> CompiledGrammar:
    layer = req_recipe(req).layers[k]
    loc: list[str | int] = ["recipe", "layers", k]
    if layer.grammar is not None:
        grammar, loc = layer.grammar, [*loc, "grammar"]
    else:
        try:
            grammar = load_preset(layer.preset or "")
        except GrammarError as exc:
            raise field_error([*loc, "preset"], exc.message) from None
    try:
        return compile_grammar(grammar, library_settings(settings, max_pieces))
    except GrammarError as exc:
        if layer.grammar is None:
            raise field_error([*loc, "preset"], exc.message) from None
        raise forest_error(exc, loc) from None
    except ForestError as exc:
        kind = "limit_error" if isinstance(exc, LimitError) else "value_error"
        raise field_error(loc, exc.message, kind) from None


HEX_PACKING = math.pi / (2 * math.sqrt(3))  # the densest packing of equal discs


def _check_room(
    recipe: Recipe,
    compiled: tuple[CompiledGrammar, ...],
    counts: tuple[int, ...],
    area: tuple[float, float],
    where: list[str | int],
) -> None:
    """Refuse a stand whose trees cannot all stand on the area whatever the placement: trunks
    keep their spacing (the larger of two trees'), so discs of half each tree's spacing (at its
    smallest size) never overlap, and no packing covers more than the area (and a rim of the
    largest disc) at the hexagonal density. A stand that passes may still not fit (density
    maps, terrain and light rules): the job then fails saying how many trees found room."""
    need, rim = 0.0, 0.0
    for layer, cg, n in zip(recipe.layers, compiled, counts, strict=True):
        spacing = layer.spacing if layer.spacing is not None else crown_radius(layer, cg.grammar)
        size = layer.size.range[0] if layer.size.range is not None else SIZE_MIN
        r = max(MIN_SPACING_M, spacing * size) * (0.98 if layer.rows is not None else 1.0) / 2
        need += n * math.pi * r * r
        rim = max(rim, r)
    room = (area[0] + 2 * rim) * (area[1] + 2 * rim) * HEX_PACKING
    if need > room:
        raise field_error(
            where,
            f"{sum(counts):,} trees at their spacing need at least {need:,.0f} m2; "
            f"{area[0]:g} x {area[1]:g} m cannot hold them: "
            + (
                "a larger area or lower densities"
                if recipe.by_density
                else "fewer trees or a larger area"
            ),
            "limit_error",
        )


def req_recipe(req: TreeRequest) -> Recipe:
    assert req.recipe is not None and not isinstance(req.recipe, str)
    return req.recipe


def resolve_recipe(
    req: TreeRequest,
    settings: ServiceSettings,
    max_trees: int,
    max_pieces: int,
    *,
    flat: bool = False,
) -> StandPlan:
    """Check a recipe request before any work: the recipe (a built-in name, or an object whose
    images decode), its trees on the area (shares of ``trees``, or densities over ``area``)
    within ``max_trees``, each layer's grammar, the expected pieces of them all within
    ``max_pieces``, the peak memory (layers are grown one at a time; ``flat``: the stand is
    then flattened into one file), the files' bytes and each layer's palette within the caps.
    Each fault is a 422 naming its field."""
    check_frames(req, settings)
    try:
        loaded = loaded_recipe(req)
    except ForestError as exc:
        raise forest_error(exc) from None
    recipe = loaded.recipe
    req = req.model_copy(update={"recipe": recipe})  # the object, a built-in's too
    trees, area = stand_size(req, recipe)
    counts = tuple(layer_counts(recipe, trees, area))
    total = sum(counts)
    where: list[str | int] = ["area"] if recipe.by_density else ["trees"]
    if total < 1:
        raise field_error(where, "the recipe's densities give no tree on this area")
    cap = min(max_trees, MAX_STAND_TREES)
    if total > cap:
        raise field_error(
            where,
            f"the recipe gives {total:,} trees on {area[0]:g} x {area[1]:g} m; at most {cap:,}: "
            + ("a smaller area or lower densities" if recipe.by_density else "fewer trees"),
            "limit_error",
        )
    _check_images(loaded)
    compiled = tuple(_layer_grammar(req, k, settings, max_pieces) for k in range(len(counts)))
    _check_room(recipe, compiled, counts, area, where)
    # each layer's counts at its trees' sizes (the CLI's estimate too): young trees grow
    # fewer orders, and the pieces here are also the job's cost against the tenant's quota
    compiled = tuple(layer_estimates(recipe, compiled, get_settings()))
    per_layer = [cg.expected_pieces * n for cg, n in zip(compiled, counts, strict=True)]
    pieces = sum(per_layer)
    if pieces > max_pieces:
        biggest = max(range(len(counts)), key=lambda k: per_layer[k])
        raise field_error(
            where,
            f"about {pieces:.0f} pieces expected (layer {recipe.layers[biggest].name!r}: "
            f"{per_layer[biggest]:.0f}); the cap is {max_pieces}",
            "limit_error",
        )
    memory, scene = 0, 0
    for k, (cg, n) in enumerate(zip(compiled, counts, strict=True)):
        cost = forest_cost(per_layer[k], n, req.frames, req.segments, "usdc", req.skinned)
        memory = max(memory, cost.memory_bytes)
        scene += cost.scene_bytes
        try:
            check_palette(cg, n, req.frames, get_settings())
        except LimitError as exc:
            raise field_error(
                ["frames"] if req.frames > 1 else ["recipe", "layers", k],
                f"layer {recipe.layers[k].name!r}: {exc.message} ({exc.path})",
                "limit_error",
            ) from None
    if flat:
        if req.format == "usda":
            scene = int(scene * USDA_FACTOR)
        memory = max(memory, BASE_MEMORY + FLATTEN_FACTOR * scene)
    if memory > settings.max_forest_memory_mb << 20:
        raise field_error(
            where,
            f"about {memory >> 20} MiB of memory to generate and write; the cap is "
            f"{settings.max_forest_memory_mb} MiB (max_forest_memory_mb): fewer trees, frames "
            "or segments",
            "limit_error",
        )
    if scene > settings.max_scene_bytes:
        raise field_error(
            where,
            f"files of about {scene >> 20} MiB; the cap is {settings.max_scene_bytes >> 20} MiB "
            "(max_scene_bytes): fewer trees, frames or segments",
            "limit_error",
        )
    return StandPlan(loaded, counts, compiled, pieces, scene)
