"""Image files through OpenImageIO: texture examples in (8 or 16 bit, float, grey or RGB, any
format OpenImageIO reads), tile PNGs and the multi-subimage TIFF texture array out.

Every problem with an input file raises :class:`~forest.errors.ForestError` naming the file
and what is wrong with it; a file that cannot be written raises
:class:`~forest.errors.OutputError`.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from forest.atomic import replaced_when_written
from forest.errors import ForestError, OutputError
from forest.sniff import HEAD_BYTES, NOT_IMAGE_KINDS, describe, sniff_bytes


class _OnFirstUse:
    """OpenImageIO, imported when an image is first read or written: its 40-70 ms would
    otherwise be paid by every command that imports this module for :func:`srgb_to_linear`
    (growing a forest) without touching a picture."""

    def __getattr__(self, name: str) -> Any:
        import OpenImageIO

        return getattr(OpenImageIO, name)


if TYPE_CHECKING:
    import OpenImageIO as oiio
else:
    oiio = _OnFirstUse()

U8 = NDArray[np.uint8]
# An example larger than this is almost surely a mistake (a 64 Mpx photo is 192 MB as RGB
# bytes), and reading it whole would take the machine's memory for nothing.
MAX_EXAMPLE_PIXELS = 64 * 1024 * 1024
# TIFF writers stamp the current time; a fixed stamp keeps the texture array reproducible.
FIXED_DATETIME = "2000:01:01 00:00:00"


@dataclass(frozen=True, eq=False)
class ExampleImage:
    """One texture example, as RGB bytes.

    pixels : (h, w, 3) uint8 (grey files are repeated into the three channels)
    channels : channels in the file (1 or 3)   format : the file's pixel type ("uint8", ...)
    sha256 : hex digest of the file's bytes
    """

    path: Path
    pixels: U8
    channels: int
    format: str
    sha256: str

    @property
    def width(self) -> int:
        return int(self.pixels.shape[1])

    @property
    def height(self) -> int:
        return int(self.pixels.shape[0])


@contextmanager
def _quiet_stderr() -> Iterator[None]:
    """Silence file descriptor 2 for a moment: libpng prints its errors to the console as
    well as handing them to OpenImageIO, and we report them once, as a ForestError."""
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no stderr to silence
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _oiio_message(text: str) -> str:
    lines = [ln.strip() for ln in text.strip().splitlines() if ln.strip()]
    return lines[0] if lines else "unknown error"


def _check_example_spec(spec: oiio.ImageSpec, where: str, min_size: int, max_pixels: int) -> None:
    """What makes an image's header unusable as a texture example: ForestError at ``where``."""
    width, height, nch = spec.width, spec.height, spec.nchannels
    names = ", ".join(spec.channelnames)
    if spec.deep or spec.depth > 1:
        raise ForestError("deep and volume images are not texture examples", path=where)
    if spec.alpha_channel >= 0 or nch in (2, 4):
        raise ForestError(
            f"has an alpha channel ({names}); give grey or RGB images without alpha", path=where
        )
    if nch not in (1, 3):
        raise ForestError(
            f"has {nch} channels ({names}); give grey (1) or RGB (3) images", path=where
        )
    if width * height <= 1:
        raise ForestError(f"is a single pixel ({width}x{height}), not a texture", path=where)
    if width < min_size or height < min_size:
        raise ForestError(
            f"is {width}x{height} pixels, smaller than one {min_size}x{min_size} tile", path=where
        )
    if width * height > max_pixels:
        raise ForestError(
            f"is {width}x{height} pixels, more than the {max_pixels} accepted", path=where
        )


def check_example_header(path: Path, where: str, min_size: int, max_pixels: int) -> None:
    """Only the header of an uploaded example (the service, before a job is made): readable
    by OpenImageIO and usable by :func:`read_example`; ForestError at ``where`` (a request
    field, never the temporary file's path) naming what is wrong."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        # OpenImageIO's message names the file: not the server's path
        why = _oiio_message(oiio.geterror()).replace(str(path), "the image")
        raise ForestError(f"not a readable image ({why})", path=where)
    try:
        _check_example_spec(inp.spec(), where, min_size, max_pixels)
    finally:
        inp.close()


def read_example(path: Path, min_size: int = 2) -> ExampleImage:
    """Read a texture example, checking everything that would make it unusable.

    min_size : the smallest width and height accepted (the tile size, when building tiles)
    """
    where = str(path)
    if not path.exists():
        raise ForestError("file not found", path=where)
    if path.is_dir():
        raise ForestError("is a folder, not an image", path=where)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ForestError(f"cannot read file: {exc.strerror}", path=where) from None
    if not data:
        raise ForestError("file is empty", path=where)
    kind = sniff_bytes(data[:HEAD_BYTES])
    if kind in NOT_IMAGE_KINDS:
        raise ForestError(f"is {describe(kind)}, not an image", path=where)
    inp = oiio.ImageInput.open(where)
    if inp is None:
        raise ForestError(f"not a readable image ({_oiio_message(oiio.geterror())})", path=where)
    try:
        spec = inp.spec()
        width, height, nch = spec.width, spec.height, spec.nchannels
        _check_example_spec(spec, where, min_size, MAX_EXAMPLE_PIXELS)
        with _quiet_stderr():
            pixels = inp.read_image(0, 0, 0, nch, "uint8")
        # a truncated file may come back as None, or as pixels with an error left behind
        problem = inp.geterror()
        if pixels is None or problem:
            raise ForestError(
                f"image data is truncated or corrupt ({_oiio_message(problem)})", path=where
            )
        fmt = str(spec.format)
    finally:
        inp.close()
    pixels = np.asarray(pixels, dtype=np.uint8).reshape(height, width, nch)
    if nch == 1:
        pixels = np.repeat(pixels, 3, axis=2)
    return ExampleImage(
        path=path,
        pixels=np.ascontiguousarray(pixels),
        channels=nch,
        format=fmt,
        sha256=hashlib.sha256(data).hexdigest(),
    )


def srgb_to_linear(srgb: NDArray[np.floating]) -> NDArray[np.float64]:
    """sRGB-encoded values in [0, 1] as linear ones (the sRGB transfer function's inverse)."""
    x = np.asarray(srgb, np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def read_pixels(path: Path) -> U8:
    """A single image as stored, ``(h, w, c)`` uint8 (tile-set outputs, in tests)."""
    return read_subimages(path)[0]


def _spec(pixels: U8) -> oiio.ImageSpec:
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, "uint8")
    spec.attribute("DateTime", FIXED_DATETIME)
    return spec


def _create(path: Path, shown: Path) -> oiio.ImageOutput:
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise OutputError(f"cannot write ({_oiio_message(oiio.geterror())})", path=str(shown))
    return out


def write_png(path: Path, pixels: U8) -> Path:
    """Write ``(h, w, c)`` uint8 pixels (c = 1, 3 or 4, top row first) as an 8-bit PNG."""
    pixels = np.ascontiguousarray(pixels, dtype=np.uint8)
    with replaced_when_written(path) as tmp:
        out = _create(tmp, path)
        ok = out.open(str(tmp), _spec(pixels)) and out.write_image(pixels)
        problem = out.geterror()
        out.close()
        if not ok or problem:
            raise OutputError(f"cannot write ({_oiio_message(problem)})", path=str(path))
    return path


def write_texture_array(path: Path, slices: U8) -> Path:
    """Write ``(n, h, w, c)`` uint8 slices as one TIFF with ``n`` subimages in slice order
    (zip-compressed, fixed time stamp, so the same slices give the same bytes)."""
    slices = np.ascontiguousarray(slices, dtype=np.uint8)
    specs = [_spec(s) for s in slices]
    for spec in specs:
        spec.attribute("compression", "zip")
        # this libtiff build fails writing the (empty) Exif directory; there is none to keep
        spec.attribute("tiff:write_exif", 0)
    with replaced_when_written(path) as tmp:
        out = _create(tmp, path)
        if not out.supports("multiimage"):
            out.close()
            raise OutputError("format cannot hold several subimages; use .tif", path=str(path))
        ok = out.open(str(tmp), specs)
        for k, pixels in enumerate(slices):
            if not ok:
                break
            if k:
                ok = out.open(str(tmp), specs[k], "AppendSubimage")
            ok = ok and out.write_image(pixels)
        problem = out.geterror()
        out.close()
        if not ok or problem:
            raise OutputError(f"cannot write ({_oiio_message(problem)})", path=str(path))
    return path


def read_subimages(path: Path) -> list[U8]:
    """Every subimage of an image file in order, each ``(h, w, c)`` uint8 (a texture-array
    TIFF holds one per slice, a PNG one)."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ForestError(
            f"not a readable image ({_oiio_message(oiio.geterror())})", path=str(path)
        )
    slices = []
    try:
        k = 0
        while inp.seek_subimage(k, 0):
            spec = inp.spec()
            pixels = inp.read_image(k, 0, 0, spec.nchannels, "uint8")
            if pixels is None or inp.geterror():
                raise ForestError(f"subimage {k} is truncated or corrupt", path=str(path))
            slices.append(np.asarray(pixels, np.uint8).reshape(spec.height, spec.width, -1))
            k += 1
    finally:
        inp.close()
    return slices


def read_texture_array(path: Path) -> U8:
    """Every subimage of a texture-array TIFF, ``(n, h, w, c)`` uint8 in slice order."""
    return np.stack(read_subimages(path))


MAX_MAP_PIXELS = 16 * 1024 * 1024  # a 4096 x 4096 density map or heightfield
MAX_MAP_BYTES = 32 * 1024 * 1024
_SUFFIX = {"png": ".png", "jpeg": ".jpg", "tiff": ".tif", "exr": ".exr", "gif": ".gif"}


def read_grey(data: bytes, field: str) -> NDArray[np.float32]:
    """A greyscale map (a forest recipe's density map or heightfield) from a file's bytes:
    ``(h, w)`` float32 in [0, 1] at the file's own precision (16-bit heights stay 16-bit); the
    first channel of a colour image. Anything else is a ForestError at ``field``."""
    with _map_file(data, field) as name:
        return _read_grey_file(name, field)


def check_grey(data: bytes, field: str) -> tuple[int, int]:
    """``(width, height)`` of a map that :func:`read_grey` reads, found by decoding it a band
    of rows at a time (memory stays a band's, whatever the image's size): the service's check
    of a recipe's images before any job. Anything else is a ForestError at ``field``."""
    with _map_file(data, field) as name:
        inp, width, height = _open_map(name, field)
        try:
            for y in range(0, height, CHECK_ROWS):
                with _quiet_stderr():
                    band = inp.read_scanlines(0, 0, y, min(y + CHECK_ROWS, height), 0, 0, 1)
                problem = inp.geterror()
                if band is None or problem:
                    raise ForestError(
                        f"image data is truncated or corrupt ({_oiio_message(problem)})",
                        path=field,
                    )
                if not np.isfinite(np.asarray(band, np.float32)).all():
                    raise ForestError("the image holds NaN or infinite values", path=field)
        finally:
            inp.close()
        return width, height


CHECK_ROWS = 64


@contextmanager
def _map_file(data: bytes, field: str) -> Iterator[str]:
    """The bytes of a map in a private temporary file named by their kind (OpenImageIO reads
    files), once they are not empty, not too large and of a kind a map may be."""
    if not data:
        raise ForestError("the image is empty", path=field)
    if len(data) > MAX_MAP_BYTES:
        raise ForestError(
            f"the image is {len(data):,} bytes, more than the {MAX_MAP_BYTES:,} accepted",
            path=field,
        )
    kind = sniff_bytes(data[:HEAD_BYTES])
    if kind not in _SUFFIX:
        raise ForestError(
            f"is {describe(kind)}, not a PNG, JPEG, TIFF, OpenEXR or GIF image", path=field
        )
    fd, name = tempfile.mkstemp(suffix=_SUFFIX[kind], prefix="forest-map-")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        yield name
    finally:
        os.unlink(name)


def _open_map(name: str, field: str) -> tuple[oiio.ImageInput, int, int]:
    """The open image and its width and height, within the map caps."""
    inp = oiio.ImageInput.open(name)
    if inp is None:
        raise ForestError(f"not a readable image ({_oiio_message(oiio.geterror())})", path=field)
    try:
        spec = inp.spec()
        width, height = spec.width, spec.height
        if spec.deep or spec.depth > 1:
            raise ForestError("deep and volume images are not maps", path=field)
        if width < 2 or height < 2:
            raise ForestError(f"is {width}x{height} pixels; a map needs at least 2x2", path=field)
        if width * height > MAX_MAP_PIXELS:
            raise ForestError(
                f"is {width}x{height} pixels, more than the {MAX_MAP_PIXELS:,} accepted",
                path=field,
            )
    except BaseException:
        inp.close()
        raise
    return inp, width, height


def _read_grey_file(name: str, field: str) -> NDArray[np.float32]:
    inp, width, height = _open_map(name, field)
    try:
        with _quiet_stderr():
            pixels = inp.read_image(0, 0, 0, 1, "float")
        problem = inp.geterror()
        if pixels is None or problem:
            raise ForestError(
                f"image data is truncated or corrupt ({_oiio_message(problem)})", path=field
            )
    finally:
        inp.close()
    grey = np.asarray(pixels, np.float32).reshape(height, width)
    if not np.isfinite(grey).all():
        raise ForestError("the image holds NaN or infinite values", path=field)
    return np.clip(grey, 0.0, 1.0)
