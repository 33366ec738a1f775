"""The render worker: a USD forest scene -> GPU buffers -> frames, preview PNG and frame-time
metrics, with moderngl on EGL (no display needed).

Modules (the GL context and the shader loader are the library's, :mod:`forest.gl`):
``scene_buffers`` (scene arrays -> GPU buffers), ``textures`` (the bark texture array),
``camera``, ``renderer``, ``metrics``, ``render_job`` (``forest render``), ``inspect_sheet``
(``forest inspect``, pyvista diagnostics) and ``bench`` (``forest bench render``).
Import them directly; this package imports nothing heavy on its own.
"""
