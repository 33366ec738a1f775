"""Tile-set manifest (paper 5.1): which texture-array slices belong to which tile class."""

from __future__ import annotations

import itertools
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator


class TileClass(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Annotated[str, Field(min_length=1, max_length=64)]
    id: Annotated[int, Field(ge=1, le=255)]
    """The tile class a quad carries (1 bark, 2 fork region)."""
    first: Annotated[int, Field(ge=0)]
    """First texture-array slice (also UDIM tile ``1001 + slice``) of this class."""
    count: Annotated[int, Field(ge=1, le=4096)]


class TileSetManifest(BaseModel):
    model_config = ConfigDict(extra="allow", frozen=True)

    classes: Annotated[list[TileClass], Field(min_length=1)]

    @model_validator(mode="after")
    def _disjoint(self) -> TileSetManifest:
        ids = [c.id for c in self.classes]
        if len(set(ids)) != len(ids):
            raise ValueError(f"tile class ids repeat: {ids}")
        spans = sorted((c.first, c.first + c.count) for c in self.classes)
        for (_, end), (start, _) in itertools.pairwise(spans):
            if start < end:
                raise ValueError("tile class slice ranges overlap")
        return self

    @property
    def n_slices(self) -> int:
        return max(c.first + c.count for c in self.classes)


DEFAULT_MANIFEST = TileSetManifest(
    classes=[
        TileClass(name="bark", id=1, first=0, count=8),
        TileClass(name="fork", id=2, first=8, count=4),
    ]
)
