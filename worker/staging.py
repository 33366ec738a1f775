"""Staging around the forest: a sky gradient behind it and a ground under it (issue 11).

Both are drawn first, into the renderer's framebuffer: the sky without depth, the ground with
it, so trees (whose bases stand at y = 0) and their leaf clouds cover them where they should.
The ground is a square at y = 0 centred under the camera's target,
:data:`worker.camera.GROUND_SPAN` camera-target distances to either side, shaded with the
bark's sun, sky ambient and fog (shaders ``ground.*``, ``sky.*``). No shadows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from forest.geometry.transforms import F64
from worker import shaders
from worker.camera import GROUND_SPAN, Camera, look_at

if TYPE_CHECKING:
    import moderngl

ZENITH = np.array([0.16, 0.30, 0.62])  # linear


@dataclass(frozen=True)
class Staging:
    """What to draw around the scene: ``ground`` (the meadow at y = 0) and ``sky`` (a
    gradient instead of the flat sky colour)."""

    ground: bool = True
    sky: bool = True


def _set(prog: moderngl.Program, values: dict[str, Any]) -> None:
    for name, value in values.items():
        if name in prog:
            cast("moderngl.Uniform", prog[name]).value = value


class StageRenderer:
    """Draws :class:`Staging` for a camera into the bound framebuffer; attribute-less draws."""

    def __init__(self, ctx: moderngl.Context, staging: Staging) -> None:
        import moderngl

        self.ctx = ctx
        self.staging = staging
        self._mgl = moderngl
        make: Any = ctx.program
        self.programs: dict[str, moderngl.Program] = {}
        self.vaos: dict[str, moderngl.VertexArray] = {}
        for name, wanted in (("sky", staging.sky), ("ground", staging.ground)):
            if wanted:
                prog = make(**shaders.sources(name))
                self.programs[name] = prog
                self.vaos[name] = ctx.vertex_array(prog, [])

    def draw(self, camera: Camera, sun: F64, sky: F64, fog: float) -> None:
        """Sky, then ground; leaves depth testing on, as the branch pass wants it."""
        mgl, ctx = self._mgl, self.ctx
        if "sky" in self.programs:
            rows = look_at(camera.eye, camera.target)[:3, :3]  # right, up, back
            tan_v = float(np.tan(np.deg2rad(camera.fov_y) / 2))
            _set(
                self.programs["sky"],
                {
                    "u_right": tuple(rows[0]),
                    "u_up": tuple(rows[1]),
                    "u_forward": tuple(-rows[2]),
                    "u_tan_half": (tan_v * camera.aspect, tan_v),
                    "u_sky": tuple(sky),
                    "u_zenith": tuple(ZENITH),
                },
            )
            ctx.disable(mgl.DEPTH_TEST)
            self.vaos["sky"].render(mgl.TRIANGLES, vertices=3)
        ctx.enable(mgl.DEPTH_TEST)
        if "ground" in self.programs:
            prog = self.programs["ground"]
            dist = float(np.linalg.norm(camera.target - camera.eye))
            _set(
                prog,
                {
                    "u_centre": (float(camera.target[0]), float(camera.target[2])),
                    "u_half": GROUND_SPAN * dist,
                    "u_camera": tuple(camera.eye),
                    "u_sun": tuple(sun),
                    "u_sky": tuple(sky),
                    "u_fog": fog,
                },
            )
            vp = camera.view_projection().T.astype("f4")
            cast("moderngl.Uniform", prog["u_view_projection"]).write(vp.tobytes())
            self.vaos["ground"].render(mgl.TRIANGLE_STRIP, vertices=4)

    def release(self) -> None:
        for vao in self.vaos.values():
            vao.release()
        for prog in self.programs.values():
            prog.release()
        self.vaos.clear()
        self.programs.clear()
