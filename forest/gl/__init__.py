"""OpenGL on EGL for whatever in the project draws: the one place a moderngl context is made
(:mod:`forest.gl.context`) and the GLSL sources of ``shaders/`` by name
(:mod:`forest.gl.shaders`). Used by the renderer (``worker/render``) and the impostor bake
(:mod:`forest.lod.impostor`); moderngl is the render extra's, imported only when a context
is made."""
