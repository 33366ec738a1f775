"""Tile sets by image quilting (paper 5.2): seamless borders, no repetition, real photographs
(scikit-image's bundled brick, grass and gravel), the shipped default set, the manifest."""

from __future__ import annotations

import fnmatch
import hashlib
import itertools
import json
import tomllib
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from click.testing import CliRunner
from pydantic import ValidationError
from scipy.signal import fftconvolve
from skimage import data as skdata

from bench.tiles import procedural_examples, stitch_inputs, stitch_tile_python
from cli import main
from forest.bark.images import read_pixels, read_texture_array
from forest.bark.tiles import manifest_for
from forest.bark.tileset import (
    LOWER_PREFIX,
    ClassSpec,
    TileGeometry,
    build_tileset,
    default_classes,
    stitch_tiles,
)
from forest.bark.tilesets import (
    LOWER_TRUNK,
    MEAN_COLOUR_FILE,
    SETS,
    default_dir,
    make_set,
    mean_colour,
    measured_mean_colour,
    set_dir,
)
from forest.errors import ForestError, LimitError
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from schemas.tileset import (
    DEFAULT_MANIFEST,
    QUARTER_TURN,
    TileEdges,
    TileSetManifest,
    udim_file,
)

PHOTOS = ("brick", "grass", "gravel")
# Repetition score (see `repetition_score`): an exact or shifted copy of a tile's interior
# scores 0 and the same copy after 8-bit requantisation a few thousandths; two different
# places of these photographs score 0.26 at the least (0.6 to 0.9 typically), even after the
# best of ~1000 shifts. A block three quarters of which reappears elsewhere scores about a
# quarter of an unrelated one's (~0.15 at the median): 0.15 flags that and passes texture
# that merely looks alike.
REPETITION_THRESHOLD = 0.15


@pytest.fixture(scope="module")
def photos(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    folder = tmp_path_factory.mktemp("photos")
    paths = []
    for name in PHOTOS:
        pixels = getattr(skdata, name)()  # (512, 512) uint8 grey, bundled with scikit-image
        path = folder / f"{name}.png"
        out = oiio.ImageOutput.create(str(path))
        out.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 1, "uint8"))
        out.write_image(pixels)
        out.close()
        paths.append(path)
    return paths


@pytest.fixture(scope="module")
def photo_set(photos: list[Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("tiles") / "photo_tiles"
    args = ["tiles", *map(str, photos), "-o", str(folder), "--per-class", "6", "--size", "256"]
    result = CliRunner().invoke(main, [*args, "--seed", "3"])
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith(f"wrote {folder}: 12 tiles of 256 px (6 bark, 6 fork)")
    assert "note:" not in result.stderr  # 12 disjoint interiors fit in three 512 px photos
    # progress on stderr, plain lines (not a terminal): the tiles chosen, stitched, written
    for line in ("patches 12/12 (100%) in ", "stitch 12/12 (100%) in ", "write 13/13 (100%) in "):
        assert f"tiles: {line}" in result.stderr, result.stderr
    return folder


def load(folder: Path) -> tuple[TileSetManifest, np.ndarray]:
    manifest = manifest_for(folder)
    assert manifest.files is not None
    tiles = np.stack([read_pixels(folder / name) for name in manifest.files.slices])
    return manifest, tiles


def patterns(folder: Path, m: TileSetManifest) -> dict[str, np.ndarray]:
    return {p.name: read_pixels(folder / p.file) for p in m.edge_patterns}


def across(pats: dict[str, np.ndarray], name: str) -> np.ndarray:
    """Colour ``name``'s pattern on a top or bottom side: a quarter-turn colour's vertical
    pattern turned its quarter (clockwise for ``cw``)."""
    turn = QUARTER_TURN.get(name)
    return pats[name] if turn is None else np.rot90(pats[name], k=-1 if turn == "cw" else 1)


def sets() -> list[Path]:
    return [default_dir()]


# ---------------------------------------------------------------- seamless


def check_borders(folder: Path) -> None:
    """Every tile's border strips equal its class's edge patterns, and its corners the corner
    pattern's quadrants, exactly."""
    m, tiles = load(folder)
    s, w = m.tile_size, m.border
    assert s is not None and w is not None and m.overlap is not None and m.corner is not None
    e = w + m.overlap
    pats = patterns(folder, m)
    corners = {False: read_pixels(folder / m.corner.file)}
    if m.lower_corner is not None:  # the lower trunk's classes have a corner of their own
        corners[True] = read_pixels(folder / m.lower_corner.file)
    for c in m.classes:
        corner = corners[c.stands_for is not None]
        assert corner.shape == (2 * e, 2 * e, 3)
        assert c.edges is not None
        left, right = pats[c.edges.left], pats[c.edges.right]
        top, bottom = across(pats, c.edges.top), across(pats, c.edges.bottom)
        assert left.shape == right.shape == (s, 2 * e, 3)
        assert top.shape == bottom.shape == (2 * e, s, 3)
        for t in tiles[c.first : c.first + c.count]:
            assert np.array_equal(t[:, :w], left[:, e : e + w])
            assert np.array_equal(t[:, s - w :], right[:, e - w : e])
            # a quarter-turn pattern on top or bottom is the tile's only between the corners
            # (the corners are the corner pattern's, from the left and right patterns)
            a = e if c.edges.top in QUARTER_TURN else 0
            assert np.array_equal(t[:w, a : s - a], top[e : e + w, a : s - a])
            a = e if c.edges.bottom in QUARTER_TURN else 0
            assert np.array_equal(t[s - w :, a : s - a], bottom[e - w : e, a : s - a])
            assert np.array_equal(t[:w, :w], corner[e : e + w, e : e + w])
            assert np.array_equal(t[:w, s - w :], corner[e : e + w, e - w : e])
            assert np.array_equal(t[s - w :, :w], corner[e - w : e, e : e + w])
            assert np.array_equal(t[s - w :, s - w :], corner[e - w : e, e - w : e])


def check_joints(folder: Path) -> None:
    """Wherever two tiles agree on the colour of the edge between them, side by side or one
    above the other, the pixels across the joint are one continuous piece of the pattern;
    where four meet, of the corner pattern."""
    m, tiles = load(folder)
    s, w, e = m.tile_size, m.border, (m.border or 0) + (m.overlap or 0)
    assert s is not None and w is not None and m.corner is not None
    pats = patterns(folder, m)
    corner = read_pixels(folder / m.corner.file)
    edges = {k: c.edges for c in m.classes for k in range(c.first, c.first + c.count)}
    joints = 0
    for a, b in itertools.product(range(len(tiles)), repeat=2):
        ea, eb = edges[a], edges[b]
        assert ea is not None and eb is not None
        if ea.right == eb.left:
            band = np.concatenate([tiles[a][:, s - w :], tiles[b][:, :w]], axis=1)
            assert np.array_equal(band, pats[ea.right][:, e - w : e + w])
            joints += 1
        if ea.bottom == eb.top:
            band = np.concatenate([tiles[a][s - w :], tiles[b][:w]], axis=0)
            c = e if ea.bottom in QUARTER_TURN else 0  # turned: between the corners only
            assert np.array_equal(
                band[:, c : s - c], across(pats, ea.bottom)[e - w : e + w, c : s - c]
            )
            joints += 1
        # quarter turns (schemas.tileset.QUARTER_TURN): b turned a quarter beside a, its
        # bottom or top side on a's left or right edge, continues the vertical pattern
        # between the corners (a quarter-turn edge ends where the grid is irregular, so the
        # corner quadrants cannot all line up there)
        for colour, turn in QUARTER_TURN.items():
            k = 1 if turn == "cw" else -1  # b as it lies beside a (np.rot90: k=1 is ccw)
            near, far = ("bottom", "top") if turn == "cw" else ("top", "bottom")
            mid = slice(e, s - e)
            if ea.left == colour and getattr(eb, near) == colour:
                band = np.concatenate([np.rot90(tiles[b], k)[:, s - w :], tiles[a][:, :w]], 1)
                assert np.array_equal(band[mid], pats[colour][mid, e - w : e + w])
                joints += 1
            if ea.right == colour and getattr(eb, far) == colour:
                band = np.concatenate([tiles[a][:, s - w :], np.rot90(tiles[b], k)[:, :w]], 1)
                assert np.array_equal(band[mid], pats[colour][mid, e - w : e + w])
                joints += 1
    # every pair of plain tiles (bark and fork) of one group (the lower trunk's, or the
    # rest) meets at least one way
    group = {
        k: c.name.startswith(LOWER_PREFIX)
        for c in m.classes
        for k in range(c.first, c.first + c.count)
    }
    plain = [
        sum(
            1
            for k, e in edges.items()
            if e is not None
            and group[k] == g
            and QUARTER_TURN.keys().isdisjoint((e.left, e.right, e.top, e.bottom))
        )
        for g in (False, True)
    ]
    assert joints >= sum(n * n for n in plain)
    n = (
        min(c.first for c in m.classes if c.stands_for is not None)
        if m.lower_corner
        else len(tiles)
    )
    a, b, c, d = tiles[0], tiles[n - 1], tiles[1], tiles[n // 2]
    upper = np.concatenate([a[s - w :, s - w :], b[s - w :, :w]], axis=1)
    lower = np.concatenate([c[:w, s - w :], d[:w, :w]], axis=1)
    junction = np.concatenate([upper, lower], axis=0)
    assert np.array_equal(junction, corner[e - w : e + w, e - w : e + w])


def test_photo_tiles_borders_equal_edge_patterns(photo_set: Path) -> None:
    check_borders(photo_set)


def test_photo_tiles_meet_without_a_seam(photo_set: Path) -> None:
    check_joints(photo_set)


@pytest.mark.parametrize("name", SETS)
def test_shipped_tiles_are_seamless(name: str) -> None:
    check_borders(set_dir(name))
    check_joints(set_dir(name))


# ---------------------------------------------------------------- no repetition


def repetition_score(tile_a: np.ndarray, tile_b: np.ndarray, border: int, extent: int) -> float:
    """How well ``a``'s interior block (inside the frame, always patch pixels) reappears
    anywhere in ``b`` inside its border: the least mean squared difference over every shift,
    brightness offset removed, over twice the block's variance. 0 for a copy; about 1 for
    unrelated pixels of the same texture."""
    a = tile_a.astype(np.float64).mean(axis=2)
    b = tile_b.astype(np.float64).mean(axis=2)
    s = a.shape[0]
    blk = a[extent : s - extent, extent : s - extent]
    region = b[border : s - border, border : s - border]
    m = blk.shape[0]
    zero = blk - blk.mean()
    ones = np.ones((m, m))
    sum_b = fftconvolve(region, ones, mode="valid")
    sum_b2 = fftconvolve(region * region, ones, mode="valid")
    corr = fftconvolve(region, zero[::-1, ::-1], mode="valid")
    ssd = (zero * zero).sum() + sum_b2 - sum_b**2 / (m * m) - 2 * corr
    return float(max(ssd.min(), 0.0) / (m * m) / (2 * blk.var()))


def check_no_repetition(folder: Path) -> float:
    m, tiles = load(folder)
    w, e = m.border or 0, (m.border or 0) + (m.overlap or 0)
    scores = [
        repetition_score(tiles[i], tiles[j], w, e)
        for i, j in itertools.permutations(range(len(tiles)), 2)
    ]
    assert min(scores) > REPETITION_THRESHOLD, sorted(scores)[:5]
    # and by construction: interiors come from disjoint places of the examples
    r = (m.tile_size or 0) - 2 * w
    for t, u in itertools.combinations(m.tiles, 2):
        if t.source == u.source:
            assert abs(t.y - u.y) >= r or abs(t.x - u.x) >= r, (t, u)
    return min(scores)


def test_photo_tiles_do_not_repeat(photo_set: Path) -> None:
    check_no_repetition(photo_set)


@pytest.mark.slow  # 4-8 s a set
@pytest.mark.parametrize("name", SETS)
def test_shipped_tiles_do_not_repeat(name: str) -> None:
    check_no_repetition(set_dir(name))


def test_repetition_score_catches_copies() -> None:
    """The negative control: the score does flag a repeated interior, shifted or not."""
    m, tiles = load(default_dir())
    w, e = m.border or 0, (m.border or 0) + (m.overlap or 0)
    t = tiles[0]
    assert repetition_score(t, t, w, e) < 1e-6
    shifted = np.roll(t, (5, -7), axis=(0, 1))
    assert repetition_score(t, shifted, w, e) < 1e-6
    mixed = tiles[1].copy()
    s = t.shape[0]
    mixed[w : s - w, w : s - w] = t[w : s - w, w : s - w]
    assert repetition_score(t, mixed, w, e) < REPETITION_THRESHOLD


# ---------------------------------------------------------------- outputs and manifest


def test_photo_set_files_and_manifest(photo_set: Path, photos: list[Path]) -> None:
    m, tiles = load(photo_set)
    assert [(c.name, c.id, c.first, c.count) for c in m.classes] == [
        ("bark", 1, 0, 6),
        ("fork", 2, 6, 6),
    ]
    assert m.files is not None and m.files.slices == [f"bark.{1001 + k}.png" for k in range(12)]
    assert m.files.slices == [udim_file(m.files.udim, k) for k in range(12)]
    assert (m.tile_size, m.border, m.overlap, m.seed) == (256, 32, 32, 3)
    assert tiles.shape == (12, 256, 256, 3) and tiles.dtype == np.uint8
    assert m.files.array is not None
    assert np.array_equal(read_texture_array(photo_set / m.files.array), tiles)
    assert [s.file for s in m.sources] == [p.name for p in photos]
    for src, path in zip(m.sources, photos, strict=True):
        assert src.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
        assert (src.width, src.height, src.channels, src.format) == (512, 512, 1, "uint8")
    assert {(p.name, p.axis) for p in m.edge_patterns} == {
        ("bark-v", "vertical"),
        ("bark-h", "horizontal"),
        ("crotch-h", "horizontal"),
    }
    assert [t.slice for t in m.tiles] == list(range(12))
    again = TileSetManifest.model_validate_json((photo_set / "manifest.json").read_text())
    assert again == m


def test_forest_generate_uses_the_built_set(photo_set: Path) -> None:
    forest = generate_forest(
        load_preset("almond"), 2, ForestOptions(trees=2), manifest=manifest_for(photo_set)
    )
    t = forest.tile_indices
    assert t.max() == 11 and t[t >= 0].min() == 0


@pytest.mark.parametrize("name", SETS)
def test_shipped_set_has_the_default_manifest_classes(name: str) -> None:
    m, tiles = load(set_dir(name))
    n = DEFAULT_MANIFEST.n_slices
    assert [(c.id, c.first, c.count) for c in m.classes[: len(DEFAULT_MANIFEST.classes)]] == [
        (c.id, c.first, c.count) for c in DEFAULT_MANIFEST.classes
    ]
    prefix = "procedural-bark" if name == "default" else f"procedural-{name}"
    files = [f"{prefix}-1.png", f"{prefix}-2.png"]
    lower = m.classes[len(DEFAULT_MANIFEST.classes) :]
    if name in LOWER_TRUNK:  # bark and fork again, for the lower trunk, after the rest
        assert m.lower_trunk == LOWER_TRUNK[name]
        assert [(c.id, c.first, c.count, c.stands_for) for c in lower] == [
            (101, n, 8, 1),
            (102, n + 8, 4, 2),
        ]
        n += 12
        files += [f"{prefix}-lower-1.png", f"{prefix}-lower-2.png"]
    else:
        assert not lower and m.lower_trunk is None
    assert tiles.shape == (n, 128, 128, 3)
    assert [s.file for s in m.sources] == files
    size = sum(p.stat().st_size for p in set_dir(name).iterdir())
    # 27 tiles (15 crotch classes of one tile each): under 2 MB a set; 75 kB a tile more
    assert size < 2_000_000 + 75_000 * (n - 27), f"{name} tile set is {size} bytes"


@pytest.mark.slow  # every set rebuilt, 5 s each
@pytest.mark.parametrize("name", SETS)
def test_shipped_set_is_what_the_code_makes(name: str, tmp_path: Path) -> None:
    """The shipped files are current (rebuild them with ``python -m forest.bark.tilesets``).
    Every set is rebuilt (about half a second each). Source checksums depend on the PNG
    encoder's version, so they are left out."""
    ts = make_set(name, tmp_path)
    m, tiles = load(set_dir(name))
    assert np.array_equal(tiles, ts.tiles), "run `python -m forest.bark.tilesets`"

    def strip(man: TileSetManifest) -> dict:
        d = man.model_dump()
        for src in d["sources"]:
            src.pop("sha256")
        return d

    assert strip(m) == strip(ts.manifest), "run `python -m forest.bark.tilesets`"
    shipped = (set_dir(name) / MEAN_COLOUR_FILE).read_text(encoding="utf-8")
    assert shipped == (tmp_path / MEAN_COLOUR_FILE).read_text(encoding="utf-8")


@pytest.mark.parametrize("name", SETS)
def test_stored_mean_colour_is_the_tiles_mean(name: str) -> None:
    """A scene's flat bark colour comes from the set's stored mean, exactly the one measured
    from its texture array (a rebuild writes both)."""
    assert (set_dir(name) / MEAN_COLOUR_FILE).is_file()
    assert mean_colour(name) == measured_mean_colour(name)


def test_same_seed_same_tiles_other_seed_other_tiles() -> None:
    ex = procedural_examples(200)
    geom = TileGeometry.for_size(64)
    a = build_tileset(ex, default_classes(3, 2), geom, 11)
    b = build_tileset(ex, default_classes(3, 2), geom, 11)
    c = build_tileset(ex, default_classes(3, 2), geom, 12)
    assert np.array_equal(a.tiles, b.tiles) and a.manifest == b.manifest
    assert not np.array_equal(a.tiles, c.tiles)


def test_stitch_equals_the_plain_python_baseline() -> None:
    ex = procedural_examples(120)
    geom = TileGeometry.for_size(40)
    ts = build_tileset(ex, default_classes(2, 2), geom, 4)
    frames, patches = stitch_inputs(ts, ex)
    tiles, cuts = stitch_tiles(frames, patches, geom)
    assert np.array_equal(tiles, ts.tiles)
    assert cuts.shape == (4, 4, 40) and cuts.min() >= 0 and cuts.max() < geom.overlap
    for f, p, t in zip(frames, patches, tiles, strict=True):
        assert np.array_equal(stitch_tile_python(f, p, geom), t)
        e = geom.extent
        assert np.array_equal(t[e:-e, e:-e], p[e:-e, e:-e])  # the interior is the patch


def test_more_tiles_than_disjoint_places_still_seamless(photos: list[Path], tmp_path: Path) -> None:
    out = tmp_path / "many"
    (out).mkdir()
    (out / "bark.1099.png").write_bytes(b"stale slice of an older, larger set")
    args = ["tiles", str(photos[0]), "-o", str(out), "--per-class", "5", "--size", "256"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    assert "note: the examples hold only 4 disjoint 192 px interiors; 6 tile(s)" in result.stderr
    assert not (out / "bark.1099.png").exists()
    check_borders(out)
    check_joints(out)


def test_16_bit_rgb_and_grey_examples(photos: list[Path], tmp_path: Path) -> None:
    grass = skdata.grass().astype(np.uint16) * 257
    rgb = np.stack([grass, grass // 2 + 8000, 65535 - grass], axis=-1)
    path = tmp_path / "grass16.tif"
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(512, 512, 3, "uint16"))
    out.write_image(rgb)
    out.close()
    folder = tmp_path / "t16"
    args = ["tiles", str(path), str(photos[2]), "-o", str(folder), "--per-class", "2"]
    result = CliRunner().invoke(main, [*args, "--size", "96", "--seed", "5"])
    assert result.exit_code == 0, result.output
    m, tiles = load(folder)
    assert [(s.channels, s.format) for s in m.sources] == [(3, "uint16"), (1, "uint8")]
    assert tiles.shape == (4, 96, 96, 3)
    assert (tiles[..., 0] != tiles[..., 2]).any()  # colour survives
    check_borders(folder)


def test_bad_options_and_classes(photos: list[Path], tmp_path: Path) -> None:
    r = CliRunner().invoke(main, ["tiles", str(photos[0]), "-o", str(tmp_path), "--size", "8"])
    assert r.exit_code == 2 and "--size" in r.output
    r = CliRunner().invoke(main, ["tiles", "-o", str(tmp_path)])
    assert r.exit_code == 2 and "EXAMPLE_IMAGE" in r.output
    ex = procedural_examples(64)
    with pytest.raises(ForestError, match="smaller than one 128x128 tile") as exc:
        build_tileset(ex, default_classes(1, 1), TileGeometry.for_size(128), 0)
    assert exc.value.path == "procedural-bark-1"
    bad = ClassSpec(
        "x", 3, 1, TileEdges(left="bark-h", right="bark-v", top="bark-h", bottom="bark-h")
    )
    with pytest.raises(ForestError, match="both vertical and horizontal") as exc:
        build_tileset(ex, [bad], TileGeometry.for_size(32), 0)
    assert exc.value.path == "classes.x.edges.top"
    with pytest.raises(ForestError, match="at most 999"):
        build_tileset(ex, default_classes(500, 500), TileGeometry.for_size(32), 0)
    r = CliRunner().invoke(
        main, ["tiles", "x.png", "-o", str(tmp_path), "--size", "4096", "--per-class", "20"]
    )
    assert r.exit_code == 2
    assert r.stderr == "error: --per-class: 40 tiles of 4096 px take 1.9 GiB; at most 1 GiB\n"
    with pytest.raises(LimitError, match="40 tiles of 4096 px"):
        build_tileset(ex, default_classes(20, 20), TileGeometry.for_size(4096), 0)


def test_manifest_references_are_checked(photo_set: Path, tmp_path: Path) -> None:
    good = (photo_set / "manifest.json").read_text()
    m = TileSetManifest.model_validate_json(good)
    d = m.model_dump()
    d["classes"][1]["edges"]["bottom"] = "nope"
    with pytest.raises(ValidationError, match="has no pattern"):
        TileSetManifest.model_validate(d)
    d = m.model_dump()
    d["classes"][0]["edges"]["left"] = "bark-h"
    with pytest.raises(ValidationError, match="is horizontal, not vertical"):
        TileSetManifest.model_validate(d)
    d = m.model_dump()
    d["files"]["slices"] = d["files"]["slices"][:-1]
    with pytest.raises(ValidationError, match="11 images for 12 slices"):
        TileSetManifest.model_validate(d)
    d = m.model_dump()
    d["tiles"][0]["source"] = 7
    with pytest.raises(ValidationError, match="source 7"):
        TileSetManifest.model_validate(d)
    folder = tmp_path / "broken"
    folder.mkdir()
    d = m.model_dump()
    d["sources"][0]["sha256"] = "xyz"
    (folder / "manifest.json").write_text(json.dumps(d))
    with pytest.raises(ForestError, match="sha256") as exc:
        manifest_for(folder)
    assert exc.value.path == str(folder / "manifest.json")


@pytest.mark.parametrize("name", SETS)
def test_shipped_set_is_package_data(name: str) -> None:
    """Every shipped file matches a ``[tool.setuptools.package-data]`` pattern, so the wheel
    carries it."""
    config = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    patterns = config["tool"]["setuptools"]["package-data"]["forest"]
    root = Path(__file__).parents[1] / "forest"
    files = sorted(set_dir(name).iterdir())
    m = manifest_for(set_dir(name))
    # slices, one pattern per edge colour, the array, the corner (and the lower trunk's), the
    # manifest and the mean bark colour
    assert len(files) == m.n_slices + len(m.edge_patterns) + 4 + (m.lower_corner is not None)
    for f in files:
        rel = f.relative_to(root).as_posix()
        assert any(fnmatch.fnmatch(rel, p) for p in patterns), rel
