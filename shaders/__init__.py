"""GLSL sources of the render worker (``*.vert *.tesc *.tese *.frag``), shipped inside the
wheel and read by name through :mod:`forest.gl.shaders`. No Python code lives here."""
