"""The USD layout of a forest scene: every prim path, prim name, attribute, primvar, variant
and metadata key the writers author and the readers expect, named once. Writers
(:mod:`forest.usd.scene` and the modules it calls, :mod:`forest.usd.tiled`), the reader
(:mod:`forest.usd.read`), the upload guard and the renderer import these names; nothing else
spells them out. Plain strings only (no ``pxr``), so the upload guard can name attributes
before it loads USD.

Stage: ``upAxis = Y``, ``metersPerUnit = 1``, default prim ``/World``; time codes are frames
(``timeCodesPerSecond = framesPerSecond = fps``, frames ``0 .. frames - 1``) when the forest
is animated. Every matrix is a Gf ``matrix4d``: row vectors, the transpose of the library's
column-vector numpy arrays. Primvar names below are the primvar's own name; the attribute a
reader opens is :func:`primvar` of it (``primvars:forest:treeId``).

``/World`` (Xform, kind assembly)

``/World/Forest`` (:data:`FOREST`, Xform, kind group), everything needed to make the scene
again: :data:`GRAMMAR` string (the grammar as sorted JSON), :data:`SEED` int64,
:data:`VERSION` string (the library's), :data:`OPTIONS` string (JSON: trees, area, frames,
fps, placement, segments, wind, season), :data:`TILE_MANIFEST` string (the tile set's
manifest JSON), :data:`TREE_TRANSFORMS` matrix4d[] ``(t,)`` each tree's model transform. It
carries the variant set :data:`REPRESENTATION`, choosing what a consumer that knows nothing
of ``forest:*`` composes: :data:`ENGINE` the pieces at their topological (rest) transforms,
to be skinned with the bone rig (the renderer, game engines); :data:`POSED` each piece at the
similarity that best fits its skinned vertices, time-sampled; :data:`SKINNED` one UsdSkel
tree per SkelRoot (when written, then the default; ``Pieces`` and ``Foliage`` inactive).

``/World/Forest/Pieces`` (:data:`PIECES`, PointInstancer): every piece of every tree, ``n``
instances. ``protoIndices`` and ``ids``; ``positions``, ``orientationsf`` (quatf: the exact
topological transforms; no quath ``orientations`` beside it since bone format 3),
``scales`` and ``extent`` in the ``engine`` variant, and ``positions``, ``orientations``
(quath), ``scales`` and ``extent`` in the ``posed`` one (time-sampled). Vertex primvars,
int[] ``(n,)``: :data:`TREE_ID`, :data:`BONE_OFFSET` (the instance's first bone in the palette),
:data:`PARENT` (-1 at a tree's root), :data:`PARENT_RIM`, :data:`TWIST`, :data:`DEPTH`,
:data:`SYMBOL` (an index into :data:`SYMBOLS`); :data:`TILE_INDICES` int[] ``(n, q_max)``
(elementSize ``q_max``, the most quads of any piece; -1 past a piece's quads). Attributes:
:data:`SYMBOLS` token[] the grammar's symbols; the compact bone rig (``b`` bones,
:mod:`forest.growth.rig`): :data:`BONE_FORMAT` int (:data:`BONE_FORMAT_VERSION`),
:data:`BONE_PARENTS` int[] ``(b,)`` (-1 for a tree's root), :data:`BONE_TRANSLATIONS`
float3[] ``(b,)``, :data:`BONE_SCALES` float[] ``(b,)``, :data:`ROOT_ROTATIONS` quatf[]
``(n,)`` (each instance's root bone), and :data:`JOINT_ROTATIONS` quatf[] ``(b - n,)``
time-sampled with wind: every hub and terminal, in palette order without the roots. A scene
of format 2 stored the translations, scales and root rotations in double precision
(double3[], double[], quatd[]); one of format 1 has :data:`LEGACY_BONE_PALETTE` instead
(matrix4d[] per bone per frame). The reader refuses both.

``/World/Forest/Pieces/Prototypes/<piece>`` (:data:`PIECE_PROTOTYPES`, Mesh, one per piece
type: ``v`` points, ``q`` quads, ``r`` leaf rims, ``j = 2 + r`` joints): points, vertex
normals, faceVarying ``st``; primvars :data:`TILE_CLASS` uniform int[] ``(q,)``,
:data:`JOINT_INDICES` int[] and :data:`JOINT_WEIGHTS` float[] ``(v, 4)`` (vertex,
elementSize 4); attributes :data:`ROOT_RIM` int[] ``(6,)``, :data:`LEAF_RIMS` int[]
``(r, 6)`` (flat, like every array of rows here), :data:`BUILDING` matrix4d[] ``(r,)``
(root rim -> leaf rim), :data:`JOINT_REST` matrix4d[] ``(j,)`` (joint frames in model
space), :data:`JOINT_PARENTS` int[] ``(j,)``, :data:`JOINT_NAMES` token[] ``(j,)``; bound to
:data:`BARK_MATERIAL`.

``/World/Forest/Foliage`` (:data:`FOLIAGE`, PointInstancer; only where the forest bears leaf
clouds): ``k`` clouds. ``protoIndices`` (the cloud model), ``ids``, ``positions`` (centres,
time-sampled with wind; the default is the first sample), ``orientations``/``orientationsf``
(a turn about +y), ``scales`` (diameters), ``extent``; vertex primvars ``displayColor``
color3f[] ``(k,)`` (linear RGB), :data:`YAW` double[] ``(k,)`` radians, :data:`INSTANCE`
int[] (the piece it sits on), :data:`BONE_OFFSET` int[] (that piece's), :data:`JOINT` int[]
(1, the hub), :data:`REST_POSITION` float3[] ``(k,)`` (in the piece's model space): the
centre at any frame is ``palette[boneOffset + joint]`` applied to the rest position.
``/World/Forest/Foliage/Prototypes/LeafCloud<m>`` (:data:`FOLIAGE_CLOUD` + the model index,
Mesh): double-sided leaf cards of unit diameter, vertex ``st``, :data:`LEAF_FAMILY` token
(which leaf picture its ``st`` index); bound to the leaf materials.

``/World/Forest/Trees`` (:data:`TREES`, Xform, kind group; authored in the ``skinned``
variant), one ``Tree_NNNNN`` (:func:`tree_name`) SkelRoot per tree (kind component; assetInfo
name, version, :data:`ASSET_SEED` and :data:`ASSET_TREE`, the tree's index) holding
:data:`SKELETON` (with its SkelAnimation :data:`WIND_ANIMATION`), :data:`BARK_MESH` (skinned
quads, indexed UDIM ``st``), :data:`PROXY_MESH` (decimated, purpose proxy) and
:data:`LEAVES_MESH` (the tree's leaf clouds, uniform ``displayColor``); with levels of detail
(the default) the leaves are purpose render with :data:`LEAVES_PROXY_MESH` (lod2's cards,
purpose proxy) as their ``proxyPrim``, and a variant set :data:`LOD` (:func:`lod_variant`,
default ``lod0``, the meshes above) whose higher levels deactivate those four and hold
:func:`lod_mesh` meshes bound to the same
Skeleton; ``lod3`` (when baked) the :data:`IMPOSTOR_MESH` card pair, its
:data:`IMPOSTOR_MATERIAL` and, on the mesh, the octahedral atlases (:data:`IMPOSTOR_ATLAS`,
:data:`IMPOSTOR_FRAMES`, :data:`IMPOSTOR_SPHERE`).

``/World/Looks`` (:data:`LOOKS`): :data:`BARK_MATERIAL` (UsdPreviewSurface; its
:data:`BARK_TILE_SET` string names the shipped tile set; with a tile folder its
:data:`BARK_TILES_SHIPPED` bool says whether the folder is a copy of that set or the user's, and its
:data:`BARK_TILES` UsdUVTexture reads ``inputs:file`` = the UDIM pattern), the leaves'
:data:`LEAF_MATERIAL` (bound for all purposes) and :data:`LEAF_TINTED_MATERIAL` (bound for
``preview``, reading ``displayColor``).

A tiled forest's root layer: ``/World/Tiles`` (:data:`TILES`, Xform, group; :data:`TILING`
string, the plan as JSON) and per tile ``T_<i>_<j>`` (:func:`tile_name`, Xform, assembly; a
payload of the tile's scene, ``extentsHint``, :data:`TILE_INDEX` int2 ``(i, j)``,
:data:`TILE_TREES` int).

A mixed forest's root layer (:mod:`forest.usd.stand`): :data:`RECIPE` on ``/World``,
:data:`TERRAIN` (Mesh) bound to :data:`TERRAIN_MATERIAL`, and :data:`STAND_LAYERS` with one
prim per recipe layer (:data:`LAYER_SPECIES`, :data:`LAYER_ROLE`, :data:`TILE_TREES`)
referencing its scene file, or per tile ``T_<i>_<j>`` when tiled.
"""

from __future__ import annotations

# -- prims ----------------------------------------------------------------------------------
WORLD = "/World"
FOREST = f"{WORLD}/Forest"
PIECES = f"{FOREST}/Pieces"
PIECE_PROTOTYPES = f"{PIECES}/Prototypes"  # + the piece's name
FOLIAGE = f"{FOREST}/Foliage"
FOLIAGE_PROTOTYPES = f"{FOLIAGE}/Prototypes"
FOLIAGE_CLOUD = f"{FOLIAGE_PROTOTYPES}/LeafCloud"  # + the model index: LeafCloud0, ...
TREES = f"{FOREST}/Trees"
LOOKS = f"{WORLD}/Looks"
BARK_MATERIAL = f"{LOOKS}/Bark"
BARK_TILES = f"{BARK_MATERIAL}/Tiles"  # the UsdUVTexture reading the UDIM tiles
LEAF_MATERIAL = f"{LOOKS}/Leaf"
LEAF_TINTED_MATERIAL = f"{LOOKS}/LeafTinted"
TILES = f"{WORLD}/Tiles"  # a tiled forest's root layer
STAND_LAYERS = f"{WORLD}/Layers"  # a mixed forest's root layer: one prim per species layer
TERRAIN = f"{WORLD}/Terrain"  # its ground mesh
TERRAIN_MATERIAL = f"{WORLD}/Looks/Ground"

# prim names inside a material
SURFACE = "Surface"  # the UsdPreviewSurface
ST_READER = "StReader"  # the st primvar reader beside a texture
LEAF_CUTOUT = "Cutout"  # a leaf material's texture (opacity from the leaf picture's alpha)
DISPLAY_COLOR_READER = "DisplayColor"  # the tinted leaf material's displayColor reader

# prim names inside a skinned tree
SKELETON = "Skeleton"
WIND_ANIMATION = "Wind"  # under SKELETON
BARK_MESH = "Bark"
PROXY_MESH = "Proxy"
LEAVES_MESH = "Leaves"
LEAVES_PROXY_MESH = "LeavesProxy"  # with levels of detail: LEAVES_MESH's proxy, lod2's cards
# a skinned tree's levels of detail (forest.lod): a variant set on its SkelRoot, LOD0 the tree
# as above; a higher level deactivates those meshes and holds its own, named by lod_mesh
LOD = "lod"
IMPOSTOR_MESH = "Impostor"  # lod3's crossed card pair
IMPOSTOR_MATERIAL = "ImpostorLook"  # beside it in lod3: the cards' picture, cut by its alpha
IMPOSTOR_ATLAS = "forest:impostorAtlas"  # + ":albedo", ":normal", ":depth": asset each
IMPOSTOR_MAPS = ("albedo", "normal", "depth")
IMPOSTOR_FRAMES = "forest:impostorFrames"  # int: the atlas's views per side
IMPOSTOR_SPHERE = "forest:impostorSphere"  # float4: centre (tree space) and radius framed


def lod_variant(level: int) -> str:
    """The :data:`LOD` variant of level ``level`` (``lod0`` is the full tree, the default)."""
    return f"lod{level}"


def lod_mesh(mesh: str, level: int) -> str:
    """The prim name of a mesh (:data:`BARK_MESH`, :data:`LEAVES_MESH`) at ``level`` >= 1."""
    return f"{mesh}_lod{level}"


def tree_name(k: int) -> str:
    """The name of tree ``k``'s SkelRoot under :data:`TREES` (also its asset name)."""
    return f"Tree_{k:05d}"


def tile_name(i: int, j: int) -> str:
    """The name of tile ``(i, j)``'s prim under :data:`TILES`."""
    return f"T_{i}_{j}"


def primvar(name: str) -> str:
    """The attribute that holds primvar ``name``."""
    return f"primvars:{name}"


# -- the representation variant set on FOREST ----------------------------------------------
REPRESENTATION = "representation"
ENGINE, POSED, SKINNED = "engine", "posed", "skinned"

# -- FOREST attributes ----------------------------------------------------------------------
GRAMMAR = "forest:grammar"
SEED = "forest:seed"
VERSION = "forest:version"
OPTIONS = "forest:options"
TILE_MANIFEST = "forest:tileManifest"
TREE_TRANSFORMS = "forest:treeTransforms"

# -- PIECES: per-instance primvars, symbols and the bone rig --------------------------------
TREE_ID = "forest:treeId"
BONE_OFFSET = "forest:boneOffset"  # also on FOLIAGE
TILE_INDICES = "forest:tileIndices"
PARENT = "forest:parent"
PARENT_RIM = "forest:parentRim"
TWIST = "forest:twist"
DEPTH = "forest:depth"
SYMBOL = "forest:symbol"
SYMBOLS = "forest:symbols"
BONE_FORMAT = "forest:boneFormat"
# the value of BONE_FORMAT: 3 is the compact rig of forest.growth.rig in float32 (float3[]
# translations, float[] scales, quatf[] root rotations); 2 was the same rig in float64
# (double3[], double[], quatd[]); 1 (no attribute) was one matrix4d per bone per frame,
# LEGACY_BONE_PALETTE
BONE_FORMAT_VERSION = 3
BONE_PARENTS = "forest:boneParents"
BONE_TRANSLATIONS = "forest:boneTranslations"
BONE_SCALES = "forest:boneScales"
ROOT_ROTATIONS = "forest:rootRotations"
JOINT_ROTATIONS = "forest:jointRotations"
LEGACY_BONE_PALETTE = "forest:bonePalette"

# -- piece prototypes ----------------------------------------------------------------------
TILE_CLASS = "forest:tileClass"
JOINT_INDICES = "forest:jointIndices"
JOINT_WEIGHTS = "forest:jointWeights"
ROOT_RIM = "forest:rootRim"
LEAF_RIMS = "forest:leafRims"
BUILDING = "forest:building"
JOINT_REST = "forest:jointRest"
JOINT_PARENTS = "forest:jointParents"
JOINT_NAMES = "forest:jointNames"

# -- FOLIAGE primvars and its leaf-cloud prototypes -------------------------------------------
YAW = "forest:yaw"
INSTANCE = "forest:instance"
JOINT = "forest:joint"
REST_POSITION = "forest:restPosition"
LEAF_FAMILY = "forest:leafFamily"

# -- materials ------------------------------------------------------------------------------
BARK_TILE_SET = "forest:barkTileSet"
# true where the bark texture is this writer's copy of that shipped set (the renderer reads the
# set itself); false where it is a tile folder the user named (--tiles)
BARK_TILES_SHIPPED = "forest:barkTilesShipped"

# -- a skinned tree's assetInfo keys --------------------------------------------------------
ASSET_SEED = "forest:seed"
ASSET_TREE = "forest:tree"

# -- a tiled forest's root layer ------------------------------------------------------------
TILING = "forest:tiling"
TILE_INDEX = "forest:tile"
TILE_TREES = "forest:trees"
RECIPE = "forest:recipe"  # a mixed forest's recipe (JSON) on /World
LAYER_SPECIES = "forest:species"  # a mixed forest layer's preset (or grammar) name
LAYER_ROLE = "forest:role"  # canopy, understorey or edge
