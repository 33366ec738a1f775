"""Tree grammar: stochastic rules that expand symbols into pieces (paper 4.2; issue 2).

A symbol expands into one of its weighted alternatives. An alternative names a piece and,
for each of the piece's leaf rims in order, a successor (a symbol with scale ranges) or
``null`` for an open tip. Cross-field checks that need the piece library (rim counts, unknown
symbols, termination) live in ``forest.growth.compile``; this module holds shape and ranges only.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from schemas.base import StrictModel

MAX_DEPTH_BOUND = 65_536
"""Upper bound of an alternative's ``min_depth``/``max_depth`` (no tree grows that deep)."""

PieceName = Literal["I", "Y", "T", "Psi", "Cap", "Flare"]
Symbol = Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]{0,63}$")]


def _ordered(lo_hi: tuple[float, float], name: str) -> None:
    if lo_hi[0] > lo_hi[1]:
        raise ValueError(f"{name} range [{lo_hi[0]}, {lo_hi[1]}] has low > high")


class Successor(StrictModel):
    """What grows at one leaf rim."""

    symbol: Symbol
    length: tuple[Annotated[float, Field(gt=0, le=4)], Annotated[float, Field(gt=0, le=4)]] = (
        1.0,
        1.0,
    )
    """Range of the child's length scale (stretches the child piece along its bones)."""
    radius: tuple[Annotated[float, Field(gt=0, le=2)], Annotated[float, Field(gt=0, le=2)]] = (
        1.0,
        1.0,
    )
    """Range of the uniform scale at this rim's terminal joint: scales the rim and the whole
    subtree, so forks can be asymmetric (paper 4.1)."""

    @model_validator(mode="after")
    def _ranges(self) -> Successor:
        _ordered(self.length, "length")
        _ordered(self.radius, "radius")
        return self


Degrees = Annotated[float, Field(ge=0, le=90)]


class Pose(StrictModel):
    """Joint rotation ranges in degrees, drawn per piece instance about random horizontal
    axes, so equal topologies look different (paper 4.3)."""

    bend: tuple[Degrees, Degrees] = (0.0, 0.0)
    """Rotation of the hub joint: bends everything above the piece's hub."""
    spread: tuple[Degrees, Degrees] = (0.0, 0.0)
    """Rotation of each terminal joint: turns each leaf rim and its subtree."""

    @model_validator(mode="after")
    def _ranges(self) -> Pose:
        _ordered(self.bend, "bend")
        _ordered(self.spread, "spread")
        return self


class Tropism(StrictModel):
    """Bends toward a direction, applied at each piece's hub from the piece's orientation in
    the (posed) tree: per piece, this fraction of the angle to the direction is closed."""

    gravity: Annotated[float, Field(ge=-1, le=1, allow_inf_nan=False)] = 0.0
    """Toward the vertical: positive bends up (leaders, poplar), negative down (weeping)."""
    light: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = 0.0
    """Toward the light: outward from the trunk and 45 degrees up."""


class Alternative(StrictModel):
    piece: PieceName
    # bounded so the cumulative weights of any rule stay far from float overflow
    # and from denormals: a weight of 5e-324 sums to a cumulative table that never reaches 1
    weight: Annotated[float, Field(ge=1e-6, le=1e9, allow_inf_nan=False)] = 1.0
    successors: list[Successor | None]
    """One entry per leaf rim of ``piece`` (I: 1, Y: 2, T: 2, Psi: 3)."""
    twist: Literal["random"] | Annotated[int, Field(ge=0, le=5)] = "random"
    """Which of the six 60-degree twists lays this piece onto its parent's rim."""
    pose: Pose = Pose()
    roll: Annotated[float, Field(ge=-360, le=360, allow_inf_nan=False)] | None = None
    """Phyllotaxis: divergence in degrees between this piece's laterals and the previous
    piece's along the same axis (137.5 spiral, 180 alternate/distichous, 120 for whorls of
    three...). Rolls are kept exactly along the axis and laid onto the six rim twists with
    the rounding error carried forward. Overrides ``twist``."""
    branch_angle: tuple[Degrees, Degrees] | None = None
    """Range of the angle in degrees between each lateral rim's axis and the stem (Y: each
    branch's angle from the fork's axis); the piece's built-in angle otherwise."""
    tropism: Tropism = Tropism()
    taper: tuple[
        Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)],
        Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)],
    ] = (1.0, 1.0)
    """Range of the radius where the children leave over the piece's own root radius: the
    branch narrows along its axis; the pipe model splits what is left."""
    # bounded: depths are compared as int32 arrays (2^31 overflowed)
    min_depth: Annotated[int, Field(ge=0, le=MAX_DEPTH_BOUND)] = 0
    max_depth: Annotated[int, Field(ge=0, le=MAX_DEPTH_BOUND)] | None = None
    """Depth condition: the alternative applies when min_depth <= depth <= max_depth."""
    min_radius: Annotated[float, Field(ge=0, le=100, allow_inf_nan=False)] = 0.0
    max_radius: Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)] | None = None
    """Thickness condition, metres: the alternative applies to a piece whose root rim's
    radius (at rest, the tree's scale included) r has min_radius <= r < max_radius. Twigs
    are grown by thickness, not depth: e.g. a non-forking, strongly tapering last order
    below some radius. A symbol with no alternative for its radius ends there (a tip)."""

    @model_validator(mode="after")
    def _depths(self) -> Alternative:
        _ordered(self.taper, "taper")
        if self.max_depth is not None and self.max_depth < self.min_depth:
            raise ValueError(f"max_depth {self.max_depth} < min_depth {self.min_depth}")
        if self.max_radius is not None and self.max_radius <= self.min_radius:
            raise ValueError(f"max_radius {self.max_radius} <= min_radius {self.min_radius}")
        return self


Hex = Annotated[str, Field(pattern=r"^#[0-9a-fA-F]{6}$")]


LeafFamily = Literal[
    "broadleaf", "needles", "strands",
    "oak", "birch", "hazel", "willow", "almond", "poplar", "pine", "spruce",
]  # fmt: skip
Metres = Annotated[float, Field(gt=0, le=2, allow_inf_nan=False)]


class Leaves(StrictModel):
    """Foliage of a species: leaf sprays (shoots of the last order carrying leaf cards at the
    species' real size), where they grow, in which colours."""

    family: LeafFamily = "broadleaf"
    """The species' sprays and leaf picture: ``oak`` (lobed, crowded at shoot ends), ``birch``
    (small triangular leaves on long stalks, hanging shoots), ``hazel`` (round, toothed, two
    ranks), ``willow`` (narrow leaves on long hanging shoots), ``almond`` (narrow, toothed),
    ``poplar`` (triangular, long stalks), ``pine`` (tufts of needle pairs at shoot ends),
    ``spruce`` (short needles all round branchlets); the older ``broadleaf`` (ovate),
    ``needles`` (spruce-like) and ``strands`` (hanging narrow leaves)."""
    length: tuple[Metres, Metres] | None = None
    """Range of a leaf card's length in metres, stalk included (the family's own without:
    e.g. oak 0.08-0.14, birch 0.05-0.08, spruce needles 0.012-0.022)."""
    phyllotaxis: Literal["spiral", "alternate", "opposite", "whorled"] | None = None
    """How leaves sit along a shoot: ``spiral`` (137.5 degrees apart), ``alternate`` (two
    ranks, 180), ``opposite`` (decussate pairs), ``whorled`` (threes); the family's own
    without."""
    sprays: tuple[Annotated[int, Field(ge=0, le=32)], Annotated[int, Field(ge=0, le=32)]] = (2, 4)
    """Range of the number of sprays on each foliage-bearing piece, along its axis from the
    hub to a terminal, denser towards the terminal."""
    scale: tuple[
        Annotated[float, Field(gt=0, le=4, allow_inf_nan=False)],
        Annotated[float, Field(gt=0, le=4, allow_inf_nan=False)],
    ] = (0.85, 1.15)
    """Range of each spray's scale (the sprays are in metres: a jitter about 1)."""
    size: Annotated[float, Field(gt=0, le=50, allow_inf_nan=False)] | None = None
    """No longer used (leaf clouds were this many branch radii across; sprays are at real
    size now): accepted so older grammars load."""
    max_radius: Annotated[float, Field(gt=0, le=10, allow_inf_nan=False)] | None = None
    """Metres: no spray on a piece whose root rim is thicker (trunks and main limbs)."""
    min_height: Annotated[float, Field(ge=0, le=100, allow_inf_nan=False)] = 0.0
    """Metres above the tree's foot below which no spray grows."""
    shell: Annotated[float, Field(ge=0, lt=1, allow_inf_nan=False)] = 0.0
    """Leaves live in the crown's outer shell: no spray nearer the crown's centre than this
    fraction of the way to its outer surface (0: anywhere)."""
    max_triangles: Annotated[int, Field(ge=0, le=10_000_000)] | None = None
    """Most leaf triangles per tree: beyond it the innermost sprays go."""
    colors: Annotated[list[Hex], Field(min_length=1, max_length=8)] = ["#38691f"]
    """sRGB palette: each tree draws a base colour from it, each spray varies around it."""
    autumn_colors: Annotated[list[Hex], Field(max_length=8)] = []
    """The palette with ``season: autumn`` (none: the summer palette)."""

    @model_validator(mode="after")
    def _ranges(self) -> Leaves:
        if self.length is not None:
            _ordered(self.length, "length")
        _ordered(self.sprays, "sprays")
        _ordered(self.scale, "scale")
        return self


class Crown(StrictModel):
    """Crown envelope and apical control (after Weber and Penn's shape ratios)."""

    shape: Literal["cone", "ellipsoid", "column", "dome", "vase", "umbrella"] = "ellipsoid"
    """Scales the length of each first-order branch by where it leaves the trunk."""
    base: Annotated[float, Field(ge=0, lt=1)] = 0.0
    """Fraction of the tree's height below which no branch grows (a bare trunk) and no
    leaf cloud sits."""
    height: tuple[Annotated[float, Field(gt=0, le=150)], Annotated[float, Field(gt=0, le=150)]] = (
        10.0,
        10.0,
    )
    """Range of each tree's height in metres: the trunk's axis stops growing there."""

    @model_validator(mode="after")
    def _range(self) -> Crown:
        _ordered(self.height, "height")
        return self


class Grammar(StrictModel):
    """A tree grammar. JSON Schema: ``schemas/json/grammar.schema.json``."""

    name: Annotated[str, Field(min_length=1, max_length=64)] = "custom"
    description: Annotated[str, Field(max_length=2000)] = ""
    axiom: Symbol
    rules: Annotated[
        dict[Symbol, Annotated[list[Alternative], Field(min_length=1)]], Field(min_length=1)
    ]
    axiom_length: Annotated[float, Field(gt=0, le=4, allow_inf_nan=False)] = 1.0
    """Length scale of each tree's root piece (a successor's ``length`` for the axiom): short
    for a shrub's stool, whose stems leave near the ground."""
    max_depth: Annotated[int, Field(ge=0, le=64)] | None = None
    """Pieces deeper than this are not grown (their rims stay open tips). Without it the rules
    must terminate on their own."""
    foliage: list[Symbol] = []
    """Symbols whose pieces bear leaf clouds."""
    leaves: Leaves = Leaves()
    crown: Crown | None = None
    pipe_exponent: Annotated[float, Field(ge=2, le=3)] | None = None
    """Pipe model: at a fork, ``r_parent^e = sum(r_child^e)``. The successors' ``radius``
    ranges of a fork are then relative weights (the split ratio), normalised to that rule."""
    twig_radius: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] | None = None
    """Metres: a rim thinner than this grows no successor; the branch ends there."""
    ground_clearance: Annotated[float, Field(ge=0, le=10, allow_inf_nan=False)] = 0.0
    """Metres: no branch bends down below this height (posed, without wind): a piece that
    heads down (its hub or a leaf rim lower than its root) and gets lower ends its branch in
    a cap there, so weeping shoots stop above the ground, never through it. Pieces rising
    from lower down (a trunk, a shrub's stems) are not cut."""
    close_tips: bool = True
    """End every open rim with a tapered cap piece."""
    bark: Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]{0,31}$")] = "default"
    """The shipped bark tile set (``forest/bark/tilesets/<name>``) the scene uses."""
    trunk_radius: Annotated[float, Field(gt=0, le=100)] = 0.15
    """Root-rim circumradius of a tree in metres (the tree's base scale)."""
    tree_scale: tuple[
        Annotated[float, Field(gt=0, le=10)], Annotated[float, Field(gt=0, le=10)]
    ] = (
        0.85,
        1.15,
    )
    """Range of each tree's random uniform scale on top of ``trunk_radius``."""

    @model_validator(mode="after")
    def _scale(self) -> Grammar:
        _ordered(self.tree_scale, "tree_scale")
        return self
