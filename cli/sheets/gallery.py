"""``forest gallery``: every preset as one tree (side view, on the ground, with a scale bar
and its measured height), in two close-ups (the leaves at a shoot end on the crown's sunny
side, and the trunk's base) and as a small stand (overview, on the ground), plus two contact
sheets (trees and stands; close-ups); and each built-in mixed-forest recipe asked for
(``recipes``) as a stand of a few hundred trees on its terrain, from above and at eye level.

Each scene goes through a written and re-read USD file, as a render job sees it. One tree is
framed from its own posed surface (every skinned piece vertex) and leaf clouds; the stand is
as many trees as the tree's crown width suits, Poisson-placed. Same seed, same images.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from forest.bark.images import write_png
from forest.errors import ForestError, LimitError, OutputError
from forest.geometry.transforms import F64
from forest.gl.context import create_context, raise_gl_error
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset, preset_names
from forest.usd.read import SceneArrays, read_scene
from forest.usd.scene import write_scene
from schemas.grammar import Grammar
from worker.render.camera import (
    Camera,
    CameraSpec,
    frame_points,
    place_camera,
    project,
    with_ground,
)
from worker.render.foliage import foliage_points
from worker.render.instance_cull import DEFAULT_LOD_PIXELS
from worker.render.renderer import Renderer, auto_lod
from worker.render.staging import STAGED
from worker.render.textures import tile_images

if TYPE_CHECKING:
    import moderngl
    from PIL import Image as PILImage

    from worker.render.stand import StandScene

Echo = Callable[[str], None]
Progress = Callable[[str, int, int], None]  # (stage, done, total), as forest.growth.generate's
SINGLE_SIZE = (480, 640)  # width, height: portrait for one tree, llvmpipe-friendly
STAND_TREES = 16
AZIMUTH = 35.0  # the overview's, so a tree and its stand are seen from the same side
FOV = 40.0
TESS_MAX = 6.0
BAR_LENGTHS = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)  # metres
BAR_SEGMENTS = {0.5: 1, 1.0: 2, 2.0: 2, 5.0: 5, 10.0: 5, 20.0: 4, 50.0: 5}
BAR_OF_HEIGHT = 0.6  # the longest bar no taller than this fraction of the tree
SHEET_THUMB = 320  # contact-sheet row height in pixels
LEAF_VIEW = 1.2  # metres across a leaf close-up: a shoot end and its leaves at their size
LEAF_BAND = (0.45, 0.85)  # the close-up's shoot is taken between these fractions of the height
BASE_VIEW = (1.5, 3.0)  # metres of trunk a base close-up shows: 12 % of the height in this range
CLOSE_ELEVATION = 8.0  # degrees: close-ups are seen from about eye level
MIN_SIZE, MAX_SIZE = 64, 4096
RECIPE_TREES = 200
RECIPE_SIDE = 110.0  # metres: the square a recipe's stand grows on
RECIPE_ELEVATION = 32.0  # degrees: steeper than a stand's overview, so glades and rows show
RECIPE_AZIMUTH = {"orchard": 0.0}  # along the orchard's rows; the others at AZIMUTH
RECIPE_EYE_DISTANCE = 0.3  # of the side: the eye stands in the wood, looking at its middle
# a spruce wood is dark and dense at eye level: the eye stands at its birch edge instead
RECIPE_EYE = {"boreal": 0.62}
EYE_CLEARANCE = 4.0  # metres from the eye to the nearest trunk


@dataclass(frozen=True)
class GalleryOptions:
    """``size``: (width, height) of a single-tree image; a stand is drawn at (height, width)."""

    output: Path
    presets: tuple[str, ...] | None = None  # None: every shipped preset
    size: tuple[int, int] = SINGLE_SIZE
    seed: int = 1
    stand_trees: int = STAND_TREES
    recipes: tuple[str, ...] = ()  # built-in recipes to draw (`forest recipes`)
    recipe_trees: int = RECIPE_TREES

    def check(self) -> None:
        for name, v in zip(("width", "height"), self.size, strict=True):
            if not MIN_SIZE <= v <= MAX_SIZE:
                raise ForestError(
                    f"{name} must be in [{MIN_SIZE}, {MAX_SIZE}], got {v}", path="size"
                )
        if not 0 <= self.seed < 2**63:
            raise ForestError(f"must be in [0, 2^63), got {self.seed}", path="seed")
        if not 2 <= self.stand_trees <= 100:
            raise ForestError(f"must be in [2, 100], got {self.stand_trees}", path="stand_trees")
        known = preset_names()
        for name in self.presets or ():
            if name not in known:
                raise ForestError(
                    f"unknown preset {name!r}; choose from {', '.join(known)}", path="presets"
                )
        if self.presets is not None and not self.presets:
            raise ForestError("name at least one preset", path="presets")
        from forest.stand.recipes import recipe_names

        for name in self.recipes:
            if name not in recipe_names():
                raise ForestError(
                    f"unknown recipe {name!r}; choose from {', '.join(recipe_names())}",
                    path="recipes",
                )
        if not 2 <= self.recipe_trees <= 2000:
            raise ForestError(f"must be in [2, 2000], got {self.recipe_trees}", path="recipe_trees")
        if self.output.exists() and not self.output.is_dir():
            raise OutputError("exists and is not a folder", path=str(self.output))


def parse_size(text: str) -> tuple[int, int]:
    """``"480x640"`` -> ``(480, 640)``; anything else is an input error naming ``size``."""
    parts = text.lower().split("x")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        raise ForestError(f"expected WIDTHxHEIGHT in pixels, got {text!r}", path="size") from None
    return w, h


# -- measuring a scene ----------------------------------------------------------------------------


def posed_vertices(scene: SceneArrays, frame: int = 0, chunk: int = 1024) -> F64:
    """``(m, 3)`` float64 world positions of every piece vertex, skinned as the vertex shader
    skins them (blend of the palette's bone matrices by the piece's joint weights), at palette
    sample ``frame``. Per piece type, ``chunk`` instances at a time (bounded memory)."""
    pal = scene.palette(frame)
    out = []
    for t, piece in enumerate(scene.pieces):
        idx = np.nonzero(scene.proto_indices == t)[0]
        homo = np.c_[piece.positions, np.ones(len(piece.positions))]  # (v, 4)
        joints = np.arange(piece.joint_rest.shape[0])
        for start in range(0, len(idx), chunk):
            bones = pal[
                scene.bone_offset[idx[start : start + chunk], None] + joints
            ]  # (m, j, 4, 4)
            at_joint = np.einsum("mjab,vb->mjva", bones[:, :, :3], homo)  # (m, j, v, 3)
            v = np.arange(len(homo))[:, None]
            picked = at_joint[:, piece.joint_indices, v]  # (m, v, 4, 3)
            out.append(np.einsum("mvkc,vk->mvc", picked, piece.joint_weights).reshape(-1, 3))
    return np.concatenate(out) if out else np.zeros((0, 3))


def scene_surface_points(scene: SceneArrays, frame: int = 0, bark: F64 | None = None) -> F64:
    """``(m, 3)`` posed piece vertices (``bark`` when already computed) and the corners of
    every leaf cloud's box."""
    bark = posed_vertices(scene, frame) if bark is None else bark
    return np.concatenate([bark, foliage_points(scene, frame)])


def bar_length(height: float) -> float:
    """The longest of :data:`BAR_LENGTHS` no taller than ``BAR_OF_HEIGHT`` of ``height``."""
    fits = [b for b in BAR_LENGTHS if b <= BAR_OF_HEIGHT * height]
    return fits[-1] if fits else BAR_LENGTHS[0]


@dataclass(frozen=True)
class TreeShot:
    """One tree's camera and scale bar: ``bar`` is (2, 3) world base and top of the bar,
    in the vertical plane through the tree's centre facing the camera."""

    camera: Camera
    height: float
    crown_width: float
    bar: F64
    bar_metres: float


def frame_tree(points: F64, root: F64, aspect: float) -> TreeShot:
    """A side view of the tree enclosed by ``points`` (``(m, 3)``) whose trunk stands at
    ``root`` (``(3,)``, on y = 0), with a scale bar standing on the ground to its left in the
    vertical plane through the root facing the camera (so it measures the trunk at scale)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    height = float(hi[1] - root[1])
    az = np.deg2rad(AZIMUTH)
    right = np.array([np.cos(az), 0.0, -np.sin(az)])  # the side view's screen x
    left = max(float(-((points - root) @ right).min()), 0.0)
    gap = 0.08 * max(height, float(np.ptp((points - root) @ right)))
    metres = bar_length(height)
    base = root - (left + gap) * right
    bar = np.stack([base, base + np.array([0.0, metres, 0.0])])
    # room for the bar's width and its label
    room = np.stack([base - 0.5 * gap * right, base + np.array([0.0, metres + gap, 0.0])])
    cam = frame_points(np.concatenate([points, bar, room]), aspect, FOV, AZIMUTH, 0.0)
    width = float(max(hi[0] - lo[0], hi[2] - lo[2]))
    return TreeShot(with_ground(cam), height, width, bar, metres)


def frame_leaves(scene: SceneArrays, aspect: float) -> Camera | None:
    """A close-up, LEAF_VIEW metres across, of the outermost foliage anchor on the camera's
    side of the crown (between LEAF_BAND of the height): the leaves a walker looks at.
    None for a tree without leaves."""
    if scene.n_foliage == 0:
        return None
    centres = scene.foliage_at(0)
    root = scene.tree_transforms[0, :3, 3]
    top = float(centres[:, 1].max()) - root[1]
    y = centres[:, 1] - root[1]
    band = (y >= LEAF_BAND[0] * top) & (y <= LEAF_BAND[1] * top)
    if not band.any():
        band = np.ones(len(centres), bool)
    az = np.deg2rad(AZIMUTH)
    toward_camera = np.array([np.sin(az), 0.0, np.cos(az)])
    middle = np.array([np.median(centres[:, 0]), 0.0, np.median(centres[:, 2])])
    reach = np.where(band, (centres - middle) @ toward_camera, -np.inf)
    target = centres[int(np.argmax(reach))]
    # a square LEAF_VIEW across facing the camera (a box's corners would frame it wider)
    right = np.array([np.cos(az), 0.0, -np.sin(az)])
    up = np.array([0.0, 1.0, 0.0])
    square = target + 0.5 * LEAF_VIEW * np.array(
        [r * right + u * up for r in (-1, 1) for u in (-1, 1)]
    )
    return frame_points(square, aspect, FOV, AZIMUTH, CLOSE_ELEVATION, target_in=target)


def frame_base(bark: F64, root: F64, height: float, aspect: float) -> tuple[Camera, float]:
    """A close-up of the trunk's base: the bark vertices up to 12 % of the tree's ``height``
    (within BASE_VIEW metres) seen from about eye level; returns the camera and the metres."""
    metres = float(np.clip(0.12 * height, *BASE_VIEW))
    low = bark[bark[:, 1] <= root[1] + metres]
    if len(low) == 0:
        low = bark
    cam = frame_points(low, aspect, FOV, AZIMUTH, CLOSE_ELEVATION)
    return with_ground(cam), metres


# -- drawing --------------------------------------------------------------------------------------


def _font(size: int) -> PILImage.ImageFont:  # type: ignore[name-defined]
    from PIL import ImageFont

    return ImageFont.load_default(size=size)


def _caption(image: PILImage.Image, text: str) -> None:
    """``text`` in the top-left corner on a light band."""
    from PIL import ImageDraw

    draw = ImageDraw.Draw(image, "RGBA")
    size = max(12, image.height // 36)
    font = _font(size)
    _, _, x1, y1 = draw.textbbox((0, 0), text, font=font)
    pad = size // 2
    draw.rectangle((0, 0, x1 + 2 * pad, y1 + 2 * pad), fill=(255, 255, 255, 170))
    draw.text((pad, pad), text, fill=(20, 20, 20, 255), font=font)


def _scale_bar(image: PILImage.Image, shot: TreeShot) -> None:
    """The bar as alternating black and white segments with its length above it."""
    from PIL import ImageDraw

    draw = ImageDraw.Draw(image)
    size = (image.width, image.height)
    ends = project(shot.camera, shot.bar, size)  # (2, 2): base, top in pixels
    n = BAR_SEGMENTS[shot.bar_metres]
    half_w = max(2.0, image.width / 120)
    x = float(ends[0, 0])
    ys = np.linspace(ends[0, 1], ends[1, 1], n + 1)
    draw.rectangle((x - half_w - 1, ys[-1] - 1, x + half_w + 1, ys[0] + 1), fill=(0, 0, 0))
    for k in range(n):
        colour = (245, 245, 245) if k % 2 else (25, 25, 25)
        lo_y, hi_y = sorted((float(ys[k]), float(ys[k + 1])))
        draw.rectangle((x - half_w, lo_y, x + half_w, hi_y), fill=colour)
    font = _font(max(12, image.height // 40))
    label = f"{shot.bar_metres:g} m"
    x0, y0, x1, y1 = draw.textbbox((0, 0), label, font=font)
    draw.text(
        (x - (x1 - x0) / 2, float(ys[-1]) - (y1 - y0) - 8), label, fill=(15, 15, 15), font=font
    )


def _render(
    ctx: moderngl.Context,
    scene: SceneArrays,
    camera: Camera,
    size: tuple[int, int],
) -> NDArray[np.uint8]:
    """``(h, w, 4)`` uint8 frame 0 of ``scene``, staged (ground, sky, sun shadows, MSAA, tone
    map: worker.render.staging.STAGED)."""
    # the species' shipped bark set, as the grammar's ``bark`` names it
    images = tile_images(scene.manifest, None, scene.tile_folder, bark=scene.bark_tile_set)
    renderer = Renderer(ctx, scene, size, images, staging=STAGED)
    try:
        pts = scene_surface_points(scene)
        tess = auto_lod(camera, pts.min(axis=0), pts.max(axis=0), TESS_MAX)
        # sub-pixel twigs of a stand's far trees are skipped, as `forest render` does
        renderer.draw(camera, tess, lod_pixels=DEFAULT_LOD_PIXELS)
        raise_gl_error(ctx, "rendering the gallery")
        return renderer.read_color()
    finally:
        renderer.release()


def _scene(grammar: Grammar, seed: int, options: ForestOptions, path: Path) -> SceneArrays:
    # read back only: the instanced forms suffice (no skinned trees to bake)
    forest = generate_forest(grammar, seed, options)
    # read back for its arrays only: the renderer takes the shipped tiles itself
    return read_scene(write_scene(forest, path, skinned=False, textures=False))


def _stand_scene(
    grammar: Grammar, seed: int, trees: int, spacing: float, path: Path
) -> tuple[SceneArrays, float, int]:
    """A stand of ``trees`` (fewer if the forest's piece cap says so) on a square that gives
    each tree about ``spacing`` metres; returns the scene, the square's side and the count."""
    while True:
        side = spacing * math.sqrt(trees)
        options = ForestOptions(trees=trees, area=(side, side))
        try:
            return _scene(grammar, seed, options, path), side, trees
        except LimitError:
            if trees <= 2:
                raise
            trees //= 2


def _recipe_stand(name: str, trees: int, seed: int, path: Path) -> StandScene:
    """Built-in recipe ``name``'s stand of ``trees`` on RECIPE_SIDE metres square (posed trees),
    written and read back as `forest render` reads it."""
    from forest.stand.generate import plan_stand
    from forest.stand.recipes import load_recipe
    from forest.usd.stand import write_stand
    from worker.render.render_file import load_scene
    from worker.render.stand import load_stand

    area = (RECIPE_SIDE, RECIPE_SIDE)
    stand = plan_stand(load_recipe(name), trees, area, seed)
    write_stand(stand, path, ForestOptions(trees=trees, area=area), skinned=False)
    return load_stand(path, load_scene)


def _render_stand(
    ctx: moderngl.Context, stand: StandScene, camera: Camera, size: tuple[int, int]
) -> NDArray[np.uint8]:
    """``(h, w, 4)`` uint8 frame 0 of every layer of ``stand`` on its terrain, staged."""
    from worker.render.stand import stand_points

    scenes = stand.scenes
    images = [tile_images(s.manifest, None, s.tile_folder, bark=s.bark_tile_set) for s in scenes]
    renderer = Renderer(ctx, scenes[0], size, images[0], staging=STAGED, terrain=stand.terrain)
    try:
        for scene, im in zip(scenes[1:], images[1:], strict=True):
            renderer.add_layer(scene, im)
        pts = stand_points(stand)
        tess = auto_lod(camera, pts.min(axis=0), pts.max(axis=0), TESS_MAX)
        renderer.draw(camera, tess, lod_pixels=DEFAULT_LOD_PIXELS)
        raise_gl_error(ctx, "rendering the gallery")
        return renderer.read_color()
    finally:
        renderer.release()


def recipe_cameras(stand: StandScene, name: str, size: tuple[int, int]) -> tuple[Camera, Camera]:
    """The overview (RECIPE_ELEVATION up, framing the terrain and every tree) and the eye-level
    view (eyes on the terrain inside the wood, looking at its middle) of a recipe's stand."""
    from worker.render.stand import stand_points, stand_view

    azimuth = RECIPE_AZIMUTH.get(name, AZIMUTH)
    pts = stand_points(stand)
    aspect = size[0] / size[1]
    overview = frame_points(pts, aspect, FOV, azimuth, RECIPE_ELEVATION)
    under = float(stand.floor()(np.asarray(overview.eye[0]), np.asarray(overview.eye[2])))
    # the eye stands in a gap of the wood: the first spot out along the view's azimuth with
    # no trunk within EYE_CLEARANCE (a bush or a crown right before the lens hides the wood)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = 0.5 * (lo + hi)
    az = np.deg2rad(azimuth)
    back = np.array([np.sin(az), np.cos(az)])
    trunks = np.concatenate([s.tree_transforms[:, [0, 2], 3] for s in stand.scenes])
    first = RECIPE_EYE.get(name, RECIPE_EYE_DISTANCE) * RECIPE_SIDE
    distance = first
    for d in np.arange(first, RECIPE_SIDE, 1.0):
        spot = centre[[0, 2]] + d * back
        if np.linalg.norm(trunks - spot, axis=1).min() >= EYE_CLEARANCE:
            distance = float(d)
            break
    spec = CameraSpec(view="eye", fov=FOV, azimuth=azimuth, distance=distance)
    eye, _ = stand_view(stand, size, TESS_MAX, spec=spec, ground=True)
    return with_ground(overview, under), eye


def make_recipe_pictures(
    ctx: moderngl.Context,
    options: GalleryOptions,
    tmp: Path,
    wrote: Callable[[Path, str], Path],
) -> list[tuple[str, Path, Path]]:
    """``recipe_<name>.png`` (overview) and ``recipe_<name>_eye.png`` for each recipe of
    ``options``, at the stand size (height x width of a single tree's picture)."""
    from PIL import Image

    w, h = options.size
    out = []
    for name in options.recipes:
        stand = _recipe_stand(name, options.recipe_trees, options.seed, tmp / f"{name}.usdc")
        trees = sum(len(np.unique(s.tree)) for s in stand.scenes)
        species = ", ".join(dict.fromkeys(n.partition("[")[0] for n in stand.names))
        over_cam, eye_cam = recipe_cameras(stand, name, (h, w))
        side = f"{RECIPE_SIDE:.0f} m x {RECIPE_SIDE:.0f} m"
        paths = []
        for cam, kind, file in ((over_cam, "overview", ""), (eye_cam, "eye level", "_eye")):
            image = Image.fromarray(_render_stand(ctx, stand, cam, (h, w))[..., :3])
            _caption(image, f"{name}: {trees} trees on {side}, {kind}")
            paths.append(
                wrote(
                    write_png(options.output / f"recipe_{name}{file}.png", np.asarray(image)),
                    f"recipe {name}, {trees} trees ({species}) on {side}, {kind}",
                )
            )
        out.append((name, paths[0], paths[1]))
    return out


# -- the gallery ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class GalleryEntry:
    """``leaves`` is None for a preset without foliage."""

    preset: str
    single: Path
    stand: Path
    height: float
    pieces: int
    stand_trees: int
    leaves: Path | None = None
    base: Path | None = None

    def closeups(self) -> tuple[Path, ...]:
        return tuple(p for p in (self.leaves, self.base) if p is not None)


def make_gallery(
    options: GalleryOptions, echo: Echo = print, progress: Progress | None = None
) -> list[GalleryEntry]:
    """Write ``<preset>.png``, ``<preset>_leaves.png`` (when it has leaves),
    ``<preset>_base.png`` and ``<preset>_stand.png`` for each preset, ``contact_sheet.png``
    (trees and stands) and ``closeups.png`` into ``options.output``; echo a line per file.
    ``progress`` hears ``("images", done, total)`` as each picture is written (a staged stand
    on a CPU rasteriser takes seconds)."""
    note = progress or (lambda stage, done, total: None)
    options.check()
    from PIL import Image

    out = options.output
    out.mkdir(parents=True, exist_ok=True)
    names = list(options.presets) if options.presets is not None else preset_names()
    w, h = options.size
    entries: list[GalleryEntry] = []
    # each preset's tree, close-ups and stand, then the two sheets
    grammars = {name: load_preset(name) for name in names}
    n_images = sum(3 + bool(g.foliage) for g in grammars.values()) + 2 + 2 * len(options.recipes)
    done = 0

    def wrote(path: Path, line: str) -> Path:
        nonlocal done
        done += 1
        note("images", done, n_images)
        echo(f"wrote {path}: {line}")
        return path

    ctx = create_context()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            note("images", 0, n_images)
            for name in names:
                grammar = grammars[name]
                one = ForestOptions(trees=1, area=(1.0, 1.0))
                scene = _scene(grammar, options.seed, one, Path(tmp) / f"{name}.usdc")
                root = scene.tree_transforms[0, :3, 3]
                bark = posed_vertices(scene)
                shot = frame_tree(scene_surface_points(scene, bark=bark), root, w / h)
                image = Image.fromarray(_render(ctx, scene, shot.camera, (w, h))[..., :3])
                _scale_bar(image, shot)
                _caption(image, f"{name}: {shot.height:.1f} m tall, {scene.n_instances} pieces")
                single = wrote(
                    write_png(out / f"{name}.png", np.asarray(image)),
                    f"{name}, one tree {shot.height:.1f} m tall, {scene.n_instances} pieces, "
                    f"side view, {shot.bar_metres:g} m bar",
                )

                # close-ups are square, as wide as the single tree's picture
                leaves = None
                leaf_cam = frame_leaves(scene, 1.0)
                if leaf_cam is None:  # a grammar whose foliage symbols bore no leaves
                    n_images -= bool(grammar.foliage)
                else:
                    image = Image.fromarray(_render(ctx, scene, leaf_cam, (w, w))[..., :3])
                    _caption(image, f"{name}: leaves, {LEAF_VIEW:g} m across")
                    leaves = wrote(
                        write_png(out / f"{name}_leaves.png", np.asarray(image)),
                        f"{name}, close-up of a shoot's leaves, {LEAF_VIEW:g} m across",
                    )
                base_cam, metres = frame_base(bark, root, shot.height, 1.0)
                image = Image.fromarray(_render(ctx, scene, base_cam, (w, w))[..., :3])
                _caption(image, f"{name}: trunk base, lowest {metres:.1f} m")
                base = wrote(
                    write_png(out / f"{name}_base.png", np.asarray(image)),
                    f"{name}, close-up of the trunk's base, lowest {metres:.1f} m",
                )

                spacing = max(0.9 * shot.crown_width, 0.4 * shot.height, 0.5)
                stand, side, n = _stand_scene(
                    grammar,
                    options.seed,
                    options.stand_trees,
                    spacing,
                    Path(tmp) / f"{name}_stand.usdc",
                )
                pts = scene_surface_points(stand)
                cam = place_camera(CameraSpec(view="overview", fov=FOV), pts, h / w, ground=True)
                image = Image.fromarray(_render(ctx, stand, cam, (h, w))[..., :3])
                _caption(image, f"{name}: {n} trees on {side:.0f} m x {side:.0f} m")
                stand_path = wrote(
                    write_png(out / f"{name}_stand.png", np.asarray(image)),
                    f"{name}, {n} trees, {stand.n_instances} pieces, {side:.0f} m square, overview",
                )
                entries.append(
                    GalleryEntry(
                        name, single, stand_path, shot.height, scene.n_instances, n, leaves, base
                    )
                )
            make_recipe_pictures(ctx, options, Path(tmp), wrote)
    finally:
        ctx.release()
    wrote(write_png(out / "contact_sheet.png", contact_sheet(entries)), f"{len(entries)} preset(s)")
    closeups = contact_sheet(entries, images=GalleryEntry.closeups)
    wrote(write_png(out / "closeups.png", closeups), f"close-ups of {len(entries)} preset(s)")
    return entries


def _tree_and_stand(e: GalleryEntry) -> tuple[Path, ...]:
    return (e.single, e.stand)


def contact_sheet(
    entries: Sequence[GalleryEntry],
    thumb: int = SHEET_THUMB,
    images: Callable[[GalleryEntry], tuple[Path, ...]] = _tree_and_stand,
) -> NDArray[np.uint8]:
    """``(h, w, 3)`` uint8: per preset, its ``images`` (default its tree and its stand)
    scaled to ``thumb`` pixels high under its name; two presets a row (one when there is
    one)."""
    from PIL import Image, ImageDraw

    font = _font(max(14, thumb // 14))
    label_h, gap = thumb // 10 + 6, 12
    cells = []
    for e in entries:
        parts = []
        for path in images(e):
            with Image.open(path) as im:
                rgb = im.convert("RGB")
            parts.append(
                rgb.resize((round(rgb.width * thumb / rgb.height), thumb), Image.Resampling.LANCZOS)
            )
        width = sum(p.width for p in parts) + gap * max(len(parts) - 1, 0)
        cell = Image.new("RGB", (max(width, thumb), label_h + thumb), "white")
        x = 0
        for part in parts:
            cell.paste(part, (x, label_h))
            x += part.width + gap
        ImageDraw.Draw(cell).text((4, 2), e.preset, fill=(0, 0, 0), font=font)
        cells.append(cell)
    cols = 1 if len(cells) <= 1 else 2
    rows = max(1, math.ceil(len(cells) / cols))
    cw = max((c.width for c in cells), default=thumb)
    ch = label_h + thumb
    sheet = Image.new("RGB", (cols * cw + (cols + 1) * gap, rows * ch + (rows + 1) * gap), "white")
    for k, cell in enumerate(cells):
        r, c = divmod(k, cols)
        sheet.paste(cell, (gap + c * (cw + gap), gap + r * (ch + gap)))
    return np.asarray(sheet)
