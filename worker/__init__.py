"""The render worker: a USD forest scene -> GPU buffers -> frames, preview PNG and frame-time
metrics, with moderngl on EGL (no display needed).

Modules: ``gl_context`` (the one place that creates a GL context), ``shaders`` (GLSL by
name), ``scene_buffers`` (scene arrays -> GPU buffers), ``textures`` (the bark texture array),
``camera``, ``renderer``, ``metrics``, ``render_job`` (``forest render``), ``inspect_sheet``
(``forest inspect``, pyvista diagnostics) and ``bench`` (``forest bench render``).
Import them directly; this package imports nothing heavy on its own.
"""
