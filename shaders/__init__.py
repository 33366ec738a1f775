"""GLSL sources of the render worker (``*.vert *.tesc *.tese *.frag``), shipped inside the
wheel and read by name through :mod:`worker.render.shaders`. No Python code lives here."""
