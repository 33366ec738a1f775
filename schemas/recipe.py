"""Forest recipe: the species layers of a mixed stand and the ground they stand on (issue
"mixed-forests"). JSON Schema: ``schemas/json/recipe.schema.json``.

A recipe says *what* grows where; the forest's seed, tree count and area come from the request
(or the CLI) as for a single-species forest. Checks that need the library (a preset that
exists, a density map that reads, the caps) live in ``forest.stand``; this module holds shape
and ranges only.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from schemas.base import FieldValueError, StrictModel
from schemas.grammar import Grammar, _ordered

LayerName = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]{0,31}$")]
Unit = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
Metres = Annotated[float, Field(ge=-1e4, le=1e4, allow_inf_nan=False)]
# a density map or a heightfield: a file path (CLI, relative to the recipe's folder) or, from
# the API, a data: URI of the image's bytes; never a server path
ImageRef = Annotated[str, Field(min_length=1, max_length=48_000_000)]
MAX_LAYERS = 8
RECIPE_NAME_PATTERN = r"^[a-z][a-z0-9_-]{0,63}$"
SIZE_MIN, SIZE_MAX = 0.15, 1.25


class SizeDistribution(StrictModel):
    """Each tree's size relative to the species' mature tree (1): its trunk's radius and its
    height scale by it, and a young tree grows fewer branch orders (twigs end at the same
    thickness), so it is a smaller version of the species, not a scaled copy. Exactly one of
    ``range`` (uniform) or ``normal`` (mean, standard deviation); drawn sizes are clipped to
    [0.15, 1.25]."""

    range: (
        tuple[
            Annotated[float, Field(ge=SIZE_MIN, le=SIZE_MAX)],
            Annotated[float, Field(ge=SIZE_MIN, le=SIZE_MAX)],
        ]
        | None
    ) = None
    normal: (
        tuple[
            Annotated[float, Field(ge=SIZE_MIN, le=SIZE_MAX)], Annotated[float, Field(ge=0, le=1)]
        ]
        | None
    ) = None

    @model_validator(mode="after")
    def _one(self) -> SizeDistribution:
        if (self.range is None) == (self.normal is None):
            raise ValueError("give exactly one of range or normal")
        if self.range is not None:
            _ordered(self.range, "range")
        return self


class RecipeLayer(StrictModel):
    """One species of the stand: what it is, how many, how big, and where it may stand."""

    name: LayerName
    """The layer's name: its scene file (``<OUT>_layers/<name>.usdc``) and its prim."""
    preset: Annotated[str, Field(min_length=1, max_length=64)] | None = None
    """A shipped grammar (``forest presets``); or give ``grammar``."""
    grammar: Grammar | None = None
    role: Literal["canopy", "understorey", "edge"] = "canopy"
    """``canopy`` layers are placed first; ``understorey`` trees stand where the canopy leaves
    light (``light``); ``edge`` trees near the area's border (``edge_width``)."""
    share: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] | None = None
    """Fraction of the forest's trees (the shares of a recipe sum to 1); or give ``density``."""
    density: Annotated[float, Field(gt=0, le=20_000, allow_inf_nan=False)] | None = None
    """Trees per hectare of the area (the forest's tree count is then their sum)."""
    size: SizeDistribution = SizeDistribution(range=(0.85, 1.0))
    spacing: Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)] | None = None
    """Least distance in metres from this layer's trunks to any other (at size 1; a smaller
    tree keeps a proportionally smaller one, at least 0.5 m). Default: the species' crown
    radius in a closed stand."""
    density_map: ImageRef | None = None
    """A greyscale image over the whole area (top row at -z, left column at -x): the chance
    that a tree stands there, 0 = no trees (a clearing, a path)."""
    altitude: tuple[Metres, Metres] | None = None
    """Terrain heights (metres) the layer grows between."""
    slope: (
        tuple[Annotated[float, Field(ge=0, le=90)], Annotated[float, Field(ge=0, le=90)]] | None
    ) = None
    """Terrain slopes (degrees) the layer grows on."""
    light: Unit | None = None
    """Least light (0 = under dense canopy, 1 = open sky) where a tree of the layer may
    stand; understorey layers default to 0.35. The chance of a tree also follows the light."""
    edge_width: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] = 12.0
    """Edge layers: metres from the border within which they are most likely."""
    rows: Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)] | None = None
    """Plant in rows this many metres apart along x (an orchard); ``spacing`` is then the
    distance along a row."""

    @model_validator(mode="after")
    def _checks(self) -> RecipeLayer:
        if (self.preset is None) == (self.grammar is None):
            raise FieldValueError("preset", "give exactly one of preset or grammar")
        if (self.share is None) == (self.density is None):
            raise FieldValueError("share", "give exactly one of share or density")
        for name in ("altitude", "slope"):
            lo_hi = getattr(self, name)
            if lo_hi is not None:
                _ordered(lo_hi, name)
        return self

    @property
    def species(self) -> str:
        """The preset's name, or the inline grammar's."""
        return self.preset if self.preset is not None else self.grammar.name if self.grammar else ""


class Terrain(StrictModel):
    """The ground under the forest, over the forest's whole area: a heightfield image
    (``image``: 8- or 16-bit greyscale PNG, TIFF or any format OpenImageIO reads; black is
    ``heights[0]``, white ``heights[1]``) or, without one, a procedural one from ``seed``
    with hills of ``relief`` metres."""

    image: ImageRef | None = None
    heights: tuple[Metres, Metres] = (0.0, 20.0)
    seed: Annotated[int, Field(ge=0, le=2**63 - 1)] = 0
    relief: Annotated[float, Field(ge=0, le=1000, allow_inf_nan=False)] = 8.0
    """Procedural terrain: the height between its lowest and highest points, metres."""
    feature: Annotated[float, Field(gt=0, le=1e5, allow_inf_nan=False)] = 60.0
    """Procedural terrain: the width of its largest hills, metres."""
    extent: (
        tuple[
            Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)],
            Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)],
        ]
        | None
    ) = None
    """Metres along x and z the terrain spans, centred on the forest's middle (the image's
    real size); the forest's area must fit in it. Default: the forest's area."""

    @model_validator(mode="after")
    def _range(self) -> Terrain:
        _ordered(self.heights, "heights")
        return self


class Recipe(StrictModel):
    """A forest recipe: a mixed stand of up to 8 species layers, optionally on terrain."""

    name: Annotated[str, Field(pattern=RECIPE_NAME_PATTERN)] = "custom"
    description: Annotated[str, Field(max_length=2000)] = ""
    layers: Annotated[list[RecipeLayer], Field(min_length=1, max_length=MAX_LAYERS)]
    terrain: Terrain | None = None

    @model_validator(mode="after")
    def _layers(self) -> Recipe:
        names = [layer.name for layer in self.layers]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise FieldValueError(f"layers.{i}.name", f"{n!r} is used twice")
        shares = [layer.share is not None for layer in self.layers]
        if any(shares) and not all(shares):
            raise FieldValueError("layers", "give every layer a share, or every layer a density")
        if all(shares):
            total = sum(layer.share or 0.0 for layer in self.layers)
            if abs(total - 1.0) > 1e-6:
                raise FieldValueError("layers", f"the shares sum to {total:g}, not 1")
        return self

    @property
    def by_density(self) -> bool:
        """True when the layers give densities (trees per hectare), not shares."""
        return self.layers[0].density is not None


class RecipeSummary(StrictModel):
    """A built-in recipe as ``GET /v1/recipes`` and ``forest recipes`` list it."""

    name: str
    description: str
    layers: list[str]
    """Each layer as ``<name>: <preset> (<role>)``."""


class RecipeList(StrictModel):
    recipes: list[RecipeSummary]
