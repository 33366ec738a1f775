"""What a forest will cost before it is grown: the peak memory of generating and writing it
and the bytes of its scene, from its expected pieces, frames, segments and format.

The figures are bytes per piece (times a geometry factor for ``segments``) and per piece and
wind frame, measured on this version's writers and rounded up by about a third, plus what the
process holds anyway. Measured (alternating and oak, segments 1 and 8, 0 to 24 frames): a
posed USD scene keeps about 320 B per piece and 70-75 B per piece-frame, its generation about
4 KB and 85 B; a skinned one (every .usdz) 16-18 KB and 130 B in the file, 40-90 KB and 310 B
in memory; a .glb 9 KB and 240 B in the file, 45-85 KB (110 KB once in a loaded CI run) and
1.7 KB in memory. A .usda is about 3.5 times its .usdc. The skinned trees' levels of detail
(on by default) add 11-18 % to the file (oak, almond; in the figures above) and, where the
impostors are baked (GL present), about 300-400 MB to the peak for the GL context and one
tree's views (1 oak: 336 -> 735 MB; 20 almonds: 670 -> 935 MB): :data:`IMPOSTOR_MEMORY`.
``tests/test_cost.py`` fails when a writer outgrows these figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from forest.usd.scene import SKINNED_MAX_PIECES, SKINNED_MAX_TREES

BASE_MEMORY = 256 << 20  # the interpreter, numpy, pxr and the piece library
BASE_SCENE = 16 << 20  # a glb's bark atlas, leaf prototypes, the scene's fixed prims
USDA_FACTOR = 4.0  # text against crate
IMPOSTOR_MEMORY = 512 << 20  # a skinned scene's impostor bake, USD or .glb (forest.lod.impostor)


@dataclass(frozen=True)
class Rates:
    """Bytes per piece (static) and per piece and frame, in the scene and in memory; the
    static ones grow by ``per_segment`` for each segment past the first."""

    scene: float
    scene_frame: float
    memory: float
    memory_frame: float
    per_segment: float


POSED = Rates(scene=420, scene_frame=100, memory=5_500, memory_frame=120, per_segment=0.1)
SKINNED = Rates(scene=24_000, scene_frame=180, memory=120_000, memory_frame=450, per_segment=0.07)
GLB = Rates(scene=12_000, scene_frame=300, memory=90_000, memory_frame=2_000, per_segment=0.85)


@dataclass(frozen=True)
class Cost:
    memory_bytes: int
    scene_bytes: int


def is_skinned(fmt: str, trees: int, pieces: float, skinned: bool | None) -> bool:
    """Whether the scene will carry skinned trees (as :func:`forest.usd.scene.wants_skinned`
    decides on the grown forest, here on the expected pieces)."""
    if fmt in ("usdz", "glb"):
        return True
    if skinned is not None:
        return skinned
    return trees <= SKINNED_MAX_TREES and pieces <= SKINNED_MAX_PIECES


def forest_cost(
    pieces: float,
    trees: int,
    frames: int,
    segments: int = 1,
    fmt: str = "usdc",
    skinned: bool | None = None,
) -> Cost:
    """Estimated peak memory and scene bytes of ``trees`` trees of ``pieces`` expected pieces
    in all, ``frames`` wind frames, written as ``fmt`` (usda, usdc, usdz or glb)."""
    if fmt == "glb":
        rates = GLB
    elif is_skinned(fmt, trees, pieces, skinned):
        rates = SKINNED
    else:
        rates = POSED
    geometry = 1.0 + rates.per_segment * (segments - 1)
    scene = pieces * (rates.scene * geometry + rates.scene_frame * frames)
    if fmt == "usda":
        scene *= USDA_FACTOR
    memory = pieces * (rates.memory * geometry + rates.memory_frame * frames)
    if rates is SKINNED or rates is GLB:  # wherever it may run: the estimate cannot see GL
        memory += IMPOSTOR_MEMORY  # a .glb's game profile bakes its LOD3 the same way
    return Cost(
        memory_bytes=BASE_MEMORY + math.ceil(memory),
        scene_bytes=BASE_SCENE + math.ceil(scene),
    )
