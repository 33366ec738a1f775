"""A mixed stand from a recipe: its ground and placement once, then each layer (a species) as
a forest of its own on the trees placed for it, one at a time, so memory follows the largest
layer (or, tiled, the largest layer of a tile), not the stand.

Each layer's trees are keyed on the seed and their global ids like any forest's
(:mod:`forest.growth.keyed`), so a layer's tree is the same whether a tile or the whole stand
grows it; a layer's bark tiles and leaf clouds draw from ``SeedSequence([seed, layer])`` (and
the tile's index when tiled).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from forest.caps import layer_estimates
from forest.errors import ForestError
from forest.growth.compile import compile_grammar
from forest.growth.generate import Forest, ForestOptions, Progress, generate_forest
from forest.growth.grammar import CompiledGrammar
from forest.growth.presets import load_preset
from forest.growth.scatter import PlacedTrees, placed
from forest.settings import ForestSettings, get_settings
from forest.stand.place import F64, LayerTrees, Placement, place_stand
from forest.stand.recipes import LoadedRecipe
from forest.stand.terrain import Heightfield, heightfield, image_bytes
from schemas.grammar import Grammar
from schemas.recipe import Recipe


@dataclass(frozen=True, eq=False)
class Stand:
    """A recipe placed over an area: what each layer grows, the ground, every tree's place."""

    recipe: Recipe
    grammars: tuple[Grammar, ...]
    ground: Heightfield
    placement: Placement
    area: tuple[float, float]
    seed: int
    _estimates: dict[ForestSettings, tuple[CompiledGrammar, ...]] = field(
        default_factory=dict, repr=False
    )

    def estimates(self, settings: ForestSettings | None = None) -> tuple[CompiledGrammar, ...]:
        """Each layer's compiled grammar with its expected counts at its trees' sizes
        (:func:`forest.caps.layer_estimates`), made once per settings: every cap of a layer
        (or a layer's tile) is checked on these before it grows, not on a mature tree's
        counts, which refused young layers many times under their caps."""
        s = settings or get_settings()
        if s not in self._estimates:
            compiled = [compile_grammar(g, s) for g in self.grammars]
            self._estimates[s] = tuple(layer_estimates(self.recipe, compiled, s))
        return self._estimates[s]

    @property
    def trees(self) -> int:
        return self.placement.trees

    def layer_seed(self, k: int, tile: tuple[int, int] | None = None) -> int:
        """Layer ``k``'s own seed (of its bark tiles and leaf clouds), per tile when tiled."""
        key = [self.seed, k] if tile is None else [self.seed, k, *tile]
        state = np.random.SeedSequence(key).generate_state(2, np.uint64)
        return int(state[0] >> np.uint64(1))

    def grow_layer(
        self,
        k: int,
        options: ForestOptions,
        trees: LayerTrees | None = None,
        tile: tuple[int, int] | None = None,
        settings: ForestSettings | None = None,
        progress: Progress | None = None,
    ) -> Forest | None:
        """Layer ``k`` (its trees, or the given subset of them: a tile's) as a forest; None
        when it has no tree there."""
        t = self.placement.layers[k] if trees is None else trees
        if len(t) == 0:
            return None
        g = self.grammars[k]
        settings = settings or get_settings()
        layer_options = replace(options, trees=len(t), area=self.area)
        with placed(PlacedTrees(t.ids, t.transforms(g.trunk_radius), self.seed, t.sizes)):
            return generate_forest(
                g,
                self.layer_seed(k, tile),
                layer_options,
                None,
                settings,
                progress,
                compiled=self.estimates(settings)[k],
            )


def layer_grammars(recipe: Recipe) -> tuple[Grammar, ...]:
    out = []
    for k, layer in enumerate(recipe.layers):
        if layer.grammar is not None:
            out.append(layer.grammar)
            continue
        try:
            out.append(load_preset(layer.preset or ""))
        except ForestError as exc:
            raise ForestError(exc.message, path=f"recipe.layers.{k}.preset") from None
    return tuple(out)


def plan_stand(
    loaded: LoadedRecipe,
    trees: int,
    area: tuple[float, float],
    seed: int,
) -> Stand:
    """Read the recipe's images, make its ground and place every tree (no growth yet)."""
    from forest.bark.images import read_grey

    recipe = loaded.recipe
    grammars = layer_grammars(recipe)
    maps: list[F64 | None] = []
    read: dict[str, F64] = {}  # layers often share one map: read (and held) once
    for k, layer in enumerate(recipe.layers):
        if layer.density_map is None:
            maps.append(None)
            continue
        if layer.density_map not in read:
            field = f"recipe.layers.{k}.density_map"
            grey = read_grey(image_bytes(layer.density_map, loaded.folder, field), field)
            read[layer.density_map] = grey.astype(np.float64)
        maps.append(read[layer.density_map])
    ground = heightfield(recipe.terrain, area, loaded.folder)
    placement = place_stand(recipe, list(grammars), trees, area, seed, ground, maps)
    return Stand(recipe, grammars, ground, placement, area, seed)
