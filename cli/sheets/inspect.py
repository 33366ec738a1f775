"""``forest inspect``: a diagnostic contact sheet of a scene, drawn offscreen with pyvista.

Four panels from one camera: the skeleton (joints and bones as lines over a ghost of the
bark), the quads coloured by tile class with every rim highlighted, the quads coloured by
their tile index (texture-array slice), and the pieces coloured by type. The bark is skinned
here in numpy with the scene's palette, so the sheet shows what the scene says, independent of
the GL renderer.

VTK draws through EGL when there is no X display (``VTK_DEFAULT_OPENGL_WINDOW``), so this
works on a headless machine with Mesa's EGL, like the renderer.

VTK terminates the process's EGL display when its window goes, and with it every other EGL
context of the process: draw sheets in a process that renders nothing else with moderngl
(``forest inspect`` is one).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from forest.bark.images import write_png
from forest.extras import MissingExtraError
from forest.geometry.transforms import F64
from forest.gl.context import INSTALL_EGL, GLUnavailableError
from forest.usd.read import SceneArrays
from worker.render.camera import Camera, frame_points
from worker.render.scene_buffers import scene_points

I64 = NDArray[np.int64]
TILE_CLASS_COLOURS = {1: "#8c5a32", 2: "#f0a020"}  # bark, fork
TYPE_COLOURS = ("#4c72b0", "#55a868", "#c44e52", "#8172b2", "#ccb974", "#64b5cd")
RIM_COLOUR = "#e8102a"
BACKGROUND = "#f4f4f0"
# above this many instances the sheet shows the first whole trees that fit
MAX_INSTANCES = 20_000


@dataclass(frozen=True, eq=False)
class SkinnedForest:
    """The forest's bark, skinned, as one quad mesh (one cell per quad of every instance).

    points : (v, 3) float64       quads : (q, 4) int64 into points
    instance, quad, piece_type, tile_class, tile : (q,) int64, per cell
    rims : (r, 6) int64 into points, every rim loop of every instance
    joints : (j, 3) float64       bones : (k, 2) int64 into joints (parent, child)
    """

    points: F64
    quads: I64
    instance: I64
    quad: I64
    piece_type: I64
    tile_class: I64
    tile: I64
    rims: I64
    joints: F64
    bones: I64


def skin_forest(scene: SceneArrays, frame: int = 0, limit: int = MAX_INSTANCES) -> SkinnedForest:
    """Linear blend skinning of every instance (of the first trees, past ``limit``)."""
    pal = scene.palette(frame)
    keep = np.arange(scene.n_instances)
    if scene.n_instances > limit:
        last_tree = scene.tree[limit - 1]
        keep = np.nonzero(scene.tree < last_tree)[0] if last_tree > 0 else keep[:limit]
    pts, quads, inst, quad, ptype, tclass, tile, rims = ([] for _ in range(8))
    joints, bones = [], []
    base = jbase = 0
    for t, piece in enumerate(scene.pieces):
        idx = keep[scene.proto_indices[keep] == t]
        if not len(idx):
            continue
        m, nv, nq = len(idx), len(piece.positions), len(piece.quads)
        blend = np.einsum(
            "vk,mvkab->mvab",
            piece.joint_weights,
            pal[scene.bone_offset[idx][:, None, None] + piece.joint_indices[None]],
        )
        p = np.einsum("mvab,vb->mva", blend[..., :3, :3], piece.positions) + blend[..., :3, 3]
        pts.append(p.reshape(-1, 3))
        starts = base + nv * np.arange(m)
        quads.append((starts[:, None, None] + piece.quads[None]).reshape(-1, 4))
        inst.append(np.repeat(idx, nq))
        quad.append(np.tile(np.arange(nq), m))
        ptype.append(np.full(m * nq, t))
        tclass.append(np.tile(piece.tile_class, m))
        tile.append(scene.tile_indices[idx, :nq].reshape(-1))
        loops = np.concatenate([piece.root_rim[None], piece.leaf_rims])
        rims.append((starts[:, None, None] + loops[None]).reshape(-1, 6))
        # joint j of an instance sits at palette[offset + j] @ rest_j (a skinning matrix is
        # global @ inverse(rest))
        g = pal[scene.bone_offset[idx][:, None] + np.arange(piece.n_joints)] @ piece.joint_rest
        joints.append(g[..., :3, 3].reshape(-1, 3))
        child = np.nonzero(piece.joint_parents >= 0)[0]
        jstarts = jbase + piece.n_joints * np.arange(m)
        pairs = np.stack([piece.joint_parents[child], child], axis=-1)
        bones.append((jstarts[:, None, None] + pairs[None]).reshape(-1, 2))
        base += m * nv
        jbase += m * piece.n_joints
    cat = np.concatenate
    return SkinnedForest(
        points=cat(pts),
        quads=cat(quads).astype(np.int64),
        instance=cat(inst).astype(np.int64),
        quad=cat(quad).astype(np.int64),
        piece_type=cat(ptype).astype(np.int64),
        tile_class=cat(tclass).astype(np.int64),
        tile=cat(tile).astype(np.int64),
        rims=cat(rims).astype(np.int64),
        joints=cat(joints),
        bones=cat(bones).astype(np.int64),
    )


def _pyvista() -> Any:
    if not os.environ.get("DISPLAY"):
        # headless: let VTK open an EGL window instead of failing on X first
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    try:
        import pyvista
    except ImportError:
        raise MissingExtraError("inspect", "pyvista", path="pyvista") from None
    pyvista.OFF_SCREEN = True
    return pyvista


def _cells(kind: int, conn: I64) -> NDArray[np.int64]:
    """VTK's flat cell array: ``[n, i0, .., in-1, n, ...]``."""
    return np.hstack([np.full((len(conn), 1), kind), conn]).ravel()


def _loops(rims: I64) -> I64:
    """Closed rim loops as line segments ``(6 r, 2)``."""
    return np.stack([rims, np.roll(rims, -1, axis=1)], axis=-1).reshape(-1, 2)


def contact_sheet(
    scene: SceneArrays,
    output: Path,
    frame: int = 0,
    size: tuple[int, int] = (1400, 1050),
) -> Path:
    """Draw the four panels into ``output`` (PNG)."""
    pv = _pyvista()
    sk = skin_forest(scene, frame)
    cam = frame_points(scene_points(scene, frame), size[0] / size[1], elevation_deg=14.0)
    mesh = pv.PolyData(sk.points, _cells(4, sk.quads))
    mesh.cell_data["tile class"] = sk.tile_class
    mesh.cell_data["tile index"] = sk.tile
    mesh.cell_data["piece type"] = sk.piece_type
    rims = pv.PolyData(sk.points, lines=_cells(2, _loops(sk.rims)))
    skeleton = pv.PolyData(sk.joints, lines=_cells(2, sk.bones))
    names = [p.name for p in scene.pieces]
    try:
        plotter = pv.Plotter(off_screen=True, shape=(2, 2), window_size=list(size), border=False)
    except Exception as exc:  # VTK raises plain RuntimeErrors when no window can be opened
        raise GLUnavailableError(
            f"VTK cannot open an offscreen window ({exc}): {INSTALL_EGL}", path="gl.egl"
        ) from None
    try:
        plotter.set_background(BACKGROUND)
        used_types = sorted(set(sk.piece_type.tolist()))
        used_classes = sorted(set(sk.tile_class.tolist()))
        panels = [
            ("skeleton: joints and bones", None),
            ("tile classes (bark brown, fork orange), rims red", "tile class"),
            (f"tile index: {len(set(sk.tile.tolist()))} texture-array slices in use", "tile index"),
            ("piece types: " + ", ".join(names[t] for t in used_types), "piece type"),
        ]
        for k, (title, scalars) in enumerate(panels):
            plotter.subplot(k // 2, k % 2)
            if scalars is None:
                plotter.add_mesh(mesh, color="#b8a898", opacity=0.18, show_scalar_bar=False)
                plotter.add_mesh(skeleton, color="#1b3a6b", line_width=2.5)
                plotter.add_mesh(pv.PolyData(sk.joints), color="#d62728", point_size=3,
                                 render_points_as_spheres=True)  # fmt: skip
            elif scalars == "tile class":
                colours = [TILE_CLASS_COLOURS.get(c, "#999999") for c in used_classes]
                plotter.add_mesh(mesh, scalars=scalars, cmap=colours, categories=True,
                                 show_scalar_bar=False, show_edges=True, edge_color="#5a4634",
                                 line_width=0.5)  # fmt: skip
                plotter.add_mesh(rims, color=RIM_COLOUR, line_width=3)
            elif scalars == "tile index":
                plotter.add_mesh(mesh, scalars=scalars, cmap="tab20", show_scalar_bar=False)
            else:
                colours = [TYPE_COLOURS[t % len(TYPE_COLOURS)] for t in used_types]
                plotter.add_mesh(mesh, scalars=scalars, cmap=colours, categories=True,
                                 show_scalar_bar=False)  # fmt: skip
            # pixel-sized text at a viewport position (corner annotations rescale with length)
            plotter.add_text(title, position=(0.02, 0.92), viewport=True, font_size=8,
                             color="black")  # fmt: skip
            _use_camera(plotter, cam)
        plotter.add_text(
            f"{Path(scene.path).name}: {scene.n_instances} pieces, "
            f"{len(np.unique(scene.tree))} tree(s), frame {frame}",
            position=(0.02, 0.02),
            viewport=True,
            font_size=7,
            color="#333333",
        )
        image = np.asarray(plotter.screenshot(None, return_img=True))
    finally:
        plotter.close()
    rgba = image if image.shape[-1] == 4 else np.dstack([image, np.full(image.shape[:2], 255)])
    return write_png(output, rgba.astype(np.uint8))


def _use_camera(plotter: Any, cam: Camera) -> None:
    plotter.camera.position = tuple(cam.eye)
    plotter.camera.focal_point = tuple(cam.target)
    plotter.camera.up = (0.0, 1.0, 0.0)
    plotter.camera.view_angle = cam.fov_y
    plotter.reset_camera_clipping_range()
