"""Tropisms: each piece's hub bend turned toward the vertical (gravitropism) and the light.
A piece's axis depends on every bend below it, so the bends are found level by level inside
one forward-kinematics pass of the palette."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from forest.geometry import affine
from forest.geometry.pieces import PieceArrays
from forest.geometry.transforms import F64
from forest.growth.expand import PieceGraph
from forest.growth.pose import PoseParams
from forest.growth.poser import Poser
from forest.growth.skeleton import Bones


def apply_tropisms(
    graph: PieceGraph,
    bones: Bones,
    pieces: tuple[PieceArrays, ...],
    tree_transforms: F64,
    transforms: F64,
    pose: PoseParams,
    alt_tropism: F64,
) -> tuple[PoseParams, F64]:
    """The pose with each piece's hub bend turned toward the vertical (gravitropism) and the
    light (outward from its trunk, 45 degrees up) by the fractions ``alt_tropism`` ``(A, 2)``
    of the angles between the piece's axis and those directions, and its palette (no wind).

    A piece's axis depends on every bend below it, so the bends are found level by level
    inside one forward-kinematics pass of the palette (the same closed forms, so what is
    measured is what is drawn)."""
    out = replace(pose, bend_azimuth=pose.bend_azimuth.copy(), bend_angle=pose.bend_angle.copy())
    strength = np.take(alt_tropism, graph.alt, axis=0)
    centre = tree_transforms[:, :3, 3]

    def bend_level(idx: NDArray[np.intp], root: F64) -> None:
        gravity, light = strength[idx, 0], strength[idx, 1]
        on = (gravity != 0) | (light != 0)
        if not on.any():
            return
        if not on.all():
            idx, root, gravity, light = idx[on], root[:, on], gravity[on], light[on]
        r = root[affine.LIN]  # rows r00 r01 r02 r10 ... of R, a rotation times a scale
        # the bend as a rotation vector (x, 0, z) about a horizontal axis: tilts toward the
        # vertical and the light add to it, and only the sum goes back to azimuth and angle
        cos_az, sin_az = affine.cos_sin(out.bend_azimuth[idx])
        ang = out.bend_angle[idx]
        x, z = ang * cos_az, ang * sin_az
        # the light: outward from the trunk, 45 degrees up (straight up on the trunk's axis)
        tree = graph.tree[idx]
        ox = root[3] - np.take(centre[:, 0], tree)
        oz = root[11] - np.take(centre[:, 2], tree)
        flat = np.sqrt(ox * ox + oz * oz)
        on_axis = flat < 1e-12
        h = np.where(on_axis, 0.0, 1.0 / np.where(on_axis, 1.0, flat * np.sqrt(2.0)))
        sun_y = np.where(on_axis, 1.0, np.sqrt(0.5))
        sx, sz = ox * h, oz * h
        # R^T d: each direction in the piece's frame; for d = (0, +-1, 0), R's second row
        up = np.sign(gravity)
        x, z = _tilt_toward(x, z, np.abs(gravity), up * r[3], up * r[4], up * r[5])
        if light.any():
            x, z = _tilt_toward(
                x,
                z,
                light,
                r[0] * sx + r[3] * sun_y + r[6] * sz,
                r[1] * sx + r[4] * sun_y + r[7] * sz,
                r[2] * sx + r[5] * sun_y + r[8] * sz,
            )
        out.bend_azimuth[idx] = np.arctan2(z, x)
        out.bend_angle[idx] = np.hypot(x, z)

    poser = Poser(graph, bones, pieces, tree_transforms, transforms, out)
    return out, poser.palette(level_hook=bend_level)


def _tilt_toward(x: F64, z: F64, k: F64, lx: F64, ly: F64, lz: F64) -> tuple[F64, F64]:
    """A horizontal-axis rotation vector ``(x, 0, z)`` plus the fraction ``k`` of the tilt
    that brings the piece's axis (+Y) onto the direction ``(lx, ly, lz)`` (its frame, any
    length): about ``+Y x d``, by ``k`` times the angle between them. Straight away from
    ``d`` there is no preferred side, and no tilt."""
    norm = np.sqrt(lx * lx + ly * ly + lz * lz)
    side = np.sqrt(lx * lx + lz * lz)
    off = np.arccos(np.clip(ly / np.maximum(norm, 1e-300), -1.0, 1.0))
    turn = np.where(side > 1e-9 * norm, k * off / np.maximum(side, 1e-300), 0.0)
    return x + turn * lz, z - turn * lx
