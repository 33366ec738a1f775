"""Clips of a render: the frames of the wind animation (or of an orbit) encoded with
maintained libraries: mp4 (H.264) and webm (VP9) through imageio's ffmpeg plugin
(imageio-ffmpeg ships the ffmpeg binary), animated gif and webp through Pillow (imageio's
pillow plugin). No encoder code of our own.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from forest.errors import ForestError, OutputError

MEDIA_TYPES = {
    ".mp4": "video/mp4",
    ".webm": "video/webm",
    ".gif": "image/gif",
    ".webp": "image/webp",
}
CODECS = {".mp4": "libx264", ".webm": "libvpx-vp9"}
DEFAULT_FPS = 24.0
ORBIT_FRAMES = 48  # an orbit of a still scene (one palette sample) when no frame count is given


def clip_suffix(path: Path) -> str:
    """The clip's format from its suffix, or an OutputError naming the path."""
    suffix = path.suffix.lower()
    if suffix not in MEDIA_TYPES:
        raise OutputError(
            f"a clip is {', '.join(s.lstrip('.') for s in MEDIA_TYPES)}: name it so",
            path=str(path),
        )
    return suffix


def check_clip(path: Path, size: tuple[int, int], fps: float) -> None:
    """Raise a ForestError for what the encoder would refuse: odd sizes for mp4/webm (4:2:0
    chroma halves both sides), an fps outside (0, 120]."""
    suffix = clip_suffix(path)
    if suffix in CODECS and (size[0] % 2 or size[1] % 2):
        raise ForestError(
            f"{suffix[1:]} needs an even width and height, got {size[0]}x{size[1]}",
            path="width" if size[0] % 2 else "height",
        )
    if not (np.isfinite(fps) and 0 < fps <= 120):
        raise ForestError(f"must be in (0, 120], got {fps}", path="fps")


def write_clip(path: Path, frames: Sequence[NDArray[np.uint8]], fps: float) -> None:
    """Encode ``frames`` (each ``(h, w, 3)`` or ``(h, w, 4)`` uint8, top row first) at
    ``fps`` into ``path`` (the format by its suffix). gif and webp loop forever; gif stores
    frame times in 10 ms steps, so its rate is the nearest one that can."""
    suffix = clip_suffix(path)
    rgb = [np.ascontiguousarray(f[..., :3]) for f in frames]
    if suffix in CODECS:
        import imageio.v2 as iio2

        writer = iio2.get_writer(
            path,
            format="FFMPEG",
            fps=fps,
            codec=CODECS[suffix],
            macro_block_size=1,  # sizes are checked even: no silent resize
            pixelformat="yuv420p",  # what every browser and player decodes
            output_params=["-crf", "30", "-b:v", "0"] if suffix == ".webm" else None,
            ffmpeg_log_level="error",
        )
        try:
            for f in rgb:
                writer.append_data(f)
        finally:
            writer.close()
    else:
        import imageio.v3 as iio

        duration = 1000.0 / fps
        if suffix == ".gif":
            duration = 10.0 * max(round(duration / 10.0), 2)
        iio.imwrite(
            path, np.stack(rgb), extension=suffix, duration=round(duration), loop=0,
            is_batch=True,
        )  # fmt: skip


def orbit_camera_eyes(eye: NDArray[np.float64], target: NDArray[np.float64], n: int
                      ) -> NDArray[np.float64]:  # fmt: skip
    """``(n, 3)`` eyes turned once about the vertical through ``target``, frame ``k`` at
    ``2 pi k / n`` (frame ``n`` would be frame 0 again: the orbit loops)."""
    a = 2 * np.pi * np.arange(n) / n
    rel = eye - target
    c, s = np.cos(a), np.sin(a)
    x = c * rel[0] + s * rel[2]
    z = -s * rel[0] + c * rel[2]
    return np.stack([target[0] + x, np.full(n, eye[1]), target[2] + z], axis=1)
