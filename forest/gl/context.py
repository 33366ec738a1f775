"""The one place that creates a GL context: moderngl on EGL, headless, OpenGL 4.3 or newer.

Failures become :class:`GLUnavailableError` (a ForestError, so the CLI prints one line and
exits 2) naming what is missing and how to install it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from forest.errors import ForestError
from forest.extras import install_line

if TYPE_CHECKING:
    import moderngl

# Tessellation shaders are core in 4.0; storage buffers (palette, instances, tiles) in 4.3.
REQUIRED_VERSION = 430
# storage blocks the pipeline binds per stage: vertex (instances, palette), tessellation
# evaluation (instances, tiles, capture)
REQUIRED_STORAGE_BLOCKS = {
    "GL_MAX_VERTEX_SHADER_STORAGE_BLOCKS": 2,
    "GL_MAX_TESS_EVALUATION_SHADER_STORAGE_BLOCKS": 3,
}
INSTALL_EGL = (
    "install Mesa's EGL (Debian/Ubuntu: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri "
    "libgles2) or a GPU driver that ships libEGL"
)


class GLUnavailableError(ForestError):
    """No usable GL context: EGL missing, the driver too old, or a capability lacking."""


@dataclass(frozen=True)
class GLInfo:
    renderer: str
    vendor: str
    version: str
    version_code: int
    timer_query: bool

    @property
    def software(self) -> bool:
        """Whether the renderer is a CPU rasteriser (timings say nothing about a GPU)."""
        return bool(re.search(r"llvmpipe|softpipe|swrast|lavapipe", self.renderer, re.I))


def create_context(require: int = REQUIRED_VERSION) -> moderngl.Context:
    """A standalone EGL context of at least GL ``require`` (e.g. 430)."""
    try:
        import moderngl
    except ImportError:
        raise GLUnavailableError(
            f"moderngl is not installed; it comes with the render extra: {install_line('render')}",
            path="gl",
        ) from None
    create: Any = moderngl.create_context  # its stub types ``backend`` wrongly
    # glcontext opens "libGL.so" and "libEGL.so" unless told: the -dev packages' links, which
    # a runtime image (a worker container) lacks; the sonames come with the libraries
    libs = {"libgl": "libGL.so.1", "libegl": "libEGL.so.1"}
    try:
        ctx = create(standalone=True, backend="egl", require=require, **libs)
    except Exception as exc:
        # a driver below ``require`` refuses the context outright (eglCreateContext fails):
        # ask for any context to say what the driver does have
        try:
            probe = create(standalone=True, backend="egl", **libs)
        except Exception:
            raise _explain(exc) from None
        try:
            check_capabilities(probe, require)
        finally:
            probe.release()
        raise _explain(exc) from None
    check_capabilities(ctx, require)
    return ctx


def _explain(exc: Exception) -> GLUnavailableError:
    """Turn glcontext's terse messages into what is missing and how to install it."""
    text = str(exc).strip() or type(exc).__name__
    first = text.splitlines()[0]
    low = text.lower()
    if "libegl" in low and "not loaded" in low:
        return GLUnavailableError(f"libEGL not found ({first}): {INSTALL_EGL}", path="gl.egl")
    if "libgl" in low and "not loaded" in low:
        return GLUnavailableError(
            f"libGL not found ({first}): install libgl1 (the GL dispatch library) and "
            "libgl1-mesa-dri, or a GPU driver",
            path="gl.libgl",
        )
    if "egl" in low:
        return GLUnavailableError(
            f"EGL could not open a display or context ({first}): {INSTALL_EGL}", path="gl.egl"
        )
    return GLUnavailableError(f"cannot create an EGL context ({first}): {INSTALL_EGL}", path="gl")


def check_capabilities(ctx: moderngl.Context, require: int = REQUIRED_VERSION) -> None:
    if ctx.version_code < require:
        wanted = f"{require // 100}.{require % 100 // 10}"
        raise GLUnavailableError(
            f"OpenGL {ctx.version_code // 100}.{ctx.version_code % 100 // 10} from "
            f"{ctx.info.get('GL_RENDERER', '?')} is too old, {wanted} is needed (tessellation "
            f"and storage buffers): use Mesa 20 or newer (llvmpipe gives 4.5 on the CPU) or a "
            f"GPU driver with OpenGL {wanted}",
            path="gl.version",
        )
    if require < REQUIRED_VERSION:
        return  # a caller that checks features itself (tests skip by capability)
    info: dict[str, Any] = dict(ctx.info)
    for key, need in REQUIRED_STORAGE_BLOCKS.items():
        have = int(info.get(key, 0))
        if have < need:
            raise GLUnavailableError(
                f"{key} is {have}, the renderer needs {need}", path="gl.capabilities"
            )


# moderngl reads GL_TIME_ELAPSED as a 32-bit result, which drivers saturate at 2**32 - 1 ns
# (NVIDIA's does): a pass of 4.29 s or more has no GPU time, rather than a wrong one
TIMER_SATURATED_NS = 2**32 - 1


def elapsed_ms(query: moderngl.Query) -> float | None:
    """The GPU time of a timed query in ms, or None where the 32-bit timer saturated."""
    ns = int(query.elapsed)
    return None if ns >= TIMER_SATURATED_NS else ns / 1e6


def gl_info(ctx: moderngl.Context) -> GLInfo:
    info: dict[str, Any] = ctx.info
    return GLInfo(
        renderer=str(info.get("GL_RENDERER", "unknown")),
        vendor=str(info.get("GL_VENDOR", "unknown")),
        version=str(info.get("GL_VERSION", "unknown")),
        version_code=int(ctx.version_code),
        # core since 3.3; the extension string says the driver really implements it
        timer_query="GL_ARB_timer_query" in ctx.extensions or ctx.version_code >= 330,
    )


def raise_gl_error(ctx: moderngl.Context, where: str) -> None:
    """A GL error after drawing is a bug in the renderer, not bad input: raise it loudly."""
    err = ctx.error
    if err != "GL_NO_ERROR":
        raise RuntimeError(f"{err} after {where} on {ctx.info.get('GL_RENDERER', '?')}")
