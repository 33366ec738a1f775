"""Tree grammar: stochastic rules that expand symbols into pieces (paper 4.2; issue 2).

A symbol expands into one of its weighted alternatives. An alternative names a piece and,
for each of the piece's leaf rims in order, a successor (a symbol with scale ranges) or
``null`` for an open tip. Cross-field checks that need the piece library (rim counts, unknown
symbols, termination) live in ``forest.growth.grammar``; this module holds shape and ranges only.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from schemas.base import StrictModel

PieceName = Literal["I", "Y", "T", "Psi"]
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


class Alternative(StrictModel):
    piece: PieceName
    # bounded so the cumulative weights of any rule stay far from float overflow
    weight: Annotated[float, Field(gt=0, le=1e9, allow_inf_nan=False)] = 1.0
    successors: list[Successor | None]
    """One entry per leaf rim of ``piece`` (I: 1, Y: 2, T: 2, Psi: 3)."""
    twist: Literal["random"] | Annotated[int, Field(ge=0, le=5)] = "random"
    """Which of the six 60-degree twists lays this piece onto its parent's rim."""
    pose: Pose = Pose()
    min_depth: Annotated[int, Field(ge=0)] = 0
    max_depth: Annotated[int, Field(ge=0)] | None = None
    """Depth condition: the alternative applies when min_depth <= depth <= max_depth."""

    @model_validator(mode="after")
    def _depths(self) -> Alternative:
        if self.max_depth is not None and self.max_depth < self.min_depth:
            raise ValueError(f"max_depth {self.max_depth} < min_depth {self.min_depth}")
        return self


class Grammar(StrictModel):
    """A tree grammar. JSON Schema: ``schemas/json/grammar.schema.json``."""

    name: Annotated[str, Field(min_length=1, max_length=64)] = "custom"
    description: Annotated[str, Field(max_length=2000)] = ""
    axiom: Symbol
    rules: Annotated[
        dict[Symbol, Annotated[list[Alternative], Field(min_length=1)]], Field(min_length=1)
    ]
    max_depth: Annotated[int, Field(ge=0, le=64)] | None = None
    """Pieces deeper than this are not grown (their rims stay open tips). Without it the rules
    must terminate on their own."""
    foliage: list[Symbol] = []
    """Symbols whose pieces bear leaf clouds."""
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
