"""Grammar presets shipped inside the package (``*.json`` beside this file)."""

from __future__ import annotations

from functools import cache
from importlib import resources
from pathlib import Path

from forest.errors import GrammarError
from forest.growth.grammar import grammar_from_json, load_grammar
from schemas.grammar import Grammar


class PresetOrGrammarError(GrammarError):
    """Not exactly one of a preset name and a grammar was given."""


def preset_names() -> list[str]:
    files = resources.files(__name__).iterdir()
    return sorted(f.name.removesuffix(".json") for f in files if f.name.endswith(".json"))


@cache
def load_preset(name: str) -> Grammar:
    if name not in preset_names():
        raise GrammarError(
            f"unknown preset {name!r}; choose one of {', '.join(preset_names())}", path="preset"
        )
    text = resources.files(__name__).joinpath(f"{name}.json").read_text(encoding="utf-8")
    return grammar_from_json(text, source=f"preset {name}")


def grammar_of(
    preset: str | None, grammar: Grammar | Path | None, bark: str | None = None
) -> Grammar:
    """The grammar a request or command names: exactly one of a preset name or a grammar (an
    object, or a JSON file to read). Neither or both: :class:`PresetOrGrammarError`, which
    the CLI words with its flags. ``bark``: a shipped tile set in place of the grammar's."""
    if (preset is None) == (grammar is None):
        raise PresetOrGrammarError(
            "give exactly one of preset (a name) or grammar (an object)", path="preset"
        )
    if preset is not None:
        found = load_preset(preset)
    elif isinstance(grammar, Grammar):
        found = grammar
    else:
        assert grammar is not None
        found = load_grammar(grammar)
    return found if bark is None else found.model_copy(update={"bark": bark})
