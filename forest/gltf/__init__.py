"""glTF 2.0 binary (.glb) export of a forest, for game engines and web viewers.

One module per concept: :mod:`~forest.gltf.buffer` (the binary chunk, buffer views and
accessors), :mod:`~forest.gltf.skin` (each tree's skeleton, inverse binds and wind
animation), :mod:`~forest.gltf.primitive` (a skinned quad mesh as a primitive, its vertices
split where UVs differ), :mod:`~forest.gltf.bark` (the bark atlas, its UVs and PBR material),
:mod:`~forest.gltf.leaves` (the alpha-tested leaf material) and
:mod:`~forest.gltf.document` (the whole file, written atomically).
"""

from __future__ import annotations

GLB_SUFFIX = ".glb"
