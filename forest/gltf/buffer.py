"""The GLB's binary chunk: numpy arrays appended as buffer views with typed accessors."""

from __future__ import annotations

from typing import Any

import numpy as np
import pygltflib as gl
from numpy.typing import NDArray

ALIGN = 4  # every view starts on 4 bytes: the largest component (float32, uint32) we write
_COMPONENT = {
    np.dtype(np.int8): gl.BYTE,
    np.dtype(np.uint8): gl.UNSIGNED_BYTE,
    np.dtype(np.int16): gl.SHORT,
    np.dtype(np.uint16): gl.UNSIGNED_SHORT,
    np.dtype(np.uint32): gl.UNSIGNED_INT,
    np.dtype(np.float32): gl.FLOAT,
}
_TYPE = {1: gl.SCALAR, 2: gl.VEC2, 3: gl.VEC3, 4: gl.VEC4, 16: gl.MAT4}


class Blob:
    """Appends data to ``gltf``'s single buffer; :meth:`finish` sets the binary blob."""

    def __init__(self, gltf: gl.GLTF2) -> None:
        self.gltf = gltf
        # one growing buffer, not a list joined at the end: the join held the forest's
        # binary data twice (three times with the padding) at the writer's peak
        self.data = bytearray()

    @property
    def size(self) -> int:
        return len(self.data)

    def view(self, data: bytes, target: int | None = None) -> int:
        """A buffer view of ``data`` (padded to :data:`ALIGN`); its index."""
        self.data += b"\0" * (-self.size % ALIGN)
        self.gltf.bufferViews.append(
            gl.BufferView(buffer=0, byteOffset=self.size, byteLength=len(data), target=target)
        )
        self.data += data
        return len(self.gltf.bufferViews) - 1

    def accessor(
        self,
        array: NDArray[Any],
        target: int | None = None,
        bounds: bool = False,
        view: int | None = None,
        offset: int = 0,
        normalized: bool = False,
    ) -> int:
        """An accessor of ``array`` ``(n,)``, ``(n, c)`` or ``(n, 4, 4)`` (matrices given
        column-vector and written column-major, as glTF reads them); its index. ``bounds``
        writes min/max (required on POSITION and animation inputs). With ``view`` the data
        already lies there at ``offset`` bytes (``array`` still gives type, count, bounds).
        ``normalized``: integers read as fractions of their type's maximum."""
        a = np.ascontiguousarray(array)
        if a.ndim == 3:
            a = np.ascontiguousarray(np.swapaxes(a, 1, 2)).reshape(len(a), 16)
        width = 1 if a.ndim == 1 else a.shape[1]
        if view is None:
            view = self.view(a.tobytes(), target)
        acc = gl.Accessor(
            bufferView=view,
            byteOffset=offset or None,
            componentType=_COMPONENT[a.dtype],
            count=len(a),
            type=_TYPE[width],
            normalized=True if normalized else None,
        )
        if bounds:
            flat = a.reshape(len(a), width)
            cast = float if a.dtype.kind == "f" else int
            acc.min = [cast(v) for v in flat.min(axis=0)]
            acc.max = [cast(v) for v in flat.max(axis=0)]
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def image(self, png: bytes, name: str) -> int:
        """A PNG image stored in the buffer; its index in ``images``."""
        view = self.view(png)
        self.gltf.images.append(gl.Image(bufferView=view, mimeType="image/png", name=name))
        return len(self.gltf.images) - 1

    def texture(self, png: bytes, name: str, *, repeat: bool = False) -> int:
        """A mip-mapped texture of a PNG stored in the buffer, clamped at its edges or
        (``repeat``) tiling; its index in ``textures``."""
        source = self.image(png, name)
        wrap = gl.REPEAT if repeat else gl.CLAMP_TO_EDGE
        self.gltf.samplers.append(
            gl.Sampler(
                magFilter=gl.LINEAR,
                minFilter=gl.LINEAR_MIPMAP_LINEAR,
                wrapS=wrap,
                wrapT=wrap,
            )
        )
        self.gltf.textures.append(
            gl.Texture(sampler=len(self.gltf.samplers) - 1, source=source, name=name)
        )
        return len(self.gltf.textures) - 1

    def finish(self) -> None:
        self.data += b"\0" * (-self.size % ALIGN)
        self.gltf.buffers = [gl.Buffer(byteLength=self.size)]
        # the bytearray itself (pygltflib keeps what it is given), no copy
        self.gltf.set_binary_blob(self.data)
