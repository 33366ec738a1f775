"""The universal rim: a regular hexagon, and the cone its quad ring lies on (paper 4.2, 4.4).

In every piece's model space the root rim is this hexagon in the XZ plane at ``y = 0``, centred
on the origin, circumradius 1, its axis +Y. A leaf rim is the same hexagon moved by the leaf's
building transform. The quad ring next to any rim lies on a cone narrowing toward +Y with the
slope :data:`CONE_SLOPE`, so positions *and* normals of rim vertices are predetermined and two
interlocking pieces share both.
"""

from __future__ import annotations

import numpy as np

from forest.geometry.transforms import F64, rotation_y

SIDES = 6
RADIUS = 1.0
# Radius lost per unit of height on a rim cone. 3/64 is exactly representable in binary16
# and float32, so piece scales built from it survive USD's half-precision SkelAnimation scales.
CONE_SLOPE = 3.0 / 64.0
# Vertex angles start at 30 degrees so two vertices (90, 270) lie on the x = 0 plane: forks
# split the hexagon there into two halves of three edges each.
ANGLES = np.deg2rad(30.0 + 60.0 * np.arange(SIDES))


def rim_ring(height: float = 0.0, radius: float = RADIUS) -> F64:
    """``(6, 3)`` hexagon vertices at ``y = height`` with circumradius ``radius``."""
    return np.stack(
        [radius * np.cos(ANGLES), np.full(SIDES, height), radius * np.sin(ANGLES)], axis=-1
    )


def cone_ring(height: float) -> F64:
    """``(6, 3)`` ring on the rim cone at signed ``height`` above the root rim (model units)."""
    return rim_ring(height, RADIUS - CONE_SLOPE * height)


def rim_normals() -> F64:
    """``(6, 3)`` unit outward normals of the cone at the root rim's vertices."""
    n = np.stack([np.cos(ANGLES), np.full(SIDES, CONE_SLOPE), np.sin(ANGLES)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def twists() -> F64:
    """``(6, 4, 4)`` rotations about +Y by multiples of 60 degrees: the six ways a root rim
    can be laid onto a leaf rim."""
    return rotation_y(np.deg2rad(60.0 * np.arange(SIDES)))
