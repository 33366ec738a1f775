"""Per-instance, per-quad tile indices (paper 5.1)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from forest.bark.tiles import class_tables, draw_tile_indices, lower_trunk
from forest.bark.tilesets import LOWER_TRUNK, shipped_manifest
from forest.errors import ForestError
from forest.geometry.pieces import piece_library
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset, preset_names
from schemas.tileset import DEFAULT_MANIFEST, TileClass, TileSetManifest

SEEDS = st.integers(min_value=0, max_value=2**63 - 1)


def check_tiles(f: Forest) -> None:
    tiles = f.tile_indices
    n_quads = np.array([len(p.quads) for p in f.pieces])
    assert tiles.dtype == np.int16
    assert tiles.shape == (f.n_instances, n_quads.max())
    by_id = {c.id: c for c in f.manifest.classes}
    stand_in = {c.stands_for: c for c in f.manifest.classes if c.stands_for is not None}
    lower = np.zeros(f.n_instances, bool)
    if f.manifest.lower_trunk is not None:
        g = f.graph
        lower = lower_trunk(g.tree, g.order, g.height, f.manifest.lower_trunk)
    for pid, piece in enumerate(f.pieces):
        for low in (False, True):
            inst = np.nonzero((f.graph.piece == pid) & (lower == low))[0]
            if len(inst) == 0:
                continue
            nq = n_quads[pid]
            block = tiles[inst]
            assert (block[:, nq:] == -1).all(), piece.name  # padding
            real = block[:, :nq]
            assert (real >= 0).all(), piece.name  # no -1 inside the piece's quads
            # a crotch class (id > 2) the manifest lacks draws from the fork class; on the
            # lower trunk a class another stands for draws from that one
            cls = [by_id.get(int(c)) or by_id[2] for c in piece.tile_class]
            if low:
                cls = [stand_in.get(c.id, c) for c in cls]
            lo = np.array([c.first for c in cls])
            hi = lo + np.array([c.count for c in cls])
            assert ((real >= lo) & (real < hi)).all(), piece.name


@pytest.mark.parametrize("name", preset_names())
@settings(max_examples=5, deadline=None)
@given(seed=SEEDS, segments=st.sampled_from([1, 2]))
def test_tile_indices_shape_padding_and_class_ranges(name: str, seed: int, segments: int) -> None:
    grammar = load_preset(name)
    f = generate_forest(grammar, seed, ForestOptions(trees=2, segments=segments))
    assert f.manifest == shipped_manifest(grammar.bark)
    check_tiles(f)


def test_every_slice_of_every_class_is_used() -> None:
    f = generate_forest(load_preset("uniform"), 5, ForestOptions(trees=30))
    check_tiles(f)
    tiles, pieces = f.tile_indices, f.pieces
    grown = [pieces[p] for p in np.unique(f.graph.piece)]
    for cls in DEFAULT_MANIFEST.classes:
        if not any((p.tile_class == cls.id).any() for p in grown):
            continue  # a class of pieces this grammar does not use (T, Psi, Cap)
        used = set()
        for pid, piece in enumerate(pieces):
            inst = np.nonzero(f.graph.piece == pid)[0]
            cols = np.nonzero(piece.tile_class == cls.id)[0]
            used |= set(np.unique(tiles[np.ix_(inst, cols)]).tolist())
        assert used == set(range(cls.first, cls.first + cls.count)), cls.name


def test_tiles_are_spread_evenly() -> None:
    """Multiply-shift of uint16 draws: every slice of a class comes up about equally often."""
    f = generate_forest(load_preset("uniform"), 9, ForestOptions(trees=60))
    for cls in DEFAULT_MANIFEST.classes:
        if cls.count == 1:
            continue  # one tile: nothing to spread
        counts = np.array(
            [(f.tile_indices == s).sum() for s in range(cls.first, cls.first + cls.count)]
        )
        assert counts.min() > 0.8 * counts.mean(), (cls.name, counts)


@settings(max_examples=5, deadline=None)
@given(seed=SEEDS)
def test_tiles_are_deterministic_per_seed(seed: int) -> None:
    opts = ForestOptions(trees=3)
    a = generate_forest(load_preset("hazel"), seed, opts)
    b = generate_forest(load_preset("hazel"), seed, opts)
    np.testing.assert_array_equal(a.tile_indices, b.tile_indices)
    c = generate_forest(load_preset("hazel"), seed + 1, opts)
    assert a.tile_indices.shape != c.tile_indices.shape or not np.array_equal(
        a.tile_indices, c.tile_indices
    )


def test_draw_is_deterministic_per_generator() -> None:
    pieces = piece_library(1)
    piece = np.array([0, 1, 2, 3, 1, 0], np.int32)
    a = draw_tile_indices(piece, pieces, DEFAULT_MANIFEST, np.random.default_rng(4))
    b = draw_tile_indices(piece, pieces, DEFAULT_MANIFEST, np.random.default_rng(4))
    c = draw_tile_indices(piece, pieces, DEFAULT_MANIFEST, np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.shape == (6, max(len(p.quads) for p in pieces))


def test_instances_of_one_piece_differ() -> None:
    f = generate_forest(load_preset("alternating"), 2, ForestOptions(trees=2))
    rows = f.tile_indices[f.graph.piece == 0]
    assert len(np.unique(rows, axis=0)) == len(rows)


def test_class_tables() -> None:
    pieces = piece_library(2)
    first, count, n_quads = class_tables(pieces, DEFAULT_MANIFEST)
    np.testing.assert_array_equal(n_quads, [len(p.quads) for p in pieces])
    assert first.shape == count.shape == (len(pieces), n_quads.max())
    for i, p in enumerate(pieces):
        assert (count[i, n_quads[i] :] == 0).all()
        by_id = {c.id: c for c in DEFAULT_MANIFEST.classes}
        want_first = [by_id[int(c)].first for c in p.tile_class]
        want_count = [by_id[int(c)].count for c in p.tile_class]
        np.testing.assert_array_equal(first[i, : n_quads[i]], want_first)
        np.testing.assert_array_equal(count[i, : n_quads[i]], want_count)
    # a set with bark and fork tiles only: crotch quads draw from the fork class
    two = TileSetManifest(classes=DEFAULT_MANIFEST.classes[:2])
    first, count, n_quads = class_tables(pieces, two)
    for i, p in enumerate(pieces):
        crotch = p.tile_class > 2
        assert (first[i, : n_quads[i]][crotch] == 8).all()
        assert (count[i, : n_quads[i]][crotch] == 4).all()


def test_custom_manifest() -> None:
    manifest = TileSetManifest(
        classes=[
            TileClass(name="fork", id=2, first=0, count=1),
            TileClass(name="bark", id=1, first=1, count=100),
        ]
    )
    f = generate_forest(load_preset("almond"), 1, ForestOptions(trees=2), manifest=manifest)
    assert f.manifest is manifest
    check_tiles(f)
    fork = np.concatenate(
        [
            f.tile_indices[i, : len(f.pieces[p].quads)][f.pieces[p].tile_class == 2]
            for i, p in enumerate(f.graph.piece)
        ]
    )
    assert (fork == 0).all()
    crotch = np.concatenate(
        [
            f.tile_indices[i, : len(f.pieces[p].quads)][f.pieces[p].tile_class > 2]
            for i, p in enumerate(f.graph.piece)
        ]
    )
    assert len(crotch) and (crotch == 0).all()  # crotch classes fall back to fork


def test_manifest_without_a_needed_class() -> None:
    manifest = TileSetManifest(classes=[TileClass(name="bark", id=1, first=0, count=8)])
    with pytest.raises(ForestError) as exc:
        generate_forest(load_preset("alternating"), 1, ForestOptions(trees=1), manifest=manifest)
    assert exc.value.path == "tileset.classes"


@pytest.mark.parametrize("threads", [2, 3])
def test_threads_draw_the_same_indices_and_leave_the_same_stream(threads: int) -> None:
    """Chunks drawn side by side from jumped-ahead copies of the stream equal one thread's
    draw, a partial last chunk included, and the generator ends in the same state."""
    pieces = piece_library(1)
    piece = np.random.default_rng(0).integers(0, len(pieces), 4 * 8192 + 7).astype(np.int32)
    one, many = np.random.default_rng(9), np.random.default_rng(9)
    a = draw_tile_indices(piece, pieces, DEFAULT_MANIFEST, one)
    b = draw_tile_indices(piece, pieces, DEFAULT_MANIFEST, many, threads=threads)
    np.testing.assert_array_equal(a, b)
    assert one.bit_generator.state == many.bit_generator.state
    assert one.integers(1 << 62) == many.integers(1 << 62)


@pytest.mark.parametrize("name", sorted(LOWER_TRUNK))
def test_lower_trunk_draws_its_own_tiles(name: str) -> None:
    """Pine's and birch's trunk pieces below the set's height fraction take the lower
    trunk's bark and fork tiles (slices after the default 27), every other piece the rest;
    the other instances' tiles are the ones the default manifest's classes give."""
    f = generate_forest(load_preset(name), 3, ForestOptions(trees=2))
    m = f.manifest
    assert m.lower_trunk == LOWER_TRUNK[name]
    check_tiles(f)
    g = f.graph
    low = lower_trunk(g.tree, g.order, g.height, LOWER_TRUNK[name])
    assert low.any() and (g.order[low] == 0).all()
    for t in range(2):  # the lowest trunk piece of each tree is on the lower trunk
        mine = np.nonzero(g.tree == t)[0]
        assert low[mine[np.argmin(g.height[mine])]]
    n = DEFAULT_MANIFEST.n_slices
    t = f.tile_indices
    assert (t[low] >= n).any() and (t[~low] < n).all()
    default = generate_forest(load_preset(name), 3, ForestOptions(trees=2), DEFAULT_MANIFEST)
    assert np.array_equal(default.tile_indices[~low], t[~low])


def test_lower_trunk_takes_the_lowest_share() -> None:
    tree = np.array([0, 0, 0, 0, 1, 1, 1])
    order = np.array([0, 0, 0, 1, 0, 0, 1])
    height = np.array([0.0, 3.0, 9.0, 1.0, 0.0, 2.0, 0.5])
    assert lower_trunk(tree, order, height, 1 / 3).tolist() == [1, 0, 0, 0, 1, 0, 0]
