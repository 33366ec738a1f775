"""The species presets judged from their written USD alone (:mod:`forest.usd.figures`), against
the targets of the issue "foliage-twigs": leaf cards the size of the species' leaves, nothing
below the ground, thin twig tips, round crowns from above, the oak's crown base and its
triangle budget. One tree per species at seeds 3 and 11, written once per module as .usdc (the
default form: skinned, as a consumer opens it).

Every failure message carries the table of the species' measured figures. A target not met
yet is a strict expected failure naming the gap (the issue's acceptance, not a guard to
loosen): today only the spruce's needle size.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from species_ranges import LEAF_CARD_M, SPECIES

from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.figures import SceneFigures, TreeFigures, figures_table, scene_figures
from forest.usd.scene import write_scene

SEEDS = (3, 11)
CASES = [(name, seed) for name in sorted(SPECIES) for seed in SEEDS]
GROUND_TOLERANCE_M = 0.001
# the largest twig tip: SPECIES.md, twigs end at 0.5-1 cm whatever the tree's size. Max over the
# tips: a tip is a Cap closing a branch, whose root rim is the branch's end (not the cap's
# tapered point), so the largest one is a branch end a viewer sees as thick
TWIG_TIP_MAX_M = 0.01
# crowns seen from above: minor over major 5-95 % extent. Every broadleaf, poplar too: a
# Lombardy poplar is a column, tall and narrow from the side but round in plan
ROUND_CROWNS = ("oak", "birch", "hazel", "almond", "willow", "poplar")
CROWN_ROUND_MIN = 0.75
OAK_CROWN_BASE = (0.20, 0.35)
OAK_TRIANGLES_MAX = 300_000  # a mature oak at full detail, bark and leaves

pytestmark = pytest.mark.slow  # 16 trees written and measured: a minute or two


@pytest.fixture(scope="module")
def figures(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, int], SceneFigures]:
    """Every (species, seed) tree written and measured once (16 trees), in one dict."""
    folder = tmp_path_factory.mktemp("species_usd")
    out = {}
    for name, seed in CASES:
        forest = generate_forest(load_preset(name), seed, ForestOptions(trees=1))
        path = write_scene(forest, Path(folder) / f"{name}_{seed}.usdc")
        del forest
        out[name, seed] = scene_figures(path)
        path.unlink()  # a mature oak's scene is 50 MB
    return out


def tree(figures: dict[tuple[str, int], SceneFigures], name: str, seed: int) -> TreeFigures:
    (t,) = figures[name, seed].trees
    return t


def table(figures: dict[tuple[str, int], SceneFigures], name: str) -> str:
    """The species' trees (both seeds) as a table, for a failure's message."""
    rows = [tree(figures, name, s) for s in SEEDS]
    return "\n" + figures_table(rows, [f"{name} {s}" for s in SEEDS], "tree")


def test_every_tree_measured(figures: dict[tuple[str, int], SceneFigures]) -> None:
    """The judge reads what it should: one skinned tree per scene, bark, leaves and tips."""
    for (name, seed), fig in figures.items():
        assert fig.representation == "skinned", (name, seed)
        (t,) = fig.trees
        assert t.height > 1 and t.cards > 0 and t.tips > 0, table(figures, name)
        assert t.bark_triangles > 0 and t.leaf_triangles == 2 * t.cards, table(figures, name)


# Targets not met yet, each an expected failure (strict: it fails the run once it passes, so
# the mark goes with the gap). A spruce card is a sprig 25-45 cm long (SPRIG_RATIO times its
# width) whose picture draws its needles at 1.5-2.5 cm (tests/test_foliage.py checks the
# picture against the cards): cards of one needle would need ~30x the triangles (a 30 m
# spruce's crown shell is ~480 m2; 2.5 cm cards cover it with ~770 k of them), so the card
# measure misses; the needles are at their size (issue foliage-twigs, open).
SPRUCE_SPRIGS = pytest.mark.xfail(
    strict=True,
    reason="spruce cards are needle sprigs 25-45 cm long; their needles are drawn at 1.5-2.5 cm",
)
LEAF_CASES = [
    pytest.param(name, seed, marks=SPRUCE_SPRIGS) if name == "spruce" else (name, seed)
    for name, seed in CASES
]


@pytest.mark.parametrize(("name", "seed"), LEAF_CASES)
def test_leaf_cards_are_the_species_leaf(
    figures: dict[tuple[str, int], SceneFigures], name: str, seed: int
) -> None:
    lo, hi = LEAF_CARD_M[name]
    t = tree(figures, name, seed)
    assert lo <= t.card_length <= hi, (
        f"{name} seed {seed}: median leaf card {100 * t.card_length:.1f} cm, "
        f"SPECIES.md {100 * lo:g}-{100 * hi:g} cm" + table(figures, name)
    )


@pytest.mark.parametrize(("name", "seed"), CASES)
def test_nothing_below_the_ground(
    figures: dict[tuple[str, int], SceneFigures], name: str, seed: int
) -> None:
    t = tree(figures, name, seed)
    low = min(t.bark_low, t.leaf_low)
    assert low >= -GROUND_TOLERANCE_M, (
        f"{name} seed {seed}: lowest bark vertex y {t.bark_low:.3f} m, lowest leaf vertex y "
        f"{t.leaf_low:.3f} m, below the ground (y = 0)" + table(figures, name)
    )


@pytest.mark.parametrize(("name", "seed"), CASES)
def test_twigs_end_thin(figures: dict[tuple[str, int], SceneFigures], name: str, seed: int) -> None:
    t = tree(figures, name, seed)
    assert t.tip_diameter_max <= TWIG_TIP_MAX_M, (
        f"{name} seed {seed}: twig tips {100 * t.tip_diameter_median:.2f} cm median, "
        f"{100 * t.tip_diameter_max:.2f} cm max; SPECIES.md 0.5-1 cm" + table(figures, name)
    )


@pytest.mark.parametrize(("name", "seed"), [c for c in CASES if c[0] in ROUND_CROWNS])
def test_broadleaf_crowns_round_from_above(
    figures: dict[tuple[str, int], SceneFigures], name: str, seed: int
) -> None:
    t = tree(figures, name, seed)
    assert t.crown_narrow_wide >= CROWN_ROUND_MIN, (
        f"{name} seed {seed}: crown from above {t.crown_narrow_wide:.2f} narrow/wide, "
        f"want >= {CROWN_ROUND_MIN}" + table(figures, name)
    )


@pytest.mark.parametrize("seed", SEEDS)
def test_oak_crown_base(figures: dict[tuple[str, int], SceneFigures], seed: int) -> None:
    t = tree(figures, "oak", seed)
    lo, hi = OAK_CROWN_BASE
    assert lo <= t.crown_base <= hi, (
        f"oak seed {seed}: crown base at {t.crown_base:.2f} of the height, want {lo}-{hi}"
        + table(figures, "oak")
    )


@pytest.mark.parametrize("seed", SEEDS)
def test_mature_oak_triangle_budget(
    figures: dict[tuple[str, int], SceneFigures], seed: int
) -> None:
    t = tree(figures, "oak", seed)
    assert t.triangles < OAK_TRIANGLES_MAX, (
        f"oak seed {seed}: {t.triangles:,} triangles ({t.bark_triangles:,} bark, "
        f"{t.leaf_triangles:,} leaves), want < {OAK_TRIANGLES_MAX:,}" + table(figures, "oak")
    )
