"""What each level of detail keeps, as triangle targets: data only (no forest imports), so
the caps (:mod:`forest.caps`) can estimate a .glb's levels before anything grows."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LodTarget:
    """A level's triangles (bark + leaves): ``fraction`` of LOD0's, at most ``budget`` (a game
    engine's budget for that level)."""

    fraction: float
    budget: int

    def triangles(self, lod0: int) -> int:
        return int(min(self.fraction * lod0, self.budget))


TARGETS = (LodTarget(1.0, 1 << 62), LodTarget(0.25, 40_000), LodTarget(0.05, 8_000))
# a game engine's LOD0 (the glTF game profile, forest.gltf.lod): the full tree where it is
# light enough, else the thinnest pieces dropped and the leaf cards thinned as for LOD1
GAME_LOD0 = LodTarget(1.0, 100_000)
# of a level's triangles, the bark's share; the leaves take the rest. The crown's outline is
# leaves: past LOD0 the thin twigs hide inside it, and the limbs show only through gaps
BARK_SHARE = 0.5
