"""Orthographic pictures of a tree's level (bark and cut leaf cards) from given directions, in
one small GL pass (moderngl on EGL, the render extra): albedo with alpha, world normals and
depth. They make the impostor's atlas (:mod:`forest.lod.impostor`) and the side-by-side
look at the levels.

The core install has no GL: :func:`draw_views` raises
:class:`forest.gl.context.GLUnavailableError` naming the extra to install.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from forest.geometry.transforms import F64
from forest.lod.select import BarkMesh, LeavesMesh

GL_VERSION = 330  # plain vertex and fragment shaders: any EGL driver
UP = np.array([0.0, 1.0, 0.0])
ALPHA_CUT = 0.5  # the leaf materials' opacityThreshold


@dataclass(frozen=True, eq=False)
class Views:
    """Pictures of one level, one per direction.

    albedo : (v, s, s, 4) uint8 sRGB, alpha 255 where the tree is
    normal : (v, s, s, 3) uint8 world normal, 0.5 + 0.5 n
    depth : (v, s, s) float32 window depth in [0, 1] (1: nothing), along each view over
        ``2 * radius`` about ``centre``
    centre, radius : the sphere every view frames
    """

    albedo: NDArray[np.uint8]
    normal: NDArray[np.uint8]
    depth: NDArray[np.float32]
    centre: F64
    radius: float


def view_matrix(direction: F64, centre: F64, radius: float) -> F64:
    """``(4, 4)`` orthographic view-projection looking at ``centre`` from ``direction``
    (towards the camera), framing a sphere of ``radius``; image x to the camera's right,
    image y up (or away from the camera's side for a view straight down)."""
    d = np.asarray(direction, np.float64) / np.linalg.norm(direction)
    up = UP if abs(d[1]) < 0.999 else np.array([0.0, 0.0, -np.sign(d[1])])
    right = np.cross(up, d)
    right /= np.linalg.norm(right)
    true_up = np.cross(d, right)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = right, true_up, d
    view[:3, 3] = -view[:3, :3] @ centre
    proj = np.diag([1.0 / radius, 1.0 / radius, -1.0 / radius, 1.0])
    return proj @ view


def _soup(
    bark: BarkMesh | None, leaves: LeavesMesh | None, bark_colour: tuple[float, float, float]
) -> NDArray[np.float32]:
    """Interleaved triangle vertices: position, normal, tint, st, textured (12 floats)."""
    parts = []
    if bark is not None and len(bark.quads):
        tris = np.concatenate([bark.quads[:, [0, 1, 2]], bark.quads[:, [0, 2, 3]]]).ravel()
        n = len(tris)
        parts.append(
            np.concatenate(
                [
                    bark.points[tris],
                    bark.normals[tris],
                    np.broadcast_to(bark_colour, (n, 3)),
                    np.zeros((n, 3)),
                ],
                axis=1,
            )
        )
    if leaves is not None and len(leaves.quads):
        order = [0, 1, 2, 0, 2, 3]
        tris = leaves.quads[:, order].ravel()
        tint = np.repeat(leaves.colour, 6, axis=0)
        parts.append(
            np.concatenate(
                [
                    leaves.points[tris],
                    leaves.normals[tris],
                    tint,
                    leaves.st[tris],
                    np.ones((len(tris), 1)),
                ],
                axis=1,
            )
        )
    return np.ascontiguousarray(np.concatenate(parts), np.float32)


def draw_views(
    bark: BarkMesh | None,
    leaves: LeavesMesh | None,
    leaf_picture: NDArray[np.uint8],
    directions: F64,
    size: int,
    bark_colour: tuple[float, float, float],
    *,
    lit: bool = False,
    centre: F64 | None = None,
    radius: float | None = None,
    context: Any = None,
) -> Views:
    """One picture of ``size`` x ``size`` pixels per direction of ``directions`` (k, 3)
    (towards the camera) of the meshes (leaf cards cut by ``leaf_picture``, the family's
    RGBA picture, row 0 at t = 0), framing ``centre`` and ``radius`` (default: the meshes'
    bounding sphere). Albedo (``lit``: under a sun and sky), normals and depth.
    ``context``: a GL context to draw in and leave open, the objects drawn with living until
    it is released (else one is made and released here)."""
    from forest.gl.context import create_context
    from forest.gl.shaders import sources

    soup = _soup(bark, leaves, bark_colour)
    pts = soup[:, :3].astype(np.float64)
    if centre is None:
        centre = (pts.min(axis=0) + pts.max(axis=0)) / 2
    if radius is None:
        radius = float(np.linalg.norm(pts - centre, axis=1).max()) * 1.01
    ctx = create_context(GL_VERSION) if context is None else context
    try:
        make: Any = ctx.program  # its stubs type the keyword arguments one by one
        prog = make(**sources("lod_view", {"ALPHA_CUT": ALPHA_CUT}))
        vbo = ctx.buffer(soup.tobytes())
        vao = ctx.vertex_array(
            prog, [(vbo, "3f 3f 3f 2f 1f", "position", "normal", "tint", "st", "textured")]
        )
        tex = ctx.texture(
            leaf_picture.shape[1::-1], 4, np.ascontiguousarray(leaf_picture).tobytes()
        )
        # no mipmaps: a leaf's averaged alpha falls under the cut and whole leaves vanish at a
        # distance; the base level sampled per pixel keeps each card's true coverage
        tex.filter = (ctx.LINEAR, ctx.LINEAR)
        tex.use(0)
        prog["leaf"].value = 0
        prog["lit"].value = 1.0 if lit else 0.0
        targets = [ctx.texture((size, size), 4), ctx.texture((size, size), 4)]
        depth_target = ctx.texture((size, size), 4, dtype="f4")
        fbo = ctx.framebuffer(
            color_attachments=[*targets, depth_target],
            depth_attachment=ctx.depth_texture((size, size)),
        )
        fbo.use()
        ctx.enable(ctx.DEPTH_TEST)
        out_a, out_n, out_d = [], [], []
        for d in np.asarray(directions, np.float64):
            d = d / np.linalg.norm(d)
            m = view_matrix(d, centre, radius)
            prog["view_proj"].write(m.T.astype(np.float32).tobytes())
            prog["eye"].value = tuple(d)
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            vao.render()
            out_a.append(np.frombuffer(fbo.read(attachment=0, components=4), np.uint8))
            out_n.append(np.frombuffer(fbo.read(attachment=1, components=3), np.uint8))
            out_d.append(
                np.frombuffer(fbo.read(attachment=2, components=1, dtype="f4"), np.float32)
            )
    finally:
        if context is None:
            ctx.release()
    k = len(out_a)
    # GL's rows run bottom-up: turn them so row 0 is the picture's top
    albedo = np.stack(out_a).reshape(k, size, size, 4)[:, ::-1]
    normal = np.stack(out_n).reshape(k, size, size, 3)[:, ::-1]
    depth = np.stack(out_d).reshape(k, size, size)[:, ::-1].copy()
    depth[albedo[..., 3] == 0] = 1.0  # nothing there: the far plane
    return Views(
        np.ascontiguousarray(albedo),
        np.ascontiguousarray(normal),
        np.ascontiguousarray(depth),
        np.asarray(centre, np.float64),
        float(radius),
    )
