"""Library settings (caps on work), read from ``FOREST_*`` environment variables.

A plain pydantic model that reads its own variables rather than a pydantic-settings
``BaseSettings``: importing pydantic-settings brings asyncio, ssl and dotenv (30-120 ms of a
one-tree run's start-up) for what is a dictionary lookup per field here. The farm's and the
service's settings, which need its sources, stay ``BaseSettings``."""

from __future__ import annotations

import os
from functools import cache
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

ENV_PREFIX = "FOREST_"


class ForestSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    max_pieces_per_tree: int = Field(100_000, gt=0)
    # ~1 KiB of arrays per piece (transforms, bones, tiles): 5 M pieces stay within a few GiB
    max_pieces_per_forest: int = Field(5_000_000, gt=0)
    max_trees: int = Field(200_000, gt=0)
    max_frames: int = Field(10_000, gt=0)
    # bone matrices over all frames (128 bytes each in a scene): 50 M is 6.4 GB of palette
    max_palette_matrices: int = Field(50_000_000, gt=0)
    # depth at which a grammar without max_depth is declared non-terminating
    depth_limit: int = Field(64, gt=0, le=256)
    # a grammar's size, checked before it is compiled: the presets have at most 12 rules
    # and 22 alternatives; expansion holds a (pieces, alternatives) table per depth
    max_grammar_rules: int = Field(256, gt=0)
    max_grammar_alternatives: int = Field(1024, gt=0)
    # threads for the block passes of generation (assembly, palette); 0: the usable cores,
    # at most 4. A farm running one job per core may set 1.
    threads: int = Field(0, ge=0, le=64)

    def __init__(self, **values: Any) -> None:
        # as BaseSettings did: FOREST_<FIELD> in any case, arguments over the environment
        super().__init__(**{**_from_environment(type(self).model_fields), **values})


def _from_environment(fields: dict[str, Any]) -> dict[str, str]:
    env = {k.upper(): v for k, v in os.environ.items() if k.upper().startswith(ENV_PREFIX)}
    return {name: env[key] for name in fields if (key := ENV_PREFIX + name.upper()) in env}


@cache
def get_settings() -> ForestSettings:
    return ForestSettings()
