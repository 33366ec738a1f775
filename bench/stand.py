"""``forest bench generate --recipe``: a mixed forest's placement (ground, density maps, dart
throwing with spacing and light) and growth, layer by layer, beside a single-species forest of
the same number of trees (the recipe's first layer's species, the hashed cell grid's
placement) and beside the same layers each grown as a forest of its own on the hashed cell
grid, run alternately in the same minutes; each keeps its best time."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from forest.growth.compile import compile_grammar
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.settings import get_settings
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
    layers = loaded.recipe.layers
    first = layers[0]
    single = load_preset(first.preset) if first.preset else first.grammar
    assert single is not None
    settings = get_settings()
    single_ok = compile_grammar(single).expected_pieces * trees <= settings.max_pieces_per_forest
    best = {"place": math.inf, "grow": math.inf, "plain": math.inf, "single": math.inf}
    pieces = plain_pieces = single_pieces = 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        stand = plan_stand(loaded, trees, area, 1)
        t_place = time.perf_counter() - t0
        t0 = time.perf_counter()
        pieces = 0
        for k in range(len(layers)):
            forest = stand.grow_layer(k, ForestOptions())
            pieces += 0 if forest is None else forest.n_instances
            del forest
        t_grow = time.perf_counter() - t0
        # the same layers, each a forest of its own on the hashed cell grid
        t0 = time.perf_counter()
        plain_pieces = 0
        for k, t in enumerate(stand.placement.layers):
            if len(t):
                forest = generate_forest(
                    stand.grammars[k], 1, ForestOptions(trees=len(t), area=area)
                )
                plain_pieces += forest.n_instances
                del forest
        t_plain = time.perf_counter() - t0
        t_single = math.inf
        if single_ok:
            t0 = time.perf_counter()
            forest = generate_forest(single, 1, ForestOptions(trees=trees, area=area))
            single_pieces = forest.n_instances
            del forest
            t_single = time.perf_counter() - t0
        for key, v in (
            ("place", t_place),
            ("grow", t_grow),
            ("plain", t_plain),
            ("single", t_single),
        ):
            best[key] = min(best[key], v)
    total = best["place"] + best["grow"]
    share = best["place"] / total
    rate, plain_rate = pieces / total, plain_pieces / best["plain"]
    echo(
        f"recipe {loaded.recipe.name}: {trees} trees over {area[0]:.0f} x {area[1]:.0f} m, "
        f"best of {repeat} alternating runs"
    )
    echo(f"{'':40}{'pieces':>10}{'seconds':>10}{'trees/s':>10}{'pieces/s':>12}")

    def row(name: str, n: int, t: float) -> None:
        p = f"{n / t:>12,.0f}" if n else f"{'':>12}"
        echo(f"{name:40}{(n or ''):>10}{t:>10.3f}{trees / t:>10,.0f}{p}")

    row("recipe: placement", 0, best["place"])
    row("recipe: growth (layer by layer)", pieces, best["grow"])
    row("recipe: total", pieces, total)
    row("same layers, hashed-grid placement", plain_pieces, best["plain"])
    if single_ok:
        row(f"single species ({first.species}), same trees", single_pieces, best["single"])
    else:
        echo(f"single species ({first.species}): {trees} trees are over the piece cap")
    echo(
        f"placement: {100 * share:.1f} % of the recipe's time; recipe pieces/s "
        f"{rate / plain_rate:.2f}x the same layers' on the hashed grid   (target: placement "
        "< 10 % extra)"
    )
    return {
        "trees": trees,
        "place_s": best["place"],
        "grow_s": best["grow"],
        "pieces": pieces,
        "plain_s": best["plain"],
        "plain_pieces": plain_pieces,
        "single_s": best["single"],
        "single_pieces": single_pieces,
        "placement_share": share,
        "rate_ratio": rate / plain_rate,
    }
