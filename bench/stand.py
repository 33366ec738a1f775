"""``forest bench generate --recipe``: a mixed forest's placement (ground, density maps, dart
throwing with spacing and light) and growth, layer by layer, beside a single-species forest of
the same number of trees (the recipe's first layer's species, the hashed cell grid's
placement), run alternately in the same minutes; each side keeps its best time."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.stand.generate import plan_stand
from forest.stand.recipes import load_recipe

Echo = Callable[[str], None]
M2_PER_TREE = 40.0  # a stand's area when none is given: room for every built-in recipe


def run_stand_bench(
    recipe: str,
    trees: int,
    repeat: int,
    area: tuple[float, float] | None = None,
    echo: Echo = print,
) -> dict[str, float]:
    loaded = load_recipe(recipe)
    side = math.sqrt(trees * M2_PER_TREE)
    area = area or (side, side)
    species = loaded.recipe.layers[0].species
    single = (
        load_preset(species) if loaded.recipe.layers[0].preset else loaded.recipe.layers[0].grammar
    )
    assert single is not None
    options = ForestOptions(trees=trees, area=area)
    best = {"place": math.inf, "grow": math.inf, "single": math.inf}
    pieces = single_pieces = 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        stand = plan_stand(loaded, trees, area, 1)
        t_place = time.perf_counter() - t0
        t0 = time.perf_counter()
        pieces = 0
        for k in range(len(stand.recipe.layers)):
            forest = stand.grow_layer(k, ForestOptions())
            pieces += 0 if forest is None else forest.n_instances
            del forest
        t_grow = time.perf_counter() - t0
        t0 = time.perf_counter()
        forest = generate_forest(single, 1, options)
        single_pieces = forest.n_instances
        del forest
        t_single = time.perf_counter() - t0
        best = {
            "place": min(best["place"], t_place),
            "grow": min(best["grow"], t_grow),
            "single": min(best["single"], t_single),
        }
    total = best["place"] + best["grow"]
    share = best["place"] / best["grow"]
    echo(
        f"recipe {loaded.recipe.name}: {trees} trees over {area[0]:.0f} x {area[1]:.0f} m, "
        f"best of {repeat} alternating runs"
    )
    echo(f"{'':36}{'pieces':>10}{'seconds':>10}{'trees/s':>10}{'pieces/s':>12}")
    echo(
        f"{'recipe: placement':36}{'':>10}{best['place']:>10.3f}"
        f"{trees / best['place']:>10,.0f}{'':>12}"
    )
    echo(
        f"{'recipe: growth (layer by layer)':36}{pieces:>10}{best['grow']:>10.3f}"
        f"{trees / best['grow']:>10,.0f}{pieces / best['grow']:>12,.0f}"
    )
    echo(
        f"{'recipe: total':36}{pieces:>10}{total:>10.3f}{trees / total:>10,.0f}"
        f"{pieces / total:>12,.0f}"
    )
    echo(
        f"{f'single species ({species}), same trees':36}{single_pieces:>10}"
        f"{best['single']:>10.3f}{trees / best['single']:>10,.0f}"
        f"{single_pieces / best['single']:>12,.0f}"
    )
    echo(f"placement costs {100 * share:.1f} % of the growth   (target < 10 %)")
    return {
        "trees": trees,
        "place_s": best["place"],
        "grow_s": best["grow"],
        "pieces": pieces,
        "single_s": best["single"],
        "single_pieces": single_pieces,
        "placement_share": share,
    }
