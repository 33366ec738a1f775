"""Per-instance, per-quad tile indices (paper 5.1): each quad draws a texture-array slice
among the tiles of its class, so no two instances look alike."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from forest.errors import ForestError
from forest.pieces import PieceArrays
from schemas.tileset import TileSetManifest


def class_tables(pieces: tuple[PieceArrays, ...], manifest: TileSetManifest
                 ) -> tuple[NDArray[np.int32], NDArray[np.int32], NDArray[np.int32]]:
    """Per piece and padded quad: first slice ``(p, q)``, tile count ``(p, q)`` (0 marks
    padding), and the quad counts ``(p,)``."""
    by_id = {c.id: c for c in manifest.classes}
    n_quads = np.array([len(p.quads) for p in pieces], np.int32)
    first = np.zeros((len(pieces), n_quads.max()), np.int32)
    count = np.zeros_like(first)
    for i, p in enumerate(pieces):
        for cid in np.unique(p.tile_class):
            if int(cid) not in by_id:
                raise ForestError(f"piece {p.name} has quads of tile class {cid} but the "
                                  "manifest has none", path="tileset.classes")
            sel = np.nonzero(p.tile_class == cid)[0]
            first[i, sel] = by_id[int(cid)].first
            count[i, sel] = by_id[int(cid)].count
    return first, count, n_quads


def draw_tile_indices(piece: NDArray[np.int32], pieces: tuple[PieceArrays, ...],
                      manifest: TileSetManifest, rng: np.random.Generator) -> NDArray[np.int32]:
    """``(n, q_max)`` int32 slice per instance and quad, ``-1`` past the piece's last quad.

    One uint16 per quad from raw random bytes, mapped by multiply-shift: the bias for
    counts up to 4096 is below 1/16, far cheaper than bounded integer draws.
    """
    first, count, _ = class_tables(pieces, manifest)
    raw = np.frombuffer(rng.bytes(2 * len(piece) * first.shape[1]), dtype=np.uint16)
    raw = raw.reshape(len(piece), first.shape[1]).astype(np.int32)
    c = count[piece]
    return np.where(c > 0, first[piece] + ((raw * c) >> 16), -1).astype(np.int32)
