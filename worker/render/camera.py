"""A perspective camera (column-vector numpy matrices, like the rest of the library) and an
automatic framing of an axis-aligned box."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from forest.errors import ForestError
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
    target_in: ArrayLike | None = None,
) -> Camera:
    """A camera looking at ``target`` (default: the centre of the points' box) from
    ``azimuth`` (about +Y, from +Z) and ``elevation``, at the least distance at which every
    point is in view.

    For a point at ``r`` from the target, with the camera at distance ``D`` on the unit
    vector ``b``: its depth is ``D - r.b``, and it is in view when ``|r.s| <= depth * tan(h/2)``
    and ``|r.u| <= depth * tan(v/2)``; so ``D = max(|r.s| / tan(h/2), |r.u| / tan(v/2)) + r.b``
    over the points.
    """
    pts = np.asarray(points_in, dtype=np.float64).reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    target = 0.5 * (lo + hi) if target_in is None else np.asarray(target_in, dtype=np.float64)
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


# -- placeable cameras ---------------------------------------------------------------------------

VIEWS = ("overview", "side", "eye")
OVERVIEW_ELEVATION = 18.0
EYE_HEIGHT = 1.7  # metres: a standing person's eyes
# the ground quad spans this many camera-target distances around the target (fogged to ~97 %
# at its edge), and the far plane reaches past it
GROUND_SPAN = 30.0


def _triple(value: object, path: str) -> F64:
    try:
        v = np.asarray(value, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise ForestError("expected three numbers X,Y,Z in metres", path=path) from None
    if not np.isfinite(v).all():
        raise ForestError(f"must be finite, got {value!r}", path=path)
    return v


@dataclass(frozen=True)
class CameraSpec:
    """Where the camera goes: a named view of the scene, or an explicit eye and target.

    ``overview``: the scene's box from ``azimuth`` (about +Y, from +Z) and 18 degrees up, at
    the least distance that shows everything (the default, as it always was). ``side``: the
    same at 0 degrees, so the camera looks horizontally at mid-height. ``eye``: eyes 1.7 m
    above the ground, ``distance`` metres (horizontally) from the scene's centre, looking at
    that centre; without ``distance``, the least distance that shows everything. ``eye`` and
    ``target`` (metres, Y up) given together override the view; ``fov`` is vertical, degrees.
    ``tree``: the view frames that tree of the scene alone (a close-up), not the forest, with
    its silhouette (not its box's centre) in the middle of the image.
    """

    view: str = "overview"
    eye: tuple[float, float, float] | None = None
    target: tuple[float, float, float] | None = None
    fov: float = 40.0
    distance: float | None = None
    azimuth: float = 35.0
    tree: int | None = None

    def check(self) -> None:
        if self.view not in VIEWS:
            raise ForestError(f"must be one of {', '.join(VIEWS)}, got {self.view!r}", path="view")
        if (self.eye is None) != (self.target is None):
            raise ForestError(
                "give --eye and --target together", path="eye" if self.eye is None else "target"
            )
        if self.eye is not None and self.target is not None:
            eye, target = _triple(self.eye, "eye"), _triple(self.target, "target")
            if np.linalg.norm(target - eye) < 1e-6:
                raise ForestError("must differ from the eye", path="target")
        if not (np.isfinite(self.fov) and 1.0 <= self.fov <= 170.0):
            raise ForestError(f"must be in [1, 170] degrees, got {self.fov}", path="fov")
        if self.distance is not None and not (np.isfinite(self.distance) and self.distance > 0):
            raise ForestError(f"must be > 0 metres, got {self.distance}", path="distance")
        if self.tree is not None and self.tree < 0:
            raise ForestError(f"must be >= 0, got {self.tree}", path="tree")
        if not np.isfinite(self.azimuth):
            raise ForestError(f"must be finite, got {self.azimuth}", path="azimuth")


def _clip_planes(eye: F64, forward: F64, points: F64, dist: float) -> tuple[float, float]:
    """``(near, far)`` enclosing ``points`` seen from ``eye`` along ``forward``."""
    depth = (points - eye) @ forward
    ahead = depth[depth > 0]
    near = max(float(ahead.min()) * 0.5 if len(ahead) else 0.0, dist * 1e-3, 1e-3)
    far = max(float(depth.max()) * 2.0 + 1.0 if len(depth) else 0.0, near * 10)
    return near, far


def with_ground(camera: Camera, floor: float = 0.0) -> Camera:
    """``camera`` with clip planes that keep the ground quad (:data:`GROUND_SPAN`): the far
    plane past its edge, the near plane before the nearest ground point in view (no nearer
    than the eye's height above ``floor``, at most the half-diagonal field off the view
    axis)."""
    dist = float(np.linalg.norm(camera.target - camera.eye))
    far = max(camera.far, 1.5 * (GROUND_SPAN + 1) * dist)
    tan_v = np.tan(np.deg2rad(camera.fov_y) / 2)
    cos_diag = float(np.cos(np.arctan(tan_v * np.hypot(1.0, camera.aspect))))
    height = abs(float(camera.eye[1]) - floor)
    near = min(camera.near, max(0.9 * height * cos_diag, dist * 1e-3, 1e-3))
    return Camera(camera.eye, camera.target, camera.fov_y, camera.aspect, near, far)


def place_camera(
    spec: CameraSpec,
    points_in: ArrayLike,
    aspect: float,
    ground: bool = False,
    floor: Callable[[F64, F64], F64] | None = None,
) -> Camera:
    """The camera ``spec`` asks for, for a scene enclosed by ``points`` (``(m, 3)`` world);
    ``ground`` fits the clip planes to the ground quad too (:func:`with_ground`). A close-up
    (``spec.tree``, ``points`` being that tree's) is :func:`centred` on its silhouette.
    ``floor``: the ground's height under ``(x, z)`` (a mixed forest's terrain; default 0):
    the ``eye`` view's eyes are EYE_HEIGHT above it, and the near plane keeps it in view."""
    spec.check()
    pts = np.asarray(points_in, dtype=np.float64).reshape(-1, 3)
    if spec.eye is not None and spec.target is not None:
        eye, target = _triple(spec.eye, "eye"), _triple(spec.target, "target")
        dist = float(np.linalg.norm(target - eye))
        near, far = _clip_planes(eye, (target - eye) / dist, pts, dist)
        cam = Camera(eye, target, spec.fov, aspect, near, far)
    else:
        if spec.view == "eye":

            def aim(target: F64 | None) -> Camera:
                return _eye_level(spec, pts, aspect, target, floor)
        else:
            elevation = OVERVIEW_ELEVATION if spec.view == "overview" else 0.0

            def aim(target: F64 | None) -> Camera:
                return frame_points(pts, aspect, spec.fov, spec.azimuth, elevation, target)

        cam = aim(None) if spec.tree is None else centred(aim, pts)
    if not ground:
        return cam
    if floor is None:
        return with_ground(cam)
    under = float(np.asarray(floor(np.asarray(cam.eye[0]), np.asarray(cam.eye[2]))))
    return with_ground(cam, under)


def centred(aim: Callable[[F64 | None], Camera], pts: F64, steps: int = 12) -> Camera:
    """The camera ``aim(target)`` gives, its target moved across the view until the points'
    projected extent is centred in the image. Aiming at the centre of the points' world box
    does not do that: seen obliquely, a lopsided crown fills its box unevenly (a box corner
    may be empty), and perspective enlarges the near side; so pan by the extent's offset
    (NDC times the half-field at the target's depth) and refit, a few times."""
    cam = aim(None)
    for _ in range(steps):
        clip = np.c_[pts, np.ones(len(pts))] @ cam.view_projection().T
        ndc = clip[:, :2] / clip[:, 3:]
        off = 0.5 * (ndc.min(axis=0) + ndc.max(axis=0))
        if np.abs(off).max() < 1e-3:
            break
        rot = look_at(cam.eye, cam.target)[:3, :3]  # rows: right, up, back
        half_v = float(np.linalg.norm(cam.target - cam.eye)) * np.tan(np.deg2rad(cam.fov_y) / 2)
        cam = aim(cam.target + off[0] * half_v * cam.aspect * rot[0] + off[1] * half_v * rot[1])
    return cam


def _eye_level(
    spec: CameraSpec,
    pts: F64,
    aspect: float,
    target_in: F64 | None = None,
    floor: Callable[[F64, F64], F64] | None = None,
) -> Camera:
    """Eyes at :data:`EYE_HEIGHT` looking at ``target`` (default: the centre of the points'
    box) from ``azimuth``,
    at ``spec.distance`` or else the least horizontal distance (found by bisection on the
    box's corners: wider is always better) that shows the whole box with the frame margin."""
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    target = 0.5 * (lo + hi) if target_in is None else target_in
    az = np.deg2rad(spec.azimuth)
    back = np.array([np.sin(az), 0.0, np.cos(az)])
    corners = box_corners(lo, hi)

    def at(d: float) -> Camera:
        eye = np.array([target[0], EYE_HEIGHT, target[2]]) + d * back
        if floor is not None:  # standing on the terrain
            eye[1] += float(np.asarray(floor(np.asarray(eye[0]), np.asarray(eye[2]))))
        return Camera(eye, target, spec.fov, aspect)

    def fits(d: float) -> bool:
        clip = np.c_[corners, np.ones(8)] @ at(d).view_projection().T
        w = clip[:, 3]
        return bool(
            (w > 0).all() and (np.abs(clip[:, :2]) <= w[:, None] / (1 + FRAME_MARGIN)).all()
        )

    if spec.distance is not None:
        d = spec.distance
    else:
        radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-2)
        lo_d, hi_d = 0.0, radius
        while not fits(hi_d) and hi_d < 1e6:
            lo_d, hi_d = hi_d, hi_d * 2
        for _ in range(40):
            mid = 0.5 * (lo_d + hi_d)
            lo_d, hi_d = (lo_d, mid) if fits(mid) else (mid, hi_d)
        d = hi_d
    cam = at(d)
    dist = float(np.linalg.norm(cam.target - cam.eye))
    near, far = _clip_planes(cam.eye, cam.forward, pts, dist)
    return Camera(cam.eye, cam.target, spec.fov, aspect, near, far)


def project(camera: Camera, points_in: ArrayLike, size: tuple[int, int]) -> F64:
    """``(m, 2)`` pixel coordinates (x right, y down from the top-left corner, pixel centres at
    half-integers) of world points ``(m, 3)`` in an image of ``size = (width, height)``."""
    pts = np.asarray(points_in, dtype=np.float64).reshape(-1, 3)
    clip = np.c_[pts, np.ones(len(pts))] @ camera.view_projection().T
    ndc = clip[:, :2] / clip[:, 3:4]
    w, h = size
    return np.stack([(ndc[:, 0] + 1) * 0.5 * w, (1 - ndc[:, 1]) * 0.5 * h], axis=1)
