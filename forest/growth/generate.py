"""Grammar + seed -> a forest's arrays: piece graph, transforms, bones, poses, tiles, foliage."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from forest import __version__
from forest.bark.tiles import draw_tile_indices, lower_trunk
from forest.bark.tilesets import shipped_manifest
from forest.caps import check_forest_pieces, check_palette
from forest.errors import LimitError
from forest.geometry.pieces import HUB, MAX_LEAF_RIMS, PIECE_NAMES, TIP0, PieceArrays, piece_library
from forest.geometry.transforms import F64, similarity_scale
from forest.growth.assembly import topological_transforms
from forest.growth.compile import compile_grammar, foliage_bearers
from forest.growth.expand import MAX_FINISH, PieceGraph, end_branches, finish_reach
from forest.growth.foliage import FoliageAnchors, Season, spray_anchors
from forest.growth.grammar import CompiledGrammar
from forest.growth.keyed import GROW, tree_keys
from forest.growth.parallel import block_threads, expand_in_groups
from forest.growth.pose import PoseParams, draw_pose
from forest.growth.poser import Poser
from forest.growth.scatter import Placement, place_trees
from forest.growth.skeleton import Bones, build_bones, joints_per_instance, rest_palette
from forest.growth.tropism import apply_tropisms
from forest.growth.wind import Wind
from forest.settings import ForestSettings, get_settings
from schemas.grammar import Grammar
from schemas.tileset import TileSetManifest

Progress = Callable[[str, int, int], None]
GROUND_PASSES = 4  # the cuts of branches under the ground: enough for the caps they make
MAX_AREA = 1e6  # metres per side: beyond this float32 USD positions lose centimetres


@dataclass(frozen=True)
class ForestOptions:
    trees: int = 1
    area: tuple[float, float] = (20.0, 20.0)
    frames: int = 0
    fps: float = 24.0
    placement: Placement = "poisson"
    segments: int = 1
    wind: Wind = field(default_factory=Wind)
    season: Season = "summer"

    def __post_init__(self) -> None:
        # a clip loops: the wind's frequencies snap to multiples of 1 / (frames / fps)
        loop = self.frames / self.fps if self.frames > 0 and 0 < self.fps < np.inf else 0.0
        if self.wind.loop_s != loop:
            object.__setattr__(self, "wind", replace(self.wind, loop_s=loop))

    def check(self, settings: ForestSettings) -> None:
        if not 1 <= self.trees <= settings.max_trees:
            raise LimitError(
                f"trees must be between 1 and {settings.max_trees}, got {self.trees}",
                path="trees",
                limit=settings.max_trees,
            )
        if not 0 <= self.frames <= settings.max_frames:
            raise LimitError(
                f"frames must be between 0 and {settings.max_frames}, got {self.frames}",
                path="frames",
                limit=settings.max_frames,
            )
        for name, v in zip(("width", "depth"), self.area, strict=True):
            if not (0 < v <= MAX_AREA) or not np.isfinite(v):
                raise LimitError(
                    f"area {name} must be in (0, {MAX_AREA:g}] metres, got {v}",
                    path=f"area.{name}",
                    limit=MAX_AREA,
                )
        if not 0 < self.fps <= 1000:
            raise LimitError(f"fps must be in (0, 1000], got {self.fps}", path="fps", limit=1000)
        if not 1 <= self.segments <= 8:
            raise LimitError(
                f"segments must be in [1, 8], got {self.segments}", path="segments", limit=8
            )


@dataclass(frozen=True, eq=False)
class Forest:
    """Everything a scene holds, as numpy arrays (written in the USD layout that
    forest/usd/contract.py names).

    tree_transforms : (t, 4, 4)   transforms : (n, 4, 4) topological world transforms
    tree_ids : (t,) int64 each tree's stable identity (its global placement cell): a tree's
    shape and pose follow from the seed and its id alone, whatever forest or tile holds it
    tile_indices : (n, q_max) int16, -1 padded
    foliage_instance : (k,) int32 instances that bear leaf clouds
    """

    grammar: Grammar
    seed: int
    version: str
    options: ForestOptions
    pieces: tuple[PieceArrays, ...]
    graph: PieceGraph
    tree_transforms: F64
    tree_ids: NDArray[np.int64]
    transforms: F64
    bones: Bones
    pose: PoseParams
    tile_indices: NDArray[np.int16]
    manifest: TileSetManifest
    foliage_instance: NDArray[np.int32]
    still_palette: F64 | None = None
    """The posed palette without wind when generation already computed it (tropisms)."""

    @property
    def n_instances(self) -> int:
        return len(self.graph)

    @property
    def animated(self) -> bool:
        return self.options.frames > 0

    def frame_times(self) -> list[float | None]:
        """Seconds of each frame, or ``[None]`` for a still (posed, windless) forest."""
        if not self.animated:
            return [None]
        return [f / self.options.fps for f in range(self.options.frames)]

    def poser(self, pose: PoseParams | None = None) -> Poser:
        """The forest's poser (one per forest, so what it derives once serves every frame),
        or one for another ``pose``."""
        return self._poser if pose is None else self._make_poser(pose)

    @cached_property
    def _poser(self) -> Poser:
        return self._make_poser(self.pose)

    def _make_poser(self, pose: PoseParams) -> Poser:
        return Poser(
            self.graph, self.bones, self.pieces, self.tree_transforms, self.transforms, pose
        )

    def local_bones(self, time: float | None = None) -> F64:
        """``(b, 4, 4)`` local bone transforms, posed, with wind at ``time`` if given."""
        wind = None if time is None else self.options.wind
        return self.poser().local_transforms(wind, time or 0.0)

    def palette(self, time: float | None = None, row_vectors: bool = False) -> F64:
        """``(b, 4, 4)`` posed skinning matrices (prototype space -> world); transposed to
        USD's row-vector convention with ``row_vectors``."""
        if time is None and not row_vectors and self.still_palette is not None:
            return self.still_palette  # read-only: shared by every caller
        wind = None if time is None else self.options.wind
        return self.poser().palette(wind, time or 0.0, row_vectors)

    def rest_palette(self) -> F64:
        return rest_palette(self.bones, self.transforms)

    def foliage_anchors(self) -> FoliageAnchors:
        """Where leaf sprays grow: along the foliage-bearing pieces, each following its piece's
        hub bone (see :func:`forest.growth.foliage.spray_anchors`)."""
        idx = self.foliage_instance
        # the tree as it stands: posed where generation kept the still palette, else at rest
        frames = (
            self.still_palette[self.bones.offset[idx] + HUB]
            if self.still_palette is not None
            else self.transforms[idx]
        )
        tree = self.graph.tree[idx]
        return spray_anchors(
            idx, self.graph.piece, self.bones.offset, [p.joint_rest for p in self.pieces],
            frames, tree, self.tree_transforms[tree, 1, 3], self.grammar.leaves,
            np.random.default_rng([self.seed, 0xF011A6E]), self.options.season,
        )  # fmt: skip


def foliage_or_none(forest: Forest) -> FoliageAnchors | None:
    """The forest's leaf sprays, or None where it bears none (no foliage piece, or every
    spray left out by height, ground, shell or budget)."""
    if not len(forest.foliage_instance):
        return None
    anchors = forest.foliage_anchors()
    return anchors if len(anchors) else None


def generate_forest(
    grammar: Grammar,
    seed: int,
    options: ForestOptions | None = None,
    manifest: TileSetManifest | None = None,
    settings: ForestSettings | None = None,
    progress: Progress | None = None,
    compiled: CompiledGrammar | None = None,
) -> Forest:
    """Expand, assemble, pose and tile a forest. Same inputs, same version: same arrays.
    ``manifest``: the tile classes the bark tiles draw from; by default the shipped set the
    grammar's ``bark`` names (:func:`forest.bark.tilesets.shipped_manifest`)."""
    if manifest is None:
        manifest = shipped_manifest(grammar.bark)
    settings = settings or get_settings()
    options = options or ForestOptions()
    options.check(settings)
    cg = compiled or compile_grammar(grammar, settings)
    # the pieces and the palette's size before any expansion (the exact counts, in expand
    # and below, are the backstop)
    check_forest_pieces(cg, options.trees, settings)
    check_palette(cg, options.trees, options.frames, settings)
    note = progress or (lambda stage, done, total: None)
    # bark tiles draw per forest; placement, growth and pose per tree and piece, keyed on the
    # seed and the tree's id, so a tree is the same in any forest or tile (forest.growth.keyed)
    pieces = piece_library(options.segments)
    note("place", 0, 5)
    placed = place_trees(
        options.trees,
        options.area,
        grammar.trunk_radius,
        grammar.tree_scale,
        seed,
        options.placement,
    )
    trees = placed.transforms
    note("grow", 1, 5)
    tree_radius = similarity_scale(trees)
    graph = expand_in_groups(
        cg, tree_keys(placed.seed, placed.ids, GROW), settings, tree_radius, placed.sizes
    )
    n_bones = int(joints_per_instance(graph, pieces).sum(dtype=np.int64))
    matrices = n_bones * max(options.frames, 1)
    if matrices > settings.max_palette_matrices:
        raise LimitError(
            f"{n_bones} bones x {max(options.frames, 1)} frame(s) = {matrices} palette "
            f"matrices, over the cap of {settings.max_palette_matrices}; use fewer frames or "
            "trees",
            path="max_palette_matrices",
            limit=settings.max_palette_matrices,
        )
    posed = _assemble(cg, graph, pieces, trees, manifest, seed, note)
    for _ in range(GROUND_PASSES):
        under, bare = _under_ground(graph, posed, pieces, trees, grammar.ground_clearance, cg)
        if not under.any():
            break
        # branches that would bend under the ground end where they reach it (a cap that
        # still dips under ends its branch one piece sooner on the next pass); the rest of
        # each tree keeps its keys, so it grows and poses exactly as before
        graph = end_branches(graph, under, cg, bare)
        posed = _assemble(cg, graph, pieces, trees, manifest, seed, note)
    transforms, bones, pose, still, tiles = posed
    note("done", 5, 5)
    return Forest(
        grammar=grammar,
        seed=seed,
        version=__version__,
        options=options,
        pieces=pieces,
        graph=graph,
        tree_transforms=trees,
        tree_ids=placed.ids,
        transforms=transforms,
        bones=bones,
        pose=pose,
        tile_indices=tiles,
        manifest=manifest,
        foliage_instance=foliage_bearers(cg, graph),
        still_palette=still,
    )


_Posed = tuple[F64, Bones, PoseParams, F64 | None, NDArray[np.int16]]


def _assemble(
    cg: CompiledGrammar,
    graph: PieceGraph,
    pieces: tuple[PieceArrays, ...],
    trees: F64,
    manifest: TileSetManifest,
    seed: int,
    note: Progress,
) -> _Posed:
    """Transforms, bones, pose (tropisms applied), the still palette where tropisms made one,
    and bark tiles of a piece graph."""
    rng_tiles = np.random.default_rng(np.random.SeedSequence(seed).spawn(4)[3])
    # the bark tiles and the pose draws depend on the piece graph alone: they run on their
    # own threads beside the assembly, and the tiles on beside the posing, whose passes leave
    # a core idle much of the time (the same arrays on any number of threads); the pool ends
    # with the call, as in forest.growth.parallel
    with ThreadPoolExecutor(2, thread_name_prefix="forest-side") as side:
        lower = None
        if manifest.lower_trunk is not None:
            lower = lower_trunk(graph.tree, graph.order, graph.height, manifest.lower_trunk)
        tiles_drawn = side.submit(
            draw_tile_indices,
            graph.piece,
            pieces,
            manifest,
            rng_tiles,
            threads=block_threads(),
            lower=lower,
        )
        pose_drawn = side.submit(draw_pose, graph, pieces, cg)
        note("assemble", 2, 5)
        transforms = topological_transforms(graph, trees, pieces)
        note("bones", 3, 5)
        bones = build_bones(graph, pieces)
        pose = pose_drawn.result()
        still = None
        if cg.alt_tropism.any():
            pose, still = apply_tropisms(
                graph, bones, pieces, trees, transforms, pose, cg.alt_tropism
            )
            still.setflags(write=False)
        note("tiles", 4, 5)
        tiles = tiles_drawn.result()
    return transforms, bones, pose, still, tiles


def _under_ground(
    graph: PieceGraph,
    posed: _Posed,
    pieces: tuple[PieceArrays, ...],
    trees: F64,
    clearance: float,
    cg: CompiledGrammar,
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """``(n,)`` pieces to end branches at: those (not a tree's root piece) heading down (their
    hub or a leaf-rim centre lower than their root) whose hub or leaf rims' bark lies lower
    than ``clearance`` above their tree's base, posed without wind, and the pieces that bear
    caps lying that low; each moved down its branch while what :func:`end_branches` would grow
    in its place (a straight finishing chain and cap) would reach that low; and ``(n,)``
    those of them that still would (a branch's first piece): they end in a bare cap."""
    transforms, bones, pose, still, _ = posed
    pal = still
    if pal is None:
        pal = Poser(graph, bones, pieces, trees, transforms, pose).palette()
    centre = np.full(len(graph), np.inf)
    bark = np.full(len(graph), np.inf)
    for j in range(HUB, TIP0 + MAX_LEAF_RIMS):
        at = np.flatnonzero(np.array([p.n_joints > j for p in pieces])[graph.piece])
        rest = np.stack([p.joint_rest[min(j, p.n_joints - 1)] for p in pieces])
        kind = graph.piece[at]
        # heights only: the bones' y rows (a quarter of the matrices) gathered once
        row = pal[bones.offset[at] + j, 1]
        y = np.einsum("nj,nj->n", row[:, :3], rest[kind, :3, 3]) + row[:, 3]
        centre[at] = np.minimum(centre[at], y)
        if j >= TIP0:  # a rim: a circle of radius 1 in its joint frame's xz plane
            ring = np.einsum("nj,njk->nk", row[:, :3], rest[kind][:, :3][:, :, [0, 2]])
            y = y - np.linalg.norm(ring, axis=1)
        bark[at] = np.minimum(bark[at], y)
    base = trees[graph.tree, 1, 3]
    root = pal[bones.offset, 1, 3]  # the root joint's rest frame is the identity
    # only pieces that head down: a stem rising from the ground is never cut
    under = (bark - base < clearance) & (centre < root) & (graph.parent >= 0)
    # a cap that dips under is its branch's end: the piece it closes ends the branch instead
    caps = np.flatnonzero(under & (graph.piece == PIECE_NAMES.index("Cap")))
    under[caps] = False
    under[graph.parent[caps]] = True
    # so is a finishing chain (forest.growth.expand.end_branches): the piece below the chain
    # ends the branch instead, one piece sooner
    for _ in range(MAX_FINISH + 1):
        chain = np.flatnonzero(under & (graph.alt == cg.finish_alt) & (graph.parent >= 0))
        if not len(chain):
            break
        under[chain] = False
        under[graph.parent[chain]] = True
    # and a piece whose replacement would reach that low (it grows straight on along the
    # piece's root axis: its lowest point is the root rim's circle or the end of that reach)
    # ends its branch one piece sooner, down to the branch's first piece
    axis = pal[bones.offset, :3, 1]
    down = axis[:, 1] / np.maximum(np.linalg.norm(axis, axis=1), 1e-30)
    side = graph.scale * np.sqrt(np.maximum(1.0 - down**2, 0.0))
    reach = root + np.minimum(down, 0.0) * finish_reach(graph.scale) - side
    dips = (reach - base < clearance) & (graph.parent >= 0)
    along = dips & (graph.order[np.maximum(graph.parent, 0)] == graph.order)
    for _ in range(int(graph.depth.max(initial=0)) + 1):
        move = np.flatnonzero(under & along)
        if not len(move):
            break
        under[move] = False
        under[graph.parent[move]] = True
    under &= graph.parent >= 0
    return under, under & dips
