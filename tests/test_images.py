"""Image files: examples in (8/16 bit, grey/RGB), tiles and the texture array out, and a clear
error naming the file for every kind of bad input, from the library and from `forest tiles`."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from click.testing import CliRunner

from cli import main
from forest.bark.images import (
    read_example,
    read_pixels,
    read_texture_array,
    write_png,
    write_texture_array,
)
from forest.errors import ForestError, OutputError


def write_raw(path: Path, pixels: np.ndarray, fmt: str = "uint8", alpha: int = -1) -> Path:
    """Write any pixels (any channel count and type) with OpenImageIO."""
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    if alpha >= 0:
        spec.alpha_channel = alpha
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(pixels), out.geterror()
    out.close()
    return path


def noise(h: int, w: int, c: int, seed: int = 0, dtype: type = np.uint8) -> np.ndarray:
    top = np.iinfo(dtype).max
    return np.random.default_rng(seed).integers(0, top + 1, (h, w, c), dtype=dtype)


def test_8_and_16_bit_grey_and_rgb_read_as_rgb_bytes(tmp_path: Path) -> None:
    rgb8 = noise(40, 50, 3)
    grey16 = noise(40, 50, 1, dtype=np.uint16)
    rgb16 = noise(40, 50, 3, seed=1, dtype=np.uint16)
    a = read_example(write_raw(tmp_path / "rgb8.png", rgb8))
    assert a.pixels.dtype == np.uint8 and np.array_equal(a.pixels, rgb8)
    assert (a.channels, a.format, a.width, a.height) == (3, "uint8", 50, 40)
    b = read_example(write_raw(tmp_path / "grey16.png", grey16, "uint16"))
    assert b.channels == 1 and b.format == "uint16" and b.pixels.shape == (40, 50, 3)
    expect = np.round(grey16[..., 0] / 257).astype(np.uint8)
    assert np.abs(b.pixels[..., 0].astype(int) - expect).max() <= 1
    assert np.array_equal(b.pixels[..., 0], b.pixels[..., 2])
    c = read_example(write_raw(tmp_path / "rgb16.tif", rgb16, "uint16"))
    assert c.format == "uint16" and np.abs(c.pixels.astype(int) - rgb16 / 257).max() <= 1
    assert a.sha256 == hashlib.sha256((tmp_path / "rgb8.png").read_bytes()).hexdigest()


def test_png_and_texture_array_round_trip(tmp_path: Path) -> None:
    tile = noise(16, 16, 3)
    assert np.array_equal(read_pixels(write_png(tmp_path / "t.png", tile)), tile)
    stack = np.stack([noise(16, 16, 3, seed=s) for s in range(5)])
    path = write_texture_array(tmp_path / "a.tif", stack)
    assert np.array_equal(read_texture_array(path), stack)
    first = path.read_bytes()
    write_texture_array(path, stack)
    assert path.read_bytes() == first  # no time stamp: the same slices give the same bytes


def test_unwritable_output_is_an_output_error(tmp_path: Path) -> None:
    with pytest.raises(OutputError) as exc:
        write_png(tmp_path / "missing-folder" / "t.png", noise(4, 4, 3))
    assert exc.value.path.endswith("t.png")
    with pytest.raises(OutputError, match="cannot write"):
        write_png(tmp_path / "t.unknown-format", noise(4, 4, 3))


def test_failed_write_keeps_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    old = write_png(tmp_path / "t.png", noise(8, 8, 3)).read_bytes()
    with pytest.raises(OutputError, match="several subimages"):
        write_texture_array(tmp_path / "t.png", np.stack([noise(8, 8, 3)] * 2))
    assert (tmp_path / "t.png").read_bytes() == old
    assert [p.name for p in tmp_path.iterdir()] == ["t.png"]


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _truncated(path: Path) -> Path:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return path


BAD_INPUTS = {
    "missing": (lambda d: d / "nope.png", "file not found"),
    "folder": (lambda d: d, "is a folder"),
    "empty": (lambda d: _write(d / "empty.png", b""), "file is empty"),
    "junk": (lambda d: _write(d / "junk.png", b"not a png at all" * 20), "not a readable image"),
    "truncated png": (
        lambda d: _truncated(write_raw(d / "cut.png", noise(200, 200, 3))),
        "truncated or corrupt",
    ),
    "truncated jpeg": (
        lambda d: _truncated(write_raw(d / "cut.jpg", noise(200, 200, 3))),
        "truncated or corrupt",
    ),
    "truncated tiff": (
        lambda d: _truncated(write_raw(d / "cut.tif", noise(200, 200, 3))),
        "truncated or corrupt",
    ),
    "rgba": (
        lambda d: write_raw(d / "rgba.png", noise(200, 200, 4), alpha=3),
        "has an alpha channel",
    ),
    "grey alpha": (
        lambda d: write_raw(d / "ya.png", noise(200, 200, 2), alpha=1),
        "has an alpha channel",
    ),
    "one pixel": (lambda d: write_raw(d / "dot.png", noise(1, 1, 3)), "is a single pixel"),
    "smaller than a tile": (
        lambda d: write_raw(d / "small.png", noise(100, 300, 3)),
        "is 300x100 pixels, smaller than one 128x128 tile",
    ),
}


@pytest.mark.parametrize("kind", sorted(BAD_INPUTS))
def test_bad_input_names_the_file_and_the_problem(tmp_path: Path, kind: str) -> None:
    make, message = BAD_INPUTS[kind]
    path = make(tmp_path)
    with pytest.raises(ForestError) as exc:
        read_example(path, min_size=128)
    assert exc.value.path == str(path)
    assert message in exc.value.message


@pytest.mark.parametrize(
    "kind", ["missing", "truncated png", "rgba", "one pixel", "smaller than a tile"]
)
def test_cli_prints_one_error_line_and_exits_2(tmp_path: Path, kind: str) -> None:
    make, message = BAD_INPUTS[kind]
    bad = make(tmp_path)
    good = write_raw(tmp_path / "good.png", noise(256, 256, 3))
    result = CliRunner().invoke(
        main, ["tiles", str(good), str(bad), "-o", str(tmp_path / "out"), "--size", "128"]
    )
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert lines == [f"error: {bad}: {lines[0].split(': ', 2)[2]}"]
    assert message in lines[0]
    assert not (tmp_path / "out" / "manifest.json").exists()


def test_truncated_png_from_the_installed_command_is_one_line(tmp_path: Path) -> None:
    """libpng also prints its errors to the console; `forest tiles` says it once."""
    bad = _truncated(write_raw(tmp_path / "cut.png", noise(200, 200, 3)))
    forest = Path(sys.executable).with_name("forest")
    run = subprocess.run(
        [str(forest), "tiles", str(bad), "-o", str(tmp_path / "out"), "--size", "64"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2
    assert run.stderr.splitlines() == [
        f"error: {bad}: image data is truncated or corrupt "
        "(Read error: hit end of file in png reader)"
    ]
