"""Species presets read as their species: invariants computed from the generated arrays
(pipe model, taper, shape figures against shared/SPECIES.md, foliage placement), plus the
botanical rules of the grammar on small grammars of their own."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from species_ranges import (
    OAK_BARK_TRIANGLES_MAX,
    OAK_CROWN_BASE,
    ROUND_CROWNS,
    ROUNDNESS_MIN,
    SPECIES,
    TIP_DIAMETER_MAX,
    within,
)

from forest.geometry.pieces import HUB as HUB_JOINT
from forest.geometry.pieces import PIECE_NAMES
from forest.growth.compile import compile_grammar
from forest.growth.foliage import YAW_STEPS
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.grammar import parse_grammar
from forest.growth.measure import fork_pipe_ratios, piece_points, tip_directions, tree_figures
from forest.growth.presets import load_preset, preset_names

CAP = PIECE_NAMES.index("Cap")
SEEDS = st.integers(0, 2**31 - 1)
# broadleaves open-grown and conifers: height over DBH of 20 or more (SPECIES.md); willow and
# almond are short and stout, so the rule of thumb is not theirs
SLENDER = ("oak", "birch", "pine", "spruce", "poplar", "hazel")


def forest(name: str, seed: int, trees: int = 3) -> Forest:
    return generate_forest(load_preset(name), seed, ForestOptions(trees=trees))


def test_every_species_ships() -> None:
    assert set(SPECIES) <= set(preset_names())
    for name in SPECIES:
        g = load_preset(name)
        assert g.bark == name and g.pipe_exponent is not None and g.twig_radius is not None


@pytest.mark.parametrize("name", sorted(SPECIES))
@settings(max_examples=3, deadline=None)
@given(seed=SEEDS)
def test_pipe_model_taper_and_closed_tips(name: str, seed: int) -> None:
    f = forest(name, seed)
    g, grammar = f.graph, f.grammar
    assert grammar.pipe_exponent is not None and grammar.twig_radius is not None
    ratios = fork_pipe_ratios(f, grammar.pipe_exponent)
    assert len(ratios) > 0
    np.testing.assert_allclose(ratios, 1.0, rtol=0.10)
    kids = np.flatnonzero(g.parent >= 0)
    assert (g.scale[kids] <= g.scale[g.parent[kids]] * (1 + 1e-9)).all(), "child thicker"
    # every branch ends in a cap; branches end by thinning below the twig radius (the rest
    # are knots of shed branches and leader tops, still thin against the trunk)
    caps = np.flatnonzero(g.piece == CAP)
    children = np.bincount(g.parent[kids], minlength=len(g))
    rims = np.array([p.n_leaf_rims for p in f.pieces])[g.piece]
    assert (children == rims).all(), "an open rim"
    thin = g.scale[caps] <= grammar.twig_radius
    assert thin.mean() >= 0.95, thin.mean()
    trunk = g.scale[g.parent < 0][g.tree[caps]]
    assert (g.scale[caps] / trunk).max() <= 0.3


@pytest.mark.parametrize("name", sorted(SPECIES))
def test_shape_in_the_species_ranges(name: str) -> None:
    # one seed of six trees. Almond and birch are calibrated well inside their ranges (means
    # over seeds 11-18: 5.7 m, 0.34 m DBH; 18.8 m, 0.42 crown ratio); hazel's and willow's
    # crowns still sit on the edge (hazel 0.65 against 0.68 at seed 13), so for them a seed
    # can still pass or fail by chance
    fig = tree_figures(forest(name, 16, trees=6))
    height, dbh, crown = SPECIES[name]
    h, d, c = np.median(fig.height), np.nanmedian(fig.dbh), np.median(fig.crown_ratio)
    assert within(h, height), (name, h, height)
    assert within(d, dbh), (name, d, dbh)
    assert within(c, crown), (name, c, crown)
    assert 300 <= np.median(fig.pieces) <= 8000
    if name in SLENDER:
        assert np.median(fig.slenderness) >= 20 * (1 - 0.15), np.median(fig.slenderness)


@pytest.mark.parametrize("name", sorted(SPECIES))
def test_twigs_end_thin_and_nothing_under_the_ground(name: str) -> None:
    fig = tree_figures(forest(name, 5, trees=4))
    assert (fig.tip_diameter <= TIP_DIAMETER_MAX).all(), (name, fig.tip_diameter)
    assert (fig.lowest >= 0.0).all(), (name, fig.lowest)


def test_willow_curtains_stop_above_the_ground() -> None:
    f = forest("willow", 8, trees=3)
    fig = tree_figures(f)
    assert f.grammar.ground_clearance > 0
    # hanging shoots end where they reach the clearance, not in the ground
    assert (fig.lowest >= f.grammar.ground_clearance - 0.1).all(), fig.lowest
    assert (fig.lowest <= 1.5).all(), fig.lowest


def test_broadleaf_crowns_are_round_from_above() -> None:
    # the median over a dozen trees of each species: single trees still vary (a crown of five
    # limbs is irregular, down to 0.57 for an almond), a fan of one plane would be far below
    medians = {}
    for name in ROUND_CROWNS:
        r = [tree_figures(forest(name, seed, trees=6)).crown_roundness for seed in (3, 7)]
        medians[name] = float(np.median(np.concatenate(r)))
    assert min(medians.values()) >= ROUNDNESS_MIN, medians


def test_oak_forks_low_under_a_dome_within_its_bark_budget() -> None:
    fig = tree_figures(forest("oak", 16, trees=6))
    assert within(float(np.median(fig.crown_base_fraction)), OAK_CROWN_BASE)
    assert np.median(fig.bark_triangles) <= OAK_BARK_TRIANGLES_MAX, fig.bark_triangles
    f = forest("oak", 16, trees=1)
    g, height = f.graph, tree_figures(f).height[0]
    # three to six heavy limbs leave the short trunk (below 0.4 of the height)
    first = (g.order == 1) & (g.order[np.maximum(g.parent, 0)] == 0) & (g.parent >= 0)
    heavy = first & (g.scale >= 0.25 * g.scale[0]) & (g.height <= 0.4 * height)
    assert 3 <= heavy.sum() <= 6, heavy.sum()


def test_spruce_branches_sweep_down_with_tips_turning_up() -> None:
    f = forest("spruce", 2, trees=1)
    g, pal = f.graph, f.palette()
    axis = pal[f.bones.offset + HUB_JOINT, :3, 1]
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    sym = {s: i for i, s in enumerate(f.grammar.rules)}
    br = g.symbol == sym["Branch"]
    thick = br & (g.scale >= 0.03)
    thin = br & (g.scale < 0.03) & (g.piece != CAP)
    assert axis[thick, 1].mean() < axis[thin, 1].mean()
    assert tree_figures(f).crown_base_fraction[0] <= 0.1  # crown to the ground


def test_thickness_conditions_choose_the_alternative() -> None:
    g = _grammar()
    g["rules"]["A"] = [  # type: ignore[index]
        {**g["rules"]["A"][0], "min_radius": 0.5},  # type: ignore[index]
        {"piece": "I", "successors": [{"symbol": "A"}], "max_radius": 0.5, "taper": [0.7, 0.7]},
    ]
    g.update(trunk_radius=1.0, tree_scale=[1.0, 1.0], max_depth=30)
    f = generate_forest(parse_grammar(g), 3, ForestOptions())
    gr = f.graph
    on_a = np.flatnonzero((gr.symbol == 0) & (gr.piece != CAP))
    t_piece = gr.piece[on_a] == PIECE_NAMES.index("T")
    np.testing.assert_array_equal(t_piece, gr.scale[on_a] >= 0.5)
    assert t_piece.any() and (~t_piece).any()


def test_ground_clearance_ends_hanging_branches_above_it() -> None:
    def branch_hubs(clearance: float) -> np.ndarray:
        g = _grammar(branch_angle=[80, 80], tropism={"gravity": -0.5})
        g["rules"]["B"] = [  # type: ignore[index]
            {"piece": "I", "successors": [{"symbol": "B"}], "tropism": {"gravity": -0.5}}
        ]
        g.update(ground_clearance=clearance, trunk_radius=0.05, max_depth=30)
        f = generate_forest(parse_grammar(g), 1, ForestOptions())
        _, hubs = piece_points(f)
        return hubs[(f.graph.order > 0) & (f.graph.piece != CAP), 1]

    for clearance in (0.0, 0.3):
        y = branch_hubs(clearance)
        # branches hang down to the clearance, never below it
        assert clearance <= y.min() <= clearance + 0.3, (clearance, y.min())


def test_narrow_and_broad_crowns_differ() -> None:
    ratio = {n: np.median(tree_figures(forest(n, 4, trees=4)).crown_ratio) for n in SPECIES}
    for narrow in ("spruce", "pine", "poplar"):
        for broad in ("oak", "willow", "almond"):
            assert ratio[narrow] < ratio[broad], (narrow, broad, ratio)


def test_willow_weeps() -> None:
    down = tip_directions(forest("willow", 8, trees=2))[:, 1] < 0
    assert down.mean() > 0.7
    up = tip_directions(forest("poplar", 8, trees=2))[:, 1] < 0
    assert up.mean() < 0.2


@pytest.mark.parametrize("name", sorted(SPECIES))
def test_foliage_on_the_last_orders_only(name: str) -> None:
    f = forest(name, 21)
    g, leaves = f.graph, f.grammar.leaves
    anchors = f.foliage_anchors()
    assert len(anchors) > 0
    assert leaves.max_radius is not None
    assert (g.scale[anchors.instance] <= leaves.max_radius).all()
    assert (g.piece[anchors.instance] != CAP).all()
    trunk = g.scale[g.parent < 0][g.tree[anchors.instance]]
    if name != "hazel":  # a shrub's leaves grow along its stems from 0.5 m up
        assert (g.scale[anchors.instance] <= trunk / 3).all(), "a spray on the trunk"
    # sprays are in metres at the species' size: their scale is a jitter about 1
    assert (anchors.size <= leaves.scale[1]).all() and np.median(anchors.size) > 0.8
    crown = f.grammar.crown
    if crown is not None and name != "willow":  # willow curtains hang to the ground
        fig = tree_figures(f)
        y = anchors.positions(f.palette())[:, 1]
        below = y < crown.base * fig.height[g.tree[anchors.instance]]
        assert below.mean() <= 0.02, below.mean()


def _grammar(**alt: object) -> dict[str, object]:
    base = {"piece": "T", "successors": [{"symbol": "A"}, {"symbol": "B", "radius": [0.4, 0.4]}]}
    return {
        "axiom": "A",
        "max_depth": 12,
        "rules": {"A": [{**base, **alt}], "B": [{"piece": "I", "successors": [None]}]},
    }


@settings(max_examples=5, deadline=None)
@given(seed=SEEDS, roll=st.sampled_from([137.5, 180.0, 90.0, 120.0]))
def test_roll_follows_the_divergence_within_half_a_twist(seed: int, roll: float) -> None:
    f = generate_forest(parse_grammar(_grammar(roll=roll)), seed, ForestOptions())
    g = f.graph
    axis = np.flatnonzero((g.order == 0) & (g.piece == PIECE_NAMES.index("T")))
    turned = 60.0 * np.cumsum(g.twist[axis])  # the axis starts at roll 0
    want = roll * np.arange(1, len(axis) + 1)
    err = np.angle(np.exp(1j * np.deg2rad(turned - want)), deg=True)
    assert np.abs(err).max() <= 30.0 + 1e-9


def test_gravitropism_bends_toward_the_vertical() -> None:
    def tip_y(gravity: float) -> float:
        g = _grammar(branch_angle=[80, 80], tropism={"gravity": gravity})
        g["rules"]["B"] = [  # type: ignore[index]
            {"piece": "I", "successors": [{"symbol": "B"}], "tropism": {"gravity": gravity}}
        ]
        f = generate_forest(parse_grammar(g), 1, ForestOptions())
        return float(tip_directions(f)[:, 1].mean())

    assert tip_y(-0.4) < -0.5 < 0.5 < tip_y(0.4)


def test_branch_angle_sets_the_lateral_angle() -> None:
    for want in (20.0, 85.0):
        f = generate_forest(parse_grammar(_grammar(branch_angle=[want, want])), 3, ForestOptions())
        g, pal = f.graph, f.palette()
        lat = np.flatnonzero((g.parent >= 0) & (g.parent_rim == 1))
        child_axis = pal[f.bones.offset[lat], :3, 1]
        parent_axis = pal[f.bones.offset[g.parent[lat]], :3, 1]
        cos = np.einsum("ij,ij->i", child_axis, parent_axis) / (
            np.linalg.norm(child_axis, axis=1) * np.linalg.norm(parent_axis, axis=1)
        )
        np.testing.assert_allclose(np.degrees(np.arccos(cos)), want, atol=3.0)


def test_crown_prunes_below_its_base_and_stops_the_trunk_at_its_height() -> None:
    g = _grammar()
    g.update(crown={"shape": "cone", "base": 0.5, "height": [6, 6]}, trunk_radius=0.3)
    g["max_depth"] = 60
    f = generate_forest(parse_grammar(g), 2, ForestOptions())
    gr = f.graph
    first = np.flatnonzero((gr.order == 1) & (gr.parent >= 0) & (gr.order[gr.parent] == 0))
    # below the base the trunk is a clear bole of straight pieces: no branch, no stub
    assert (gr.height[first] >= 0.5 * 6.0).all()
    assert (gr.piece[first] != CAP).any()
    bole = (gr.order == 0) & (gr.height < 0.5 * 6.0 - 0.3 * 2)
    assert bole.any() and (gr.piece[bole] == PIECE_NAMES.index("I")).all()
    assert gr.height[gr.order == 0].max() <= 6.0


def test_grammar_limits_by_thickness_are_estimated() -> None:
    cg = compile_grammar(load_preset("oak"))
    pieces = np.bincount(forest("oak", 1, trees=4).graph.tree)
    assert 0.5 * pieces.mean() <= cg.expected_pieces <= 2.0 * pieces.mean()


def test_autumn_turns_the_leaves() -> None:
    def color(season: str) -> np.ndarray:
        options = ForestOptions(trees=2, season=season)  # type: ignore[arg-type]
        f = generate_forest(load_preset("oak"), 2, options)
        return f.foliage_anchors().color.mean(axis=0)

    summer, autumn = color("summer"), color("autumn")
    assert summer[1] > summer[0]  # green
    assert autumn[0] > autumn[2] and autumn[0] > summer[0]  # toward red and yellow


def test_sprays_turn_out_from_their_branch() -> None:
    f = forest("oak", 6, trees=1)
    a = f.foliage_anchors()
    pieces = f.pieces
    # each spray's branch: from its piece's hub towards the terminal its rest point lies on
    heading, level = [], []
    pal = f.palette()[a.bone]
    for i in range(len(a)):
        j = pieces[f.graph.piece[a.instance[i]]].joint_rest[:, :3, 3]
        d = pal[i, :3, :3] @ (a.rest[i] - j[HUB_JOINT])
        if np.linalg.norm(d) < 1e-9:
            d = pal[i, :3, :3] @ (j[HUB_JOINT + 1] - j[HUB_JOINT])
        heading.append(np.arctan2(d[0], d[2]))
        level.append(np.hypot(d[0], d[2]) > 0.5 * np.linalg.norm(d))
    off = np.abs(np.angle(np.exp(1j * (a.yaw - np.array(heading)))))[np.array(level)]
    step = 2 * np.pi / YAW_STEPS
    # ahead (the tip's sprays) or out to either side, never back along the branch
    assert off.max() <= np.radians(100) + step / 2 + 1e-9
    assert (off > np.radians(30)).mean() > 0.5 and (off < step).mean() > 0.05
    assert len(np.unique(a.yaw)) >= 4  # not all alike
