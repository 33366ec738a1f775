"""A perspective camera (column-vector numpy matrices, like the rest of the library) and an
automatic framing of an axis-aligned box."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from forest.geometry.transforms import F64

UP = np.array([0.0, 1.0, 0.0])  # the scene contract's upAxis = Y
# margin around the framed box, as a fraction of the distance that just fits it
FRAME_MARGIN = 0.06


@dataclass(frozen=True)
class Camera:
    """eye, target : (3,) float64 world; fov_y in degrees; aspect = width / height."""

    eye: F64
    target: F64
    fov_y: float = 40.0
    aspect: float = 1.0
    near: float = 0.1
    far: float = 1000.0

    @property
    def forward(self) -> F64:
        f = self.target - self.eye
        return f / np.linalg.norm(f)

    def view(self) -> F64:
        """``(4, 4)`` world -> eye (right-handed, looking down -Z)."""
        return look_at(self.eye, self.target)

    def projection(self) -> F64:
        """``(4, 4)`` eye -> clip, OpenGL depth range [-1, 1]."""
        return perspective(self.fov_y, self.aspect, self.near, self.far)

    def view_projection(self) -> F64:
        return self.projection() @ self.view()

    def frustum_planes(self) -> F64:
        """``(6, 4)`` world-space planes (unit normal, offset) of the view frustum, inside where
        ``n . x + d >= 0``: left, right, bottom, top, near, far (Gribb and Hartmann)."""
        m = self.view_projection()
        planes = np.stack(
            [m[3] + m[0], m[3] - m[0], m[3] + m[1], m[3] - m[1], m[3] + m[2], m[3] - m[2]]
        )
        return planes / np.linalg.norm(planes[:, :3], axis=1, keepdims=True)


def look_at(eye_in: ArrayLike, target_in: ArrayLike, up_in: ArrayLike = UP) -> F64:
    eye = np.asarray(eye_in, dtype=np.float64)
    f = np.asarray(target_in, dtype=np.float64) - eye
    f /= np.linalg.norm(f)
    up = np.asarray(up_in, dtype=np.float64)
    if abs(np.dot(f, up)) > 0.999:  # looking straight up or down: any horizontal up
        up = np.array([0.0, 0.0, -1.0])
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> F64:
    t = 1.0 / np.tan(np.deg2rad(fov_y_deg) / 2)
    m = np.zeros((4, 4))
    m[0, 0] = t / aspect
    m[1, 1] = t
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def box_corners(lo: F64, hi: F64) -> F64:
    """``(8, 3)`` corners of the box ``[lo, hi]``."""
    sel = np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1).T
    return np.where(sel == 1, hi, lo)


def frame_box(
    lo_in: ArrayLike,
    hi_in: ArrayLike,
    aspect: float,
    fov_y: float = 40.0,
    azimuth_deg: float = 35.0,
    elevation_deg: float = 18.0,
) -> Camera:
    """A camera framing the eight corners of the box ``[lo, hi]`` (see :func:`frame_points`)."""
    lo = np.asarray(lo_in, dtype=np.float64)
    hi = np.asarray(hi_in, dtype=np.float64)
    return frame_points(box_corners(lo, hi), aspect, fov_y, azimuth_deg, elevation_deg)


def frame_points(
    points_in: ArrayLike,
    aspect: float,
    fov_y: float = 40.0,
    azimuth_deg: float = 35.0,
    elevation_deg: float = 18.0,
) -> Camera:
    """A camera looking at the centre of the points' box from ``azimuth`` (about +Y, from +Z)
    and ``elevation``, at the least distance at which every point is in view.

    For a point at ``r`` from the target, with the camera at distance ``D`` on the unit
    vector ``b``: its depth is ``D - r.b``, and it is in view when ``|r.s| <= depth * tan(h/2)``
    and ``|r.u| <= depth * tan(v/2)``; so ``D = max(|r.s| / tan(h/2), |r.u| / tan(v/2)) + r.b``
    over the points.
    """
    pts = np.asarray(points_in, dtype=np.float64).reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    target = 0.5 * (lo + hi)
    az, el = np.deg2rad(azimuth_deg), np.deg2rad(elevation_deg)
    back = np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])
    rot = look_at(target + back, target)[:3, :3]  # rows: right, up, back
    rel = (pts - target) @ rot.T
    tan_v = np.tan(np.deg2rad(fov_y) / 2)
    tan_h = tan_v * aspect
    need = np.maximum(np.abs(rel[:, 0]) / tan_h, np.abs(rel[:, 1]) / tan_v) + rel[:, 2]
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    dist = max(float(need.max()) * (1 + FRAME_MARGIN), 1e-3 + radius * 1e-3)
    depth = dist - rel[:, 2]
    near = max(float(depth.min()) * 0.5, dist * 1e-3)
    far = float(depth.max()) * 2.0 + 1.0
    return Camera(
        eye=target + dist * back, target=target, fov_y=fov_y, aspect=aspect, near=near, far=far
    )
