"""Compiling a grammar: cross-checks against the piece library and the settings' caps, the
tables of :class:`forest.growth.grammar.CompiledGrammar`, and the expected pieces per tree
(counted level by level, or grown from a small sample where growth ends by thickness and
height, which needs :func:`forest.growth.expand.expand`)."""

from __future__ import annotations

import contextlib
import dataclasses
from typing import Any

import numpy as np
from numpy.typing import NDArray

from forest.bark.tilesets import SETS as BARK_SETS
from forest.errors import ForestError, GrammarError, LimitError
from forest.geometry.pieces import MAX_LEAF_RIMS, PIECE_NAMES, piece_library
from forest.growth.expand import PieceGraph, expand
from forest.growth.grammar import CompiledGrammar
from forest.growth.grammar_errors import did_you_mean, raise_all, reference_errors
from forest.growth.keyed import GROW, tree_keys
from forest.settings import ForestSettings, get_settings
from schemas.grammar import Alternative, Grammar


def compile_grammar(g: Grammar, settings: ForestSettings | None = None) -> CompiledGrammar:
    """Cross-check ``g`` against the piece library and build its tables."""
    settings = settings or get_settings()
    _check_size(g, settings)
    symbols = tuple(g.rules)
    sid = {s: i for i, s in enumerate(symbols)}
    # every cross-reference error of the grammar in one pass, each with its path
    errors: list[GrammarError] = reference_errors(g.model_dump())
    if g.bark not in BARK_SETS:
        errors.append(
            GrammarError(
                f"no shipped bark tile set {g.bark!r} (shipped: {', '.join(BARK_SETS)})"
                f"{did_you_mean(g.bark, BARK_SETS)}",
                path="bark",
            )
        )
    rims = {name: p.n_leaf_rims for name, p in zip(PIECE_NAMES, piece_library(), strict=True)}
    rows: list[tuple[int, Any]] = []
    for s, alts in g.rules.items():
        for j, alt in enumerate(alts):
            where = f"rules.{s}[{j}]"
            if len(alt.successors) != rims[alt.piece]:
                errors.append(
                    GrammarError(
                        f"piece {alt.piece} has {rims[alt.piece]} leaf rim(s) but "
                        f"{len(alt.successors)} successor(s) are given",
                        path=f"{where}.successors",
                    )
                )
            rows.append((sid[s], alt))
    raise_all(errors)
    has_cap = "Cap" in PIECE_NAMES
    if has_cap:  # never drawn (weight 0): expansion puts them on every tip it closes
        # a straight piece that ends a branch stopped while thicker than a twig, tapering it
        # (forest.growth.expand.FINISH_TAPER) until the cap closes a twig-thin rim
        rows.append((0, Alternative(piece="I", weight=1.0, successors=[None])))
        rows.append((0, Alternative(piece="Cap", weight=1.0, successors=[])))
    n_alt = len(rows)
    big = np.iinfo(np.int32).max
    alt_succ = np.full((n_alt, MAX_LEAF_RIMS), -1, np.int32)
    alt_length = np.ones((n_alt, MAX_LEAF_RIMS, 2))
    alt_radius = np.ones((n_alt, MAX_LEAF_RIMS, 2))
    for a, (_, alt) in enumerate(rows):
        for r, succ in enumerate(alt.successors):
            if succ is not None:
                alt_succ[a, r] = sid[succ.symbol]
                alt_length[a, r] = succ.length
                alt_radius[a, r] = succ.radius
    max_depth = g.max_depth if g.max_depth is not None else settings.depth_limit
    cap_alt = n_alt - 1 if has_cap else -1
    finish_alt = n_alt - 2 if has_cap else -1
    alts = [alt for _, alt in rows]
    nan2 = (float("nan"), float("nan"))
    cg = CompiledGrammar(
        grammar=g,
        symbols=symbols,
        axiom=sid[g.axiom],
        max_depth=max_depth,
        alt_symbol=np.array([s for s, _ in rows], np.int32),
        alt_piece=np.array([PIECE_NAMES.index(alt.piece) for _, alt in rows], np.int32),
        alt_weight=np.array([alt.weight for _, alt in rows])
        * ~np.isin(np.arange(n_alt), [cap_alt, finish_alt]),
        alt_depth=np.array(
            [[alt.min_depth, big if alt.max_depth is None else alt.max_depth] for _, alt in rows],
            np.int32,
        ),
        alt_twist=np.array(
            [-1 if alt.twist == "random" else alt.twist for _, alt in rows], np.int32
        ),
        alt_succ=alt_succ,
        alt_length=alt_length,
        alt_radius=alt_radius,
        alt_bend=np.deg2rad([alt.pose.bend for _, alt in rows]).reshape(n_alt, 2),
        alt_spread=np.deg2rad([alt.pose.spread for _, alt in rows]).reshape(n_alt, 2),
        alt_roll=np.array([np.nan if a.roll is None else a.roll for a in alts]),
        alt_branch_angle=np.deg2rad([a.branch_angle or nan2 for a in alts]).reshape(n_alt, 2),
        alt_tropism=np.array([[a.tropism.gravity, a.tropism.light] for a in alts]).reshape(
            n_alt, 2
        ),
        alt_taper=np.array([a.taper for a in alts]).reshape(n_alt, 2),
        alt_thickness=np.array(
            [[a.min_radius, np.inf if a.max_radius is None else a.max_radius] for a in alts]
        ).reshape(n_alt, 2),
        foliage=np.isin(np.arange(len(symbols)), [sid[s] for s in g.foliage]),
        cap_alt=cap_alt,
        finish_alt=finish_alt,
        pipe_exponent=g.pipe_exponent,
        expected_pieces=0.0,
    )
    if _eligible_weight(cg, 0)[cg.axiom] <= 0:
        raise GrammarError(
            f"axiom {g.axiom!r} has no alternative allowed at depth 0 (check min_depth)",
            path=f"rules.{g.axiom}",
        )
    if g.max_depth is None:
        _check_terminates(cg)
    sampled = g.twig_radius is not None or g.crown is not None or cg.by_thickness
    if sampled:
        # growth ends by thickness and height, which counting by depth cannot see: grow a
        # small sample (its own fixed seed; the per-tree cap still stops a runaway)
        expected, kinds, bearers = _sampled_pieces(cg, settings)
    else:
        expected, kinds, bearers = _expected_pieces(cg)
    object.__setattr__(cg, "expected_pieces", expected)
    object.__setattr__(cg, "expected_kinds", kinds)
    object.__setattr__(cg, "expected_bearers", bearers)
    if expected > settings.max_pieces_per_tree:
        raise LimitError(
            f"the grammar grows about {expected:.3g} pieces per tree, over the cap of "
            f"{settings.max_pieces_per_tree}; lower max_depth or the branching",
            path="max_pieces_per_tree",
            limit=settings.max_pieces_per_tree,
        )
    if not sampled and g.close_tips and has_cap and expected <= SAMPLE_MAX_PIECES:
        # the chains that finish thick tips depend on the radii there, which counting by
        # depth cannot see: the kinds (bones, vertices) come from a sample where one is
        # cheap and grows (a grammar that fails to is refused when the forest grows)
        with contextlib.suppress(ForestError):
            _, kinds, bearers = _sampled_pieces(cg, settings)
            object.__setattr__(cg, "expected_kinds", kinds)
            object.__setattr__(cg, "expected_bearers", bearers)
    return cg


def _check_size(g: Grammar, settings: ForestSettings) -> None:
    """The grammar's rule and alternative counts within the settings' caps, before any
    table is built (what follows is linear in them, expansion is not)."""
    if len(g.rules) > settings.max_grammar_rules:
        raise GrammarError(
            f"{len(g.rules)} rules; a grammar has at most {settings.max_grammar_rules} "
            "(max_grammar_rules)",
            path="rules",
        )
    n_alt = sum(len(alts) for alts in g.rules.values())
    if n_alt > settings.max_grammar_alternatives:
        raise GrammarError(
            f"{n_alt} alternatives in all; a grammar has at most "
            f"{settings.max_grammar_alternatives} (max_grammar_alternatives)",
            path="rules",
        )


def _eligible_weight(cg: CompiledGrammar, depth: int) -> NDArray[np.float64]:
    """``(S,)`` each symbol's total weight of the alternatives eligible at ``depth`` (the last
    column of :meth:`CompiledGrammar.choice_table`, without its ``(S, A)`` table)."""
    weights = _alt_weights(cg, depth)
    return np.bincount(cg.alt_symbol, weights=weights, minlength=len(cg.symbols)).astype(float)


def _alt_weights(cg: CompiledGrammar, depth: int) -> NDArray[np.float64]:
    """``(A,)`` each alternative's weight at ``depth`` (0 where its depth range excludes it)."""
    ok = (cg.alt_depth[:, 0] <= depth) & (depth <= cg.alt_depth[:, 1])
    return cg.alt_weight * ok


SAMPLE_TREES = 4
SAMPLE_MARGIN = 1.15  # over the sample's mean: a margin for the spread of sizes
SAMPLE_MAX_PIECES = 20_000  # a tree counted by depth is sampled only below this: ~0.1 s


def _sampled_pieces(
    cg: CompiledGrammar, settings: ForestSettings
) -> tuple[float, NDArray[np.float64], float]:
    """Mean pieces per tree of a few trees of average size, each kind's and the foliage
    bearers' (x :data:`SAMPLE_MARGIN`)."""
    g = cg.grammar
    radius = np.full(SAMPLE_TREES, g.trunk_radius * sum(g.tree_scale) / 2)
    graph = expand(cg, tree_keys(0, np.arange(SAMPLE_TREES), GROW), settings, radius)
    per_tree = SAMPLE_MARGIN / SAMPLE_TREES
    kinds = np.bincount(graph.piece, minlength=len(PIECE_NAMES)).astype(np.float64) * per_tree
    bearers = len(foliage_bearers(cg, graph)) * per_tree
    return len(graph) * per_tree, kinds, bearers


def at_sizes(
    cg: CompiledGrammar, sizes: NDArray[np.float64], settings: ForestSettings | None = None
) -> CompiledGrammar:
    """``cg`` with its expected pieces, kinds and bearers per tree for trees of ``sizes``
    (a mixed stand's layer, :mod:`forest.stand`: the trunk's radius and the crown's height
    scale by the size, so a young tree ends its branches sooner and grows fewer orders): one
    tree grown at each size, their mean x :data:`SAMPLE_MARGIN`. A grammar that ends by
    depth alone grows the same at any size and is returned as it is."""
    g = cg.grammar
    if g.twig_radius is None and g.crown is None and not cg.by_thickness:
        return cg
    sizes = np.asarray(sizes, np.float64)
    graph = expand(
        cg, tree_keys(0, np.arange(len(sizes)), GROW), settings or get_settings(),
        g.trunk_radius * sizes, sizes,
    )  # fmt: skip
    per_tree = SAMPLE_MARGIN / len(sizes)
    kinds = np.bincount(graph.piece, minlength=len(PIECE_NAMES)).astype(np.float64) * per_tree
    return dataclasses.replace(
        cg,
        expected_pieces=len(graph) * per_tree,
        expected_kinds=kinds,
        expected_bearers=len(foliage_bearers(cg, graph)) * per_tree,
    )


def foliage_bearers(cg: CompiledGrammar, graph: PieceGraph) -> NDArray[np.int32]:
    """``(k,)`` the instances that bear leaf sprays: of a foliage symbol, not a cap, and no
    thicker than the leaves' ``max_radius`` (leaves live on the last orders, not on trunks
    and main limbs)."""
    bears = cg.foliage[graph.symbol]
    if "Cap" in PIECE_NAMES:
        bears &= graph.piece != PIECE_NAMES.index("Cap")
    if cg.grammar.leaves.max_radius is not None:
        bears &= graph.scale <= cg.grammar.leaves.max_radius
    return np.flatnonzero(bears).astype(np.int32)


def _check_terminates(cg: CompiledGrammar) -> None:
    """Without max_depth every reachable symbol must be able to end in a finite tree.

    Linear in the rules (a worklist, as for Horn clauses): a symbol ends once one of its
    alternatives has only ending successors; each (alternative, rim) is visited once."""
    n = len(cg.symbols)
    n_alt = len(cg.alt_symbol)
    rims = [(a, int(s)) for a, row in enumerate(cg.alt_succ) for s in row if s >= 0]
    waiting_on: list[list[int]] = [[] for _ in range(n)]  # symbol -> alternatives using it
    pending = np.zeros(n_alt, np.int64)  # per alternative: successors not known to end
    for a, s in rims:
        waiting_on[s].append(a)
        pending[a] += 1
    live = ~np.isin(np.arange(n_alt), [cg.cap_alt, cg.finish_alt])
    ends = np.zeros(n, bool)
    todo: list[int] = []

    def settle(a: int) -> None:
        s = int(cg.alt_symbol[a])
        if live[a] and not ends[s]:
            ends[s] = True
            todo.append(s)

    for first in np.nonzero(pending == 0)[0]:
        settle(int(first))
    while todo:
        for a in waiting_on[todo.pop()]:
            pending[a] -= 1
            if pending[a] == 0:
                settle(a)
    alts_of: list[list[int]] = [[] for _ in range(n)]
    for a, s in enumerate(cg.alt_symbol):
        alts_of[int(s)].append(a)
    reach = np.zeros(n, bool)
    reach[cg.axiom] = True
    todo = [cg.axiom]
    while todo:
        for a in alts_of[todo.pop()]:
            for s in cg.alt_succ[a]:
                if s >= 0 and not reach[s]:
                    reach[s] = True
                    todo.append(int(s))
    stuck = [cg.symbols[i] for i in np.nonzero(reach & ~ends)[0]]
    if stuck:
        raise GrammarError(
            f"the rules never terminate: every alternative of {', '.join(map(repr, stuck))} "
            "keeps growing; add an alternative without successors or set max_depth",
            path="max_depth",
        )


def _expected_pieces(cg: CompiledGrammar) -> tuple[float, NDArray[np.float64], float]:
    """Expected pieces per tree, summed level by level up to max_depth (each level linear
    in the alternatives); each kind's, with the caps that close the tips (which the total
    leaves out; not the finishing chains, which depend on the radii), and the foliage
    bearers' (every foliage piece: thickness is not known)."""
    n = len(cg.symbols)
    level = np.zeros(n)
    level[cg.axiom] = 1.0
    total = bearers = caps = 0.0
    kinds = np.zeros(len(PIECE_NAMES))
    has = cg.alt_succ >= 0
    succ = cg.alt_succ[has]
    rims = np.array([p.n_leaf_rims for p in piece_library()])[cg.alt_piece]
    open_rims = rims - has.sum(axis=1)  # rims without a successor: capped
    for d in range(cg.max_depth + 1):
        w = _alt_weights(cg, d)
        tot = np.bincount(cg.alt_symbol, weights=w, minlength=n)
        grown = level * (tot > 0)
        total += grown.sum()
        caps += (level * (tot <= 0)).sum()  # no eligible alternative: a tip
        bearers += grown[cg.foliage].sum()
        if total > 1e15 or not grown.any():
            break
        p = w / np.where(tot > 0, tot, 1.0)[cg.alt_symbol]
        per_alt = grown[cg.alt_symbol] * p
        kinds += np.bincount(cg.alt_piece, weights=per_alt, minlength=len(PIECE_NAMES))
        caps += per_alt @ (rims if d == cg.max_depth else open_rims)  # pruned at max_depth
        per_rim = np.broadcast_to(per_alt[:, None], has.shape)[has]
        level = np.bincount(succ, weights=per_rim, minlength=n).astype(float)
    if cg.grammar.close_tips and cg.cap_alt >= 0:
        kinds[cg.alt_piece[cg.cap_alt]] += caps
    return float(total), kinds, float(bearers)
