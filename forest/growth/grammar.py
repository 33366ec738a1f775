"""Grammar files: loading and parsing, and the compiled form (:class:`CompiledGrammar`,
numpy tables for vectorised expansion) that :func:`forest.growth.compile.compile_grammar`
builds."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from forest.errors import GrammarError
from forest.growth.grammar_errors import raise_all, reference_errors, validation_errors
from forest.sniff import describe, sniff
from schemas.grammar import Grammar

# A grammar file is a few KiB; anything this big is not a grammar and would only cost time.
MAX_GRAMMAR_BYTES = 1 << 20


def parse_grammar(data: Any) -> Grammar:
    """Validate already-decoded JSON into a :class:`Grammar`, naming every bad field at once
    (:class:`~forest.growth.grammar_errors.GrammarErrors`), with "did you mean" for unknown
    fields."""
    try:
        return Grammar.model_validate(data)
    except ValidationError as exc:
        found = validation_errors(exc)
        seen = {e.path for e in found}
        raise_all(found + [e for e in reference_errors(data) if e.path not in seen])
        raise  # unreachable: a ValidationError holds at least one error


def load_grammar(path: str | Path) -> Grammar:
    """Read a grammar JSON file; malformed, truncated, huge or missing files get a GrammarError."""
    p = Path(path)
    kind = sniff(p) if p.exists() else "missing"
    if kind not in ("json", "text", "missing"):
        raise GrammarError(f"is {describe(kind)}, not a grammar (JSON)", path=str(p))
    try:
        size = p.stat().st_size
        if size > MAX_GRAMMAR_BYTES:
            raise GrammarError(
                f"file is {size} bytes; a grammar is at most {MAX_GRAMMAR_BYTES}", path=str(p)
            )
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise GrammarError("no such file", path=str(p)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise GrammarError(f"cannot read: {exc}", path=str(p)) from None
    return grammar_from_json(text, source=str(p))


def grammar_from_json(text: str, source: str = "grammar") -> Grammar:
    try:
        data = json.loads(text)
    except RecursionError:
        raise GrammarError("JSON nested too deeply to be a grammar", path=source) from None
    except json.JSONDecodeError as exc:
        at_end = exc.pos >= len(text.rstrip()) or exc.msg.startswith("Unterminated string")
        what = "truncated JSON (the file ends early)" if at_end else "malformed JSON"
        raise GrammarError(
            f"{what}: {exc.msg} (line {exc.lineno}, column {exc.colno})", path=source
        ) from None
    return parse_grammar(data)


@dataclass(frozen=True, eq=False)
class CompiledGrammar:
    """A grammar as tables indexed by symbol id ``s`` and alternative id ``a``.

    alt_symbol : (A,) int32            alt_piece : (A,) int32 (index into PIECE_NAMES)
    alt_weight : (A,) float64          alt_depth : (A, 2) int32 inclusive [min, max]
    alt_twist : (A,) int32 (-1 random) alt_succ : (A, MAX_LEAF_RIMS) int32 (-1 none)
    alt_length, alt_radius : (A, MAX_LEAF_RIMS, 2) float64 ranges
    alt_bend, alt_spread : (A, 2) float64 ranges in radians
    alt_roll : (A,) float64 phyllotaxis divergence in degrees, NaN where none
    alt_branch_angle : (A, 2) float64 range in radians, NaN where none
    alt_tropism : (A, 2) float64 gravity and light strengths
    alt_taper : (A, 2) float64 range of the radius at the children over the root radius
    alt_thickness : (A, 2) float64 [min, max) root-rim radius in metres the alternative
    applies to (max inf where none)
    foliage : (S,) bool
    cap_alt : the alternative (last, weight 0, never drawn) that closes a tip with the Cap
    piece; -1 when the piece library has none
    finish_alt : the alternative (weight 0, never drawn, just before ``cap_alt``) that
    continues a branch stopped while thicker than a twig's end as a tapering straight piece;
    -1 when the piece library has no cap
    """

    grammar: Grammar
    symbols: tuple[str, ...]
    axiom: int
    max_depth: int
    alt_symbol: NDArray[np.int32]
    alt_piece: NDArray[np.int32]
    alt_weight: NDArray[np.float64]
    alt_depth: NDArray[np.int32]
    alt_twist: NDArray[np.int32]
    alt_succ: NDArray[np.int32]
    alt_length: NDArray[np.float64]
    alt_radius: NDArray[np.float64]
    alt_bend: NDArray[np.float64]
    alt_spread: NDArray[np.float64]
    alt_roll: NDArray[np.float64]
    alt_branch_angle: NDArray[np.float64]
    alt_tropism: NDArray[np.float64]
    alt_taper: NDArray[np.float64]
    alt_thickness: NDArray[np.float64]
    foliage: NDArray[np.bool_]
    cap_alt: int
    finish_alt: int
    pipe_exponent: float | None
    expected_pieces: float
    expected_kinds: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    """``(P,)`` expected pieces of each kind (PIECE_NAMES) per tree, with the margin of
    ``expected_pieces``: the bones and baked vertices follow from it before expansion."""
    expected_bearers: float = 0.0
    """Expected foliage-bearing pieces per tree (:func:`forest.growth.compile.foliage_bearers`)."""

    def choice_table(self, depth: int) -> NDArray[np.float64]:
        """``(S, A)`` cumulative weights of the alternatives eligible at ``depth``."""
        ok = (self.alt_depth[:, 0] <= depth) & (depth <= self.alt_depth[:, 1])
        w = np.zeros((len(self.symbols), len(self.alt_symbol)))
        w[self.alt_symbol, np.arange(len(self.alt_symbol))] = self.alt_weight * ok
        return np.cumsum(w, axis=1)

    @property
    def by_thickness(self) -> bool:
        """Whether any alternative has a thickness condition."""
        return bool(
            (self.alt_thickness[:, 0] > 0).any() or np.isfinite(self.alt_thickness[:, 1]).any()
        )
