"""Per-instance, per-quad tile indices (paper 5.1): each quad draws a texture-array slice
among the tiles of its class, so no two instances look alike."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from forest.errors import ForestError
from forest.geometry.pieces import PieceArrays
from schemas.tileset import CLASS_EDGES, DEFAULT_MANIFEST, MANIFEST_FILE, TileSetManifest

FORK_ID = 2  # the class crotch classes fall back to


def class_tables(
    pieces: tuple[PieceArrays, ...], manifest: TileSetManifest, lower: bool = False
) -> tuple[NDArray[np.int32], NDArray[np.int32], NDArray[np.int32]]:
    """Per piece and padded quad: first slice ``(p, q)``, tile count ``(p, q)`` (0 marks
    padding), and the quad counts ``(p,)``. With ``lower``, the lower trunk's: a class some
    class stands for (``TileClass.stands_for``) draws from that one.

    A crotch class (id 3 and up, :data:`schemas.tileset.CLASS_EDGES`) the manifest lacks (a
    set built with bark and fork tiles only, or written by hand) draws from the fork class:
    the forest still renders, with seams at crotches and apexes."""
    by_id = {c.id: c for c in manifest.classes}
    if FORK_ID in by_id:
        for cid in CLASS_EDGES:
            if cid > FORK_ID:
                by_id.setdefault(cid, by_id[FORK_ID])
    if lower:
        by_id.update({c.stands_for: c for c in manifest.classes if c.stands_for is not None})
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
    threads: int = 1,
    lower: NDArray[np.bool_] | None = None,
) -> NDArray[np.int16]:
    """``(n, q_max)`` int16 slice per instance and quad, ``-1`` past the piece's last quad
    (16 bits: half the bytes of the forest's largest array after the palette; a texture
    array holds far fewer slices, and the scene files still store ``int[]``).

    One uint16 per padded quad from the bit generator's raw output, mapped by multiply-shift:
    for ``c`` tiles the bias is at most ``c / 65536`` (below 1/16 for any class size the
    manifest allows), and it is far cheaper than bounded integer draws. Padding maps to -1 by
    a tile count of 0 and a first slice of -1, so rows are drawn in instance order, in chunks
    whose temporaries stay in cache, and the output is written once, front to back.

    With ``threads`` > 1 the chunks are drawn side by side, each from a copy of the stream
    advanced to where a single thread would be at that chunk (PCG64 jumps ahead in
    ``O(log n)``): the same indices on any number of threads. ``rng`` ends advanced past every
    draw either way.

    ``lower`` ``(n,)`` marks the instances on the lower trunk (:func:`lower_trunk`): they
    draw from the classes that stand for theirs. They index a second copy of the piece
    tables, so the draws, and every other instance's tiles, are the same as without.
    """
    first, count, n_quads = class_tables(pieces, manifest)
    if lower is not None and lower.any():
        low_first, low_count, _ = class_tables(pieces, manifest, lower=True)
        first = np.concatenate([first, low_first])
        count = np.concatenate([count, low_count])
        n_quads = np.concatenate([n_quads, n_quads])
        piece = np.where(lower, piece + len(pieces), piece).astype(piece.dtype)
    if int((first + count).max(initial=0)) > np.iinfo(np.int16).max:
        raise ForestError(
            f"the tile set has over {np.iinfo(np.int16).max} slices", path="tileset.classes"
        )
    q_max = first.shape[1]
    pad = np.arange(q_max) >= n_quads[:, None]
    base = np.where(pad, -1, first).astype(np.int32)
    n_count = count.astype(np.uint32)  # 0 on padding already
    out = np.empty((len(piece), q_max), np.int16)
    starts = range(0, len(piece), _TILE_CHUNK)
    # 64-bit draws per whole chunk: four uint16 each (a chunk is a multiple of 4 rows)
    words = _TILE_CHUNK * q_max // 4
    bit_gen = rng.bit_generator
    state = bit_gen.state
    # jumping ahead needs a bit generator with advance (PCG64, default_rng's); others draw
    # on one thread
    threads = max(1, min(threads, len(starts))) if hasattr(bit_gen, "advance") else 1

    def draw(part: int) -> None:
        if threads == 1:
            gen = bit_gen
        else:
            gen = type(bit_gen)()
            gen.state = state
            gen.advance(part * words)  # type: ignore[attr-defined]
        tile = np.empty((min(_TILE_CHUNK, len(piece)), q_max), np.uint32)
        for at in starts[part::threads]:
            if threads > 1 and at != starts[part]:
                gen.advance((threads - 1) * words)  # type: ignore[attr-defined]
            kinds = piece[at : at + _TILE_CHUNK]
            k = len(kinds) * q_max
            raw = gen.random_raw(-(-k // 4)).view(np.uint16)[:k]
            t = tile[: len(kinds)]
            np.multiply(raw.reshape(len(kinds), q_max), np.take(n_count, kinds, axis=0), out=t)
            t >>= 16
            signed = t.view(np.int32)
            signed += np.take(base, kinds, axis=0)
            out[at : at + len(kinds)] = signed

    if threads == 1:
        draw(0)
    else:
        with ThreadPoolExecutor(threads, thread_name_prefix="forest-tiles") as pool:
            for done in [pool.submit(draw, i) for i in range(threads)]:
                done.result()
        bit_gen.state = state
        bit_gen.advance(-(-len(piece) * q_max // 4))  # type: ignore[attr-defined]
    return out


_TILE_CHUNK = 8192  # rows per chunk: a multiple of 4, so chunks use whole 64-bit draws


def lower_trunk(
    tree: NDArray[np.integer],
    order: NDArray[np.integer],
    height: NDArray[np.floating],
    fraction: float,
) -> NDArray[np.bool_]:
    """``(n,)`` the trunk instances (branch order 0) that start below ``fraction`` of their
    tree's height, the highest start of a trunk instance in that tree (per instance
    ``tree``, ``order`` and ``height``, metres, as :class:`forest.growth.expand.PieceGraph`
    holds them)."""
    trunk = order == 0
    top = np.zeros(int(tree.max(initial=-1)) + 1)
    np.maximum.at(top, tree[trunk], height[trunk])
    return trunk & (height < fraction * top[tree])


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
