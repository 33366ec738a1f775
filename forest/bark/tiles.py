"""Per-instance, per-quad tile indices (paper 5.1): each quad draws a texture-array slice
among the tiles of its class, so no two instances look alike."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from forest.errors import ForestError
from forest.geometry.pieces import PieceArrays
from schemas.tileset import CLASS_EDGES, DEFAULT_MANIFEST, MANIFEST_FILE, TileSetManifest

FORK_ID = 2  # the class crotch classes fall back to


def class_tables(
    pieces: tuple[PieceArrays, ...], manifest: TileSetManifest
) -> tuple[NDArray[np.int32], NDArray[np.int32], NDArray[np.int32]]:
    """Per piece and padded quad: first slice ``(p, q)``, tile count ``(p, q)`` (0 marks
    padding), and the quad counts ``(p,)``.

    A crotch class (id 3 and up, :data:`schemas.tileset.CLASS_EDGES`) the manifest lacks (a
    set built with bark and fork tiles only, or written by hand) draws from the fork class:
    the forest still renders, with seams at crotches and apexes."""
    by_id = {c.id: c for c in manifest.classes}
    if FORK_ID in by_id:
        for cid in CLASS_EDGES:
            if cid > FORK_ID:
                by_id.setdefault(cid, by_id[FORK_ID])
    n_quads = np.array([len(p.quads) for p in pieces], np.int32)
    first = np.zeros((len(pieces), n_quads.max()), np.int32)
    count = np.zeros_like(first)
    for i, p in enumerate(pieces):
        for cid in np.unique(p.tile_class):
            if int(cid) not in by_id:
                raise ForestError(
                    f"piece {p.name} has quads of tile class {cid} but the manifest has none",
                    path="tileset.classes",
                )
            sel = np.nonzero(p.tile_class == cid)[0]
            first[i, sel] = by_id[int(cid)].first
            count[i, sel] = by_id[int(cid)].count
    return first, count, n_quads


def draw_tile_indices(
    piece: NDArray[np.int32],
    pieces: tuple[PieceArrays, ...],
    manifest: TileSetManifest,
    rng: np.random.Generator,
) -> NDArray[np.int32]:
    """``(n, q_max)`` int32 slice per instance and quad, ``-1`` past the piece's last quad.

    One uint16 per quad from the bit generator's raw output, mapped by multiply-shift: for
    ``c`` tiles the bias is at most ``c / 65536`` (below 1/16 for any class size the manifest
    allows), and it is far cheaper than bounded integer draws. Drawn one piece type at a time,
    only for the quads that type has, so the per-quad tables broadcast instead of being
    gathered, and in chunks of rows whose temporaries stay in cache.
    """
    first, count, n_quads = class_tables(pieces, manifest)
    out = np.full((len(piece), first.shape[1]), -1, np.int32)
    for p in range(len(pieces)):
        rows = np.flatnonzero(piece == p)
        q = int(n_quads[p])
        n_count = count[p, :q].astype(np.uint32)
        buf = np.empty((min(_TILE_CHUNK, len(rows)), q), np.uint32)
        for at in range(0, len(rows), _TILE_CHUNK):
            chunk = rows[at : at + _TILE_CHUNK]
            k = len(chunk) * q
            raw = rng.bit_generator.random_raw(-(-k // 4)).view(np.uint16)[:k]
            tile = buf[: len(chunk)]
            np.multiply(raw.reshape(len(chunk), q), n_count, out=tile)
            tile >>= 16
            signed = tile.view(np.int32)
            signed += first[p, :q]
            out[chunk, :q] = signed
    return out


_TILE_CHUNK = 8192  # rows per chunk: a multiple of 4, so chunks use whole 64-bit draws


def manifest_for(folder: Path) -> TileSetManifest:
    """The manifest of a tile-set folder; the built-in default where the folder has none."""
    if not folder.is_dir():
        raise ForestError("tile-set folder does not exist", path=str(folder))
    path = folder / MANIFEST_FILE
    if not path.exists():
        return DEFAULT_MANIFEST
    try:
        return TileSetManifest.model_validate_json(path.read_bytes())
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        raise ForestError(
            f"{where}: {err['msg']}" if where else err["msg"], path=str(path)
        ) from None
