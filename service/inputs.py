"""Checks of tree and forest requests beyond their schema: exactly one of preset/grammar,
a grammar that compiles, and the service's caps. Errors name the request field (422)."""

from __future__ import annotations

import functools

from forest.caps import check_glb_vertices, check_palette
from forest.cost import forest_cost
from forest.errors import ForestError, GrammarError, LimitError
from forest.growth.compile import compile_grammar
from forest.growth.grammar import CompiledGrammar
from forest.growth.presets import PresetOrGrammarError, grammar_of
from forest.settings import ForestSettings, get_settings
from schemas.grammar import Grammar
from schemas.jobs import TreeRequest
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


def resolve_grammar(
    req: TreeRequest, settings: ServiceSettings, trees: int, max_pieces: int
) -> tuple[Grammar, CompiledGrammar]:
    try:
        grammar = grammar_of(req.preset, req.grammar)
    except PresetOrGrammarError as exc:
        raise forest_error(exc) from None
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
