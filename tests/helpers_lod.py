"""What a default write adds for the skinned trees' levels of detail (forest.usd.lod)."""

from __future__ import annotations

from forest.usd.contract import tree_name
from forest.usd.scene import impostor_available

KINDS = ("albedo", "cards", "depth", "normal")  # forest.lod.impostor.write_impostor


def impostor_pictures(trees: int, packed: bool = False) -> list[str]:
    """The impostor pictures a default write of ``trees`` trees (up to
    forest.usd.scene.IMPOSTOR_MAX_TREES) puts beside its other pictures: each tree's four, in
    a .usdz (``packed``) its cards' only; none where GL is missing."""
    if not impostor_available():
        return []
    kinds = ("cards",) if packed else KINDS
    return [f"{tree_name(k)}.{kind}.png" for k in range(trees) for kind in kinds]
