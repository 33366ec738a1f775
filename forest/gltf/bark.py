"""Bark in glTF: the PBR metallic-roughness material reading the tile set's atlas
(:mod:`forest.bark.atlas`, shared with the .usdz's pictures), and PNG bytes of a picture."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pygltflib as gl
from numpy.typing import NDArray

from forest.bark.images import write_png
from forest.gltf.buffer import Blob

ROUGHNESS = 0.9


def png_bytes(pixels: NDArray[np.uint8]) -> bytes:
    """``(h, w, c)`` uint8 as PNG bytes (through :func:`forest.bark.images.write_png`: fixed
    metadata, so equal pixels give equal bytes)."""
    with tempfile.TemporaryDirectory(prefix="forest-gltf-") as tmp:
        path = Path(tmp) / "image.png"
        write_png(path, pixels)
        return path.read_bytes()


def add_bark_material(
    gltf: gl.GLTF2, blob: Blob, picture: NDArray[np.uint8], name: str, *, repeat: bool = False
) -> int:
    """The bark material (base colour from ``picture``: the atlas, or a super tile that
    ``repeat``s; not metallic, rough); its index."""
    texture = blob.texture(png_bytes(picture), f"bark-{name}", repeat=repeat)
    gltf.materials.append(
        gl.Material(
            name="Bark",
            pbrMetallicRoughness=gl.PbrMetallicRoughness(
                baseColorTexture=gl.TextureInfo(index=texture),
                metallicFactor=0.0,
                roughnessFactor=ROUGHNESS,
            ),
        )
    )
    return len(gltf.materials) - 1
