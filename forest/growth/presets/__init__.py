"""Grammar presets shipped inside the package (``*.json`` beside this file)."""

from __future__ import annotations

from functools import cache
from importlib import resources

from forest.errors import GrammarError
from forest.growth.grammar import grammar_from_json
from schemas.grammar import Grammar


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
