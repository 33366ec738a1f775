"""Grammar loading and compilation: bad input gets a typed error naming the field."""

from __future__ import annotations

import copy
import json
import re
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from forest.errors import ForestError, GrammarError, LimitError
from forest.growth.compile import compile_grammar
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.grammar import (
    MAX_GRAMMAR_BYTES,
    grammar_from_json,
    load_grammar,
    parse_grammar,
)
from forest.growth.presets import load_preset, preset_names
from forest.settings import ForestSettings
from schemas.grammar import Grammar

GOOD: dict[str, Any] = {
    "axiom": "A",
    "max_depth": 4,
    "rules": {
        "A": [{"piece": "I", "successors": [{"symbol": "B"}]}],
        "B": [
            {"piece": "Y", "weight": 2, "successors": [{"symbol": "A"}, None]},
            {"piece": "I", "successors": [None]},
        ],
    },
    "foliage": ["B"],
}


LINE_COLUMN = re.compile(r"line (\d+),? column (\d+)")


def line_column(msg: str) -> tuple[int, int]:
    """The (line, column) a JSON error message points at."""
    m = LINE_COLUMN.search(msg)
    assert m, f"no line and column in {msg!r}"
    return int(m.group(1)), int(m.group(2))


def grammar(**changes: Any) -> dict[str, Any]:
    g = copy.deepcopy(GOOD)
    g.update(changes)
    return g


def compile_dict(data: dict[str, Any], settings: ForestSettings | None = None) -> Any:
    return compile_grammar(parse_grammar(data), settings)


def test_good_grammar_compiles() -> None:
    cg = compile_dict(GOOD)
    assert cg.symbols == ("A", "B")
    assert cg.max_depth == 4
    assert cg.expected_pieces > 0


def test_unknown_successor_symbol() -> None:
    g = grammar()
    g["rules"]["A"][0]["successors"][0]["symbol"] = "Nope"
    with pytest.raises(GrammarError) as exc:
        compile_dict(g)
    assert exc.value.path == "rules.A[0].successors[0].symbol"
    assert "Nope" in str(exc.value)


def test_unknown_successor_symbol_in_later_alternative_and_rim() -> None:
    g = grammar()
    g["rules"]["B"][0]["successors"][1] = {"symbol": "Ghost"}
    with pytest.raises(GrammarError) as exc:
        compile_dict(g)
    assert exc.value.path == "rules.B[0].successors[1].symbol"


def test_unknown_axiom() -> None:
    with pytest.raises(GrammarError) as exc:
        compile_dict(grammar(axiom="Z"))
    assert exc.value.path == "axiom"
    assert "Z" in exc.value.message


def test_unknown_foliage_symbol() -> None:
    with pytest.raises(GrammarError) as exc:
        compile_dict(grammar(foliage=["A", "Leaf"]))
    assert exc.value.path == "foliage[1]"
    assert "Leaf" in exc.value.message


@pytest.mark.parametrize("weight", [-1.0, 0.0, -1e-9])
def test_non_positive_weight(weight: float) -> None:
    g = grammar()
    g["rules"]["A"][0]["weight"] = weight
    with pytest.raises(GrammarError) as exc:
        parse_grammar(g)
    assert exc.value.path == "rules.A[0].weight"


@pytest.mark.parametrize("weight", ["NaN", "Infinity"])
def test_non_finite_weight_from_json(weight: str) -> None:
    text = json.dumps(GOOD).replace('"weight": 2', f'"weight": {weight}')
    with pytest.raises(GrammarError) as exc:
        grammar_from_json(text)
    assert exc.value.path == "rules.B[0].weight"


def test_huge_weights_are_rejected_or_work() -> None:
    """Weights are finite but unbounded above; two of 1e308 overflow the cumulative choice
    table to inf. Either the grammar is rejected with a GrammarError, or it must grow."""
    g = grammar()
    g["rules"]["B"][0]["weight"] = 1e308
    g["rules"]["B"][1]["weight"] = 1e308
    try:
        grammar_obj = parse_grammar(g)
        cg = compile_grammar(grammar_obj)
    except GrammarError as exc:
        assert exc.path.startswith("rules.B")
        return
    assert np.isfinite(cg.expected_pieces)
    f = generate_forest(grammar_obj, 0, ForestOptions(trees=4))
    assert set(f.graph.alt[f.graph.symbol == 1].tolist()) <= {1, 2}


@pytest.mark.parametrize(("piece", "n"), [("I", 2), ("I", 0), ("Y", 1), ("T", 3), ("Psi", 2)])
def test_wrong_successor_count(piece: str, n: int) -> None:
    g = grammar()
    g["rules"]["A"][0] = {"piece": piece, "successors": [None] * n}
    with pytest.raises(GrammarError) as exc:
        compile_dict(g)
    assert exc.value.path == "rules.A[0].successors"
    assert piece in exc.value.message


def test_rules_that_never_terminate_without_max_depth() -> None:
    g = grammar()
    del g["max_depth"]
    # A -> B, and B's alternatives both keep growing
    g["rules"]["B"] = [{"piece": "Y", "successors": [{"symbol": "A"}, None]}]
    with pytest.raises(GrammarError) as exc:
        compile_dict(g)
    assert exc.value.path == "max_depth"
    assert "terminate" in exc.value.message


def test_rules_that_terminate_need_no_max_depth() -> None:
    g = grammar()
    del g["max_depth"]
    cg = compile_dict(g)
    f = generate_forest(cg.grammar, 3, ForestOptions(trees=5), compiled=cg)
    assert f.n_instances >= 5


def test_growth_past_piece_cap_is_a_limit_error() -> None:
    g = {
        "axiom": "S",
        "max_depth": 10,
        "rules": {"S": [{"piece": "Y", "successors": [{"symbol": "S"}, {"symbol": "S"}]}]},
    }
    with pytest.raises(LimitError) as exc:
        compile_dict(g, ForestSettings(max_pieces_per_tree=100))
    assert exc.value.path == "max_pieces_per_tree"
    assert exc.value.limit == 100
    # the same grammar is fine under the default cap
    assert compile_dict(g).expected_pieces == 2**11 - 1


def test_axiom_without_an_alternative_at_depth_zero() -> None:
    """The axiom's only alternative starts at depth 1: no tree can grow. The library should
    say so with a GrammarError (at compile or at generation), not crash."""
    g = {
        "axiom": "A",
        "max_depth": 3,
        "rules": {"A": [{"piece": "I", "min_depth": 1, "successors": [None]}]},
    }
    with pytest.raises(GrammarError):
        cg = compile_dict(g)
        generate_forest(cg.grammar, 1, ForestOptions(trees=2), compiled=cg)


@pytest.mark.parametrize(
    ("text", "line", "column"),
    [
        ('{"axiom": "A",, "rules": {}}', 1, 15),
        ('{\n  "axiom": "A"\n  "rules": {}\n}', 3, 3),
        ('{"axiom": "A"} trailing', 1, 16),
        ('{"axiom": "A"}}', 1, 15),  # one brace too many
        ('{"axiom": "A",}', 1, 15),  # trailing comma
        ('{"axiom": "A", "rules": {}]', 1, 27),
    ],
)  # wrong closing bracket
def test_malformed_json(text: str, line: int, column: int) -> None:
    with pytest.raises(GrammarError) as exc:
        grammar_from_json(text, source="my.json")
    msg = exc.value.message
    assert msg.startswith("malformed JSON"), msg
    assert line_column(msg) == (line, column)
    assert exc.value.path == "my.json"


GOOD_TEXT = json.dumps(GOOD, indent=2)


@pytest.mark.parametrize(
    "cut",
    [
        "{",  # just opened
        '"axiom": ',  # after a key
        '"max_depth": 4,',  # after a value and comma
        '"successors": [',  # inside a list
        '"weight": 2',  # inside a number's object
    ],
)
def test_truncated_json(cut: str) -> None:
    text = GOOD_TEXT[: GOOD_TEXT.index(cut) + len(cut)]
    with pytest.raises(GrammarError) as exc:
        grammar_from_json(text)
    msg = exc.value.message
    assert msg.startswith("truncated JSON"), msg
    assert line_column(msg)[0] == text.count("\n") + 1


def test_truncated_json_drops_the_closing_brace() -> None:
    text = GOOD_TEXT.rstrip()[:-1]  # ends with a newline: the error is on the next line
    line = text.count("\n") + 1
    with pytest.raises(GrammarError) as exc:
        grammar_from_json(text)
    assert exc.value.message.startswith("truncated JSON"), exc.value.message
    assert line_column(exc.value.message) == (line, 1)


def test_truncated_inside_a_string_is_truncated() -> None:
    """A file cut off inside a string is truncated too: json reports the string's start,
    not the end of the text, so the message must not call it malformed."""
    text = GOOD_TEXT[: GOOD_TEXT.index('"rules"') + 4]
    with pytest.raises(GrammarError) as exc:
        grammar_from_json(text)
    msg = exc.value.message
    assert msg.startswith("truncated JSON"), msg
    assert " at at " not in msg
    assert line_column(msg) == (4, 3)  # where the cut string starts


def test_empty_text_is_truncated() -> None:
    with pytest.raises(GrammarError, match="truncated JSON"):
        grammar_from_json("  \n")


def test_deeply_nested_json_is_a_grammar_error() -> None:
    """Well under MAX_GRAMMAR_BYTES, but nested past Python's recursion limit."""
    text = "[" * 100_000 + "]" * 100_000
    assert len(text) < MAX_GRAMMAR_BYTES
    with pytest.raises(GrammarError):
        grammar_from_json(text)


def test_json_of_wrong_shape() -> None:
    with pytest.raises(GrammarError):
        grammar_from_json("[1, 2, 3]")
    with pytest.raises(GrammarError) as exc:
        grammar_from_json(json.dumps(grammar(colour="green")))
    assert exc.value.path == "colour"


def test_missing_file(tmp_path: Path) -> None:
    missing = tmp_path / "nope.json"
    with pytest.raises(GrammarError) as exc:
        load_grammar(missing)
    assert exc.value.path == str(missing)
    assert "no such file" in exc.value.message


def test_huge_file(tmp_path: Path) -> None:
    big = tmp_path / "big.json"
    big.write_text('{"axiom": "A", "description": "' + "x" * MAX_GRAMMAR_BYTES + '"}')
    assert big.stat().st_size > MAX_GRAMMAR_BYTES
    with pytest.raises(GrammarError) as exc:
        load_grammar(big)
    assert exc.value.path == str(big)
    assert str(MAX_GRAMMAR_BYTES) in exc.value.message


def test_file_that_is_not_utf8(tmp_path: Path) -> None:
    bad = tmp_path / "latin1.json"
    bad.write_bytes(b'{"axiom": "\xe9"}')
    with pytest.raises(GrammarError) as exc:
        load_grammar(bad)
    assert exc.value.path == str(bad)


def test_malformed_file_names_the_file(tmp_path: Path) -> None:
    p = tmp_path / "g.json"
    p.write_text('{"axiom": ')
    with pytest.raises(GrammarError) as exc:
        load_grammar(p)
    assert exc.value.path == str(p)
    assert "truncated JSON" in exc.value.message


def test_good_file_loads(tmp_path: Path) -> None:
    p = tmp_path / "g.json"
    p.write_text(json.dumps(GOOD))
    assert load_grammar(p) == parse_grammar(GOOD)


def test_errors_are_forest_errors_with_useful_repr() -> None:
    with pytest.raises(ForestError) as exc:
        compile_dict(grammar(axiom="Z"))
    assert "GrammarError" in repr(exc.value) and "axiom" in repr(exc.value)
    assert str(exc.value).startswith("axiom: ")


@pytest.mark.parametrize("name", preset_names())
def test_presets_compile(name: str) -> None:
    g = load_preset(name)
    assert isinstance(g, Grammar)
    cg = compile_grammar(g)
    assert 1 <= cg.expected_pieces <= ForestSettings().max_pieces_per_tree
    # the shipped file loads the same through load_grammar
    path = resources.files("forest.growth.presets").joinpath(f"{name}.json")
    with resources.as_file(path) as p:
        assert load_grammar(p) == g


def test_unknown_preset() -> None:
    with pytest.raises(GrammarError) as exc:
        load_preset("baobab")
    assert exc.value.path == "preset"


def test_grammar_of_takes_exactly_one_of_preset_and_grammar(tmp_path: Path) -> None:
    from forest.growth.presets import PresetOrGrammarError, grammar_of

    good = parse_grammar(GOOD)
    for preset, named in ((None, None), ("almond", good)):
        with pytest.raises(PresetOrGrammarError) as exc:
            grammar_of(preset, named)
        assert exc.value.path == "preset"
    assert grammar_of("almond", None) == load_preset("almond")
    assert grammar_of(None, good) is good
    (tmp_path / "g.json").write_text(json.dumps(GOOD))
    assert grammar_of(None, tmp_path / "g.json") == good
    with pytest.raises(GrammarError, match="unknown preset"):
        grammar_of("nope", None)


def test_presets_include_the_papers_algorithms() -> None:
    assert {"alternating", "uniform"} <= set(preset_names())


@settings(max_examples=10, deadline=None)
@given(
    seed=st.integers(min_value=0, max_value=2**63 - 1), trees=st.integers(min_value=1, max_value=6)
)
def test_alternating_expected_count_is_exact(seed: int, trees: int) -> None:
    g = load_preset("alternating")
    cg = compile_grammar(g)
    # I and Y alternate to depth 9: 1, 1, 2, 2, 4, 4, 8, 8, 16, 16
    assert cg.expected_pieces == 62
    f = generate_forest(g, seed, ForestOptions(trees=trees), compiled=cg)
    np.testing.assert_array_equal(
        np.bincount(f.graph.tree, minlength=trees), int(cg.expected_pieces)
    )


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(min_value=0, max_value=2**32))
def test_uniform_expected_count_is_the_mean(seed: int) -> None:
    """The paper's second algorithm: I or Y with probability 1/2 at each rim; a level's
    expected size grows by 3/2, so 9 levels hold sum(1.5**d) pieces on average."""
    cg = compile_grammar(load_preset("uniform"))
    assert cg.expected_pieces == pytest.approx(sum(1.5**d for d in range(9)))
    f = generate_forest(cg.grammar, seed, ForestOptions(trees=400, placement="grid"), compiled=cg)
    mean = f.n_instances / 400
    assert abs(mean - cg.expected_pieces) < 0.25 * cg.expected_pieces


def test_a_billion_trees_is_a_limit_error() -> None:
    with pytest.raises(LimitError) as exc:
        generate_forest(load_preset("alternating"), 1, ForestOptions(trees=10**9))
    assert exc.value.path == "trees"


def test_forest_piece_cap() -> None:
    settings = ForestSettings(max_pieces_per_forest=1000)
    with pytest.raises(LimitError) as exc:
        generate_forest(load_preset("alternating"), 1, ForestOptions(trees=100), settings=settings)
    assert exc.value.path == "max_pieces_per_forest"


def chain(n: int) -> dict[str, Any]:
    """``n`` rules, each growing the next: the costly shape (every symbol one level on)."""
    rules = {
        f"R{i}": [{"piece": "I", "successors": [{"symbol": f"R{i + 1}"} if i + 1 < n else None]}]
        for i in range(n)
    }
    return {"name": "chain", "axiom": "R0", "rules": rules}


def test_a_4000_rule_chain_is_refused_by_the_rule_cap() -> None:
    data = chain(4000)
    assert len(json.dumps(data)) > 250_000  # the 254 KB grammar that took 33 s
    with pytest.raises(GrammarError) as exc:
        compile_dict(data)
    assert exc.value.path == "rules"
    assert exc.value.message == "4000 rules; a grammar has at most 256 (max_grammar_rules)"


def test_alternatives_are_capped_in_all() -> None:
    alts = [{"piece": "I", "successors": [None]}] * 600
    data = {"axiom": "A", "rules": {"A": alts, "B": alts}}
    with pytest.raises(GrammarError) as exc:
        compile_dict(data)
    assert (exc.value.path, exc.value.message) == (
        "rules", "1200 alternatives in all; a grammar has at most 1024 (max_grammar_alternatives)"
    )  # fmt: skip


def test_a_cap_sized_grammar_validates() -> None:
    settings = ForestSettings()
    cg = compile_dict(chain(settings.max_grammar_rules))
    # no max_depth: the chain stops at the depth limit, one piece per level
    assert cg.expected_pieces == settings.depth_limit + 1
    cg = compile_dict(chain(settings.max_grammar_rules) | {"max_depth": 10})
    assert cg.expected_pieces == 11


def _ends_by_fixpoint(cg: Any) -> set[str]:
    """Reference: the symbols that can end, by iterating to a fixpoint over every rule."""
    ends: set[str] = set()
    while True:
        new = {
            cg.symbols[s]
            for a, s in enumerate(cg.alt_symbol)
            if a not in (cg.cap_alt, cg.finish_alt)
            and all(r < 0 or cg.symbols[r] in ends for r in cg.alt_succ[a])
        }
        if new == ends:
            return ends
        ends = new


def _expected_by_table(cg: Any) -> float:
    """Reference: expected pieces through the dense (symbols, alternatives) choice table."""
    level = np.zeros(len(cg.symbols))
    level[cg.axiom] = 1.0
    total = 0.0
    for d in range(cg.max_depth + 1):
        cum = cg.choice_table(d)
        tot = cum[:, -1]
        p = np.diff(cum, axis=1, prepend=0.0) / np.where(tot > 0, tot, 1.0)[:, None]
        grown = level * (tot > 0)
        total += grown.sum()
        if not grown.any():
            break
        nxt = np.zeros(len(cg.symbols))
        for a, s in enumerate(cg.alt_symbol):
            for r in cg.alt_succ[a]:
                if r >= 0:
                    nxt[r] += grown[s] * p[s, a]
        level = nxt
    return total


SYMBOLS = ["A", "B", "C", "D", "E"]
successor = st.one_of(st.none(), st.sampled_from(SYMBOLS).map(lambda s: {"symbol": s}))
alternative = st.fixed_dictionaries(
    {
        "piece": st.just("Y"),
        "weight": st.sampled_from([0.5, 1.0, 3.0]),
        "successors": st.lists(successor, min_size=2, max_size=2),
        "min_depth": st.integers(0, 3),
    }
)


@settings(max_examples=60, deadline=None)
@given(rules=st.lists(st.lists(alternative, min_size=1, max_size=3), min_size=5, max_size=5))
def test_linear_checks_agree_with_the_table_ones(rules: list[list[dict[str, Any]]]) -> None:
    by_symbol = dict(zip(SYMBOLS, rules, strict=True))
    by_symbol["A"] = [{**alt, "min_depth": 0} for alt in by_symbol["A"]]
    data: dict[str, Any] = {"axiom": "A", "max_depth": 6, "rules": by_symbol}
    cg = compile_dict(data)
    assert cg.expected_pieces == pytest.approx(_expected_by_table(cg), rel=1e-12)
    del data["max_depth"]
    g = parse_grammar(data)
    reach = {"A"}
    for _ in SYMBOLS:  # reachable symbols, by brute force
        reach |= {
            s["symbol"] for r in reach for alt in by_symbol[r] for s in alt["successors"] if s
        }
    loose = ForestSettings(max_pieces_per_tree=10**18, depth_limit=8)  # termination only
    if reach <= _ends_by_fixpoint(cg):
        compile_grammar(g, loose)
    else:
        with pytest.raises(GrammarError, match="never terminate"):
            compile_grammar(g, loose)
