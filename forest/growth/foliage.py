"""Foliage (paper 6): the leaf-cloud models built in code, their procedural textures, and the
anchors that tie each cloud to the bone of the piece it sits on.

A leaf cloud is one small mesh of leaf cards (quads, double sided) inside a ball of unit
diameter about the origin. Each leaf family (``Leaves.family`` of the grammar) has MODELS
clouds of its own shape and its own texture:

* ``broadleaf``: clumpy balls of broad rhombus leaf cards, stems pointing outwards;
* ``needles``: brushes of needle sprigs (a card shows a twig with needles either side)
  radiating from a few twig segments;
* ``strands``: curtains of narrow leaves in vertical chains hanging from the top of the
  cloud (willow, birch).

Every foliage instance shows one model (``model``), turned about the vertical by ``yaw`` (a
turn about the vertical only, so strands keep hanging down; one of YAW_STEPS headings, so a
renderer can keep one impostor picture per model and heading), scaled by its size (a diameter
in metres), tinted by ``color`` (linear RGB: the textures are neutral detail, the colour comes
from the grammar's palette, one base colour per tree and a small jitter per cloud).

An anchor is a point in a piece's model space (the hub joint) and the palette entry of that
piece's hub bone; the cloud's centre at any frame is that palette matrix applied to the rest
point, so foliage follows the wind with its branch.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal, get_args

import numpy as np
from numpy.typing import NDArray

from forest.geometry.pieces import HUB
from forest.geometry.transforms import F64
from schemas.grammar import Leaves

Family = Literal["broadleaf", "needles", "strands"]
FAMILIES: tuple[Family, ...] = get_args(Family)
Season = Literal["summer", "autumn"]
SEASONS: tuple[Season, ...] = get_args(Season)
MODELS = 3  # cloud models per family
CARDS = 256  # cards per cloud model (every model: 512 triangles)
YAW_STEPS = 8  # headings a cloud may take (the renderer's impostor pictures per model)
LEAF_SEED = 6
TEXTURE_SIZE = 128
CLOUD_RADII = 7.0  # default cloud diameter in radii of the piece it sits on (Leaves.size)
# corners of a card in its own (across, along) frame, and their st, in the order base, right,
# tip, left: a rhombus for leaf blades, a rectangle for needle sprigs
RHOMBUS = np.array([[0.0, 0.0], [0.5, 0.4], [0.0, 1.0], [-0.5, 0.4]])
RHOMBUS_ST = np.array([[0.5, 0.0], [1.0, 0.4], [0.5, 1.0], [0.0, 0.4]])
RECT = np.array([[0.0, 0.0], [0.5, 0.0], [0.5, 1.0], [-0.5, 1.0]])
RECT_ST = np.array([[0.5, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
CARD, CARD_ST = RHOMBUS, RHOMBUS_ST  # the broad leaf's card (kept for existing callers)
LEAF_GREEN = (0.22, 0.42, 0.13)  # linear RGB of clouds that carry no colour (older scenes)
# per-cloud jitter about its tree's base colour: hue in turns, saturation and value as
# log-normal factors (small: a tree reads as one colour, its clouds do not look pasted)
HUE_JITTER = 0.012
SAT_JITTER = 0.08
VALUE_JITTER = 0.12


@dataclass(frozen=True, eq=False)
class LeafCloud:
    """positions, normals : (4 c, 3)   st : (4 c, 2)   quads : (c, 4) int32 (one card each).

    Each card owns its four vertices (flat normal); every vertex lies within distance 0.5 of
    the origin; ``family`` names the texture its st coordinates index."""

    positions: F64
    normals: F64
    st: F64
    quads: NDArray[np.int32]
    family: Family = "broadleaf"

    @property
    def n_cards(self) -> int:
        return len(self.quads)

    @property
    def radius(self) -> float:
        """Largest distance of a vertex from the centre (the billboard's half size)."""
        return float(np.linalg.norm(self.positions, axis=1).max())

    def triangles(self) -> NDArray[np.int32]:
        """``(2 c, 3)`` the cards split along their base-tip diagonal."""
        q = self.quads
        return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]).astype(np.int32)


def _unit(v: F64) -> F64:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _cards(
    base: F64,
    along: F64,
    helper: F64,
    length: F64 | float,
    width: F64 | float,
    shape: F64,
    shape_st: F64,
    family: Family,
) -> LeafCloud:
    """Cards from their base points and stem directions ``(c, 3)``; the blade's plane holds
    ``along`` and is turned about it by ``helper`` (any direction not along it). The cloud is
    scaled about the origin so its farthest vertex lies at 0.5 (unit diameter)."""
    c = len(base)
    along = _unit(along)
    across = _unit(np.cross(along, helper))
    normal = np.cross(across, along)
    length = np.broadcast_to(np.asarray(length, np.float64), (c,))[:, None, None]
    width = np.broadcast_to(np.asarray(width, np.float64), (c,))[:, None, None]
    pos = (
        base[:, None]
        + shape[None, :, 0:1] * width * across[:, None]
        + shape[None, :, 1:2] * length * along[:, None]
    )
    pos = pos.reshape(-1, 3)
    pos *= 0.5 / np.linalg.norm(pos, axis=1).max()
    return LeafCloud(
        positions=pos,
        normals=np.repeat(normal, 4, axis=0),
        st=np.tile(shape_st, (c, 1)),
        quads=np.arange(4 * c, dtype=np.int32).reshape(c, 4),
        family=family,
    )


def _broadleaf(rng: np.random.Generator, model: int, cards: int) -> LeafCloud:
    """Clumps of broad leaves: one ball (model 0), three lobes (1), five flattened lobes (2).
    Leaves sit denser near each clump's surface with stems pointing outwards (towards the
    light), so the silhouette reads as a clumpy cloud and the inside is mostly hidden."""
    lobes, flat = ((1, 1.0), (3, 0.85), (5, 0.7))[model % 3]
    centres = np.zeros((1, 3)) if lobes == 1 else 0.16 * _unit(rng.normal(size=(lobes, 3)))
    centres[:, 1] *= flat
    radius = 0.3 if lobes == 1 else 0.22
    which = rng.integers(lobes, size=cards)
    d = _unit(rng.normal(size=(cards, 3)))
    base = centres[which] + d * (radius * rng.random(cards) ** 0.35)[:, None]
    base[:, 1] *= flat
    along = _unit(base + 1e-3 * d) + 0.6 * rng.normal(size=(cards, 3))
    return _cards(base, along, rng.normal(size=(cards, 3)), 0.2, 0.12, RHOMBUS, RHOMBUS_ST,
                  "broadleaf")  # fmt: skip


def _needles(rng: np.random.Generator, model: int, cards: int) -> LeafCloud:
    """Needle sprigs radiating from twig segments: a round brush (model 0), a flat spray of
    level twigs (1, fir-like), upturned tufts (2, pine-like)."""
    twigs = (12, 9, 14)[model % 3]
    dirs = _unit(rng.normal(size=(twigs, 3)))
    if model % 3 == 1:
        dirs[:, 1] *= 0.25
    elif model % 3 == 2:
        dirs[:, 1] = np.abs(dirs[:, 1]) + 0.6
    dirs = _unit(dirs)
    start = 0.05 * rng.normal(size=(twigs, 3))
    which = rng.integers(twigs, size=cards)
    t = rng.random(cards) ** 0.6
    base = start[which] + (0.3 * t)[:, None] * dirs[which]
    # a sprig leaves its twig at 30-70 degrees, on any side of it
    side = _unit(np.cross(dirs[which], rng.normal(size=(cards, 3))))
    angle = np.radians(rng.uniform(30, 70, cards))[:, None]
    along = np.cos(angle) * dirs[which] + np.sin(angle) * side
    # the sprig's plane holds its twig's direction (a flat brush along the twig)
    return _cards(base, along, dirs[which], 0.24, 0.15, RECT, RECT_ST, "needles")


def _strands(rng: np.random.Generator, model: int, cards: int) -> LeafCloud:
    """Curtains of narrow leaves in chains hanging from the top of the cloud: long strands
    over a disk (model 0), more and shorter ones (1), a ring of strands round a hollow (2)."""
    n, lo, hi = ((16, 0.6, 0.9), (24, 0.4, 0.7), (20, 0.55, 0.85))[model % 3]
    phi = rng.uniform(0, 2 * np.pi, n)
    rho = 0.4 * (rng.uniform(0.6, 1.0, n) if model % 3 == 2 else np.sqrt(rng.random(n)))
    top = np.stack([rho * np.cos(phi), 0.42 - 0.25 * rho**2, rho * np.sin(phi)], axis=1)
    top[:, 1] += 0.03 * rng.normal(size=n)
    length = rng.uniform(lo, hi, n)
    strand = np.arange(cards) % n
    per = np.bincount(strand, minlength=n)
    rank = np.zeros(cards, np.int64)
    order = np.argsort(strand, kind="stable")
    rank[order] = np.arange(cards) - np.repeat(np.cumsum(per) - per, per)
    f = (rank + rng.random(cards) * 0.5) / per[strand]  # 0 at the top, 1 at the strand's end
    sway = 0.04 * rng.normal(size=(n, 3)) * np.array([1.0, 0.0, 1.0])
    base = top[strand] + f[:, None] * (
        np.array([0.0, -1.0, 0.0]) * length[strand, None] + sway[strand]
    )
    # leaves hang: down, splayed a little outwards and to the sides, blades turned at random
    out = np.stack([np.cos(phi), np.zeros(n), np.sin(phi)], axis=1)[strand]
    along = np.array([0.0, -1.0, 0.0]) + 0.35 * out + 0.3 * rng.normal(size=(cards, 3))
    along[:, 1] = -np.abs(along[:, 1]) - 0.5
    helper = rng.normal(size=(cards, 3)) * np.array([1.0, 0.2, 1.0])
    return _cards(base, along, helper, 0.11, 0.045, RHOMBUS, RHOMBUS_ST, "strands")


_BUILDERS = {"broadleaf": _broadleaf, "needles": _needles, "strands": _strands}


def leaf_cloud(
    family: Family = "broadleaf", model: int = 0, cards: int = CARDS, seed: int = LEAF_SEED
) -> LeafCloud:
    """Cloud ``model`` (0 .. MODELS - 1) of ``family``: ``cards`` cards, unit diameter. The same
    arguments give the same cloud."""
    if family not in _BUILDERS:
        raise ValueError(f"leaves.family must be one of {FAMILIES}, got {family!r}")
    if not 0 <= model < MODELS:
        raise ValueError(f"model must be in [0, {MODELS}), got {model}")
    rng = np.random.default_rng([seed, FAMILIES.index(family), model])
    return _BUILDERS[family](rng, model, cards)


@lru_cache(maxsize=len(FAMILIES))
def cloud_models(family: Family = "broadleaf") -> tuple[LeafCloud, ...]:
    """The MODELS clouds of ``family`` (built once; do not modify their arrays)."""
    return tuple(leaf_cloud(family, m) for m in range(MODELS))


def _blade(x: F64, tt: F64, widest: float, width: float, tip: float = 0.985) -> NDArray[np.bool_]:
    """Where a leaf blade is, in card coordinates (x across in -1..1, t along in 0..1):
    zero width at the stem and the tip, widest at ``widest``."""
    rise = np.sin(np.pi * 0.5 * tt / widest)
    fall = np.cos(np.pi * 0.5 * (tt - widest) / (1 - widest))
    half = np.where(tt < widest, rise, fall)
    half = width * np.clip(half, 0, 1) ** 0.8 * np.clip((tt - 0.04) / 0.06, 0, 1)
    half *= np.clip((tip - tt) / 0.05, 0, 1)
    return np.asarray(np.abs(x) <= half)


def leaf_texture(family: Family = "broadleaf", size: int = TEXTURE_SIZE) -> NDArray[np.uint8]:
    """``(size, size, 4)`` RGBA8 (row 0 is t = 0, the stem end), rgb sRGB-encoded: the family's
    leaf, alpha 255 on it and 0 around it. The rgb is neutral detail (midrib, veins, mottle,
    shading) that the renderer multiplies by each cloud's colour. Made from code, so nothing
    of unclear origin ships and any worker can rebuild it.

    broadleaf: a broad blade with midrib and side veins; strands: a narrow lanceolate blade;
    needles: a sprig, a twig along the middle with needles either side pointing forwards."""
    if family not in _BUILDERS:
        raise ValueError(f"leaves.family must be one of {FAMILIES}, got {family!r}")
    t = (np.arange(size) + 0.5) / size
    s, tt = np.meshgrid(t, t)  # s across (column), t along (row)
    x = (s - 0.5) * 2.0  # -1..1 across
    rng = np.random.default_rng([size, FAMILIES.index(family)])
    mottle = 1.0 + 0.06 * rng.standard_normal((size, size))
    if family == "needles":
        twig = (np.abs(x) < 0.06) & (tt > 0.03) & (tt < 0.97)
        # needles leave the twig every 1/11 of its length at 55 degrees, 0.9 half-widths long,
        # thick enough to stay a few texels wide in a 256-texel impostor of the cloud
        phase = (tt - 0.7 * np.abs(x)) * 11.0
        needle = (np.abs(phase - np.round(phase)) < 0.24) & (np.abs(x) < 0.92)
        needle &= (tt - 0.7 * np.abs(x) > 0.02) & (tt < 0.99)
        shape = twig | needle
        value = np.where(twig, 0.55, 0.8 + 0.2 * np.abs(x)) * mottle
    else:
        widest, width = (0.4, 0.95) if family == "broadleaf" else (0.3, 0.9)
        shape = _blade(x, tt, widest, width)
        rib = np.abs(x) < 0.045
        vein_phase = (tt - 0.55 * np.abs(x)) * (9.0 if family == "broadleaf" else 14.0)
        veins = (np.abs(vein_phase - np.round(vein_phase)) < 0.07) & (tt > 0.1)
        value = (0.72 + 0.25 * (1 - np.abs(x)) * np.clip(tt * 1.5, 0, 1)) * mottle
        value = np.where(rib | veins, value * 1.15, value)
    # neutral with a touch of warmth in the lighter parts (veins and midribs yellow a little)
    rgb = np.clip(value[..., None] * np.array([1.0, 1.0, 0.93]), 0, 1)
    out = np.zeros((size, size, 4), np.uint8)
    out[..., :3] = np.round(np.power(rgb, 1 / 2.2) * 255).astype(np.uint8)
    out[..., 3] = np.where(shape, 255, 0).astype(np.uint8)
    return out


# -- colours -----------------------------------------------------------------------------------


def hex_to_linear(colors: list[str]) -> NDArray[np.float64]:
    """``(n, 3)`` linear RGB of sRGB ``#rrggbb`` strings."""
    srgb = np.array([[int(c[i : i + 2], 16) for i in (1, 3, 5)] for c in colors], np.float64)
    srgb /= 255.0
    return np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)


def _rgb_to_hsv(rgb: F64) -> F64:
    mx, mn = rgb.max(axis=-1), rgb.min(axis=-1)
    d = mx - mn
    safe = np.where(d > 0, d, 1.0)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    h = np.where(mx == r, (g - b) / safe, np.where(mx == g, 2 + (b - r) / safe, 4 + (r - g) / safe))
    h = np.where(d > 0, (h / 6.0) % 1.0, 0.0)
    s = np.where(mx > 0, d / np.where(mx > 0, mx, 1.0), 0.0)
    return np.stack([h, s, mx], axis=-1)


def _hsv_to_rgb(hsv: F64) -> F64:
    h, s, v = hsv[..., 0] % 1.0, hsv[..., 1], hsv[..., 2]
    k = (np.array([5.0, 3.0, 1.0]) + 6.0 * h[..., None]) % 6.0
    return v[..., None] - (v * s)[..., None] * np.clip(np.minimum(k, 4 - k), 0, 1)


def cloud_colors(
    palette: list[str], tree: NDArray[np.int32], rng: np.random.Generator
) -> NDArray[np.float32]:
    """``(k, 3)`` float32 linear RGB: every tree draws a base colour from the sRGB ``palette``,
    every cloud jitters its tree's colour a little in hue, saturation and value."""
    if not palette:
        raise ValueError("leaves.colors must name at least one colour")
    tree = np.asarray(tree, np.int64)
    k = len(tree)
    n_trees = int(tree.max()) + 1 if k else 0
    base = hex_to_linear(palette)[rng.integers(len(palette), size=n_trees)]
    hsv = _rgb_to_hsv(base[tree]) if k else np.zeros((0, 3))
    hsv[:, 0] += HUE_JITTER * rng.standard_normal(k)
    hsv[:, 1] = np.clip(hsv[:, 1] * np.exp(SAT_JITTER * rng.standard_normal(k)), 0, 1)
    hsv[:, 2] = np.clip(hsv[:, 2] * np.exp(VALUE_JITTER * rng.standard_normal(k)), 0, 1)
    return _hsv_to_rgb(hsv).astype(np.float32)


# -- anchors -----------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FoliageAnchors:
    """instance : (k,) int32 piece instance each cloud sits on
    bone : (k,) int32 the palette entry it follows (the instance's bone offset + HUB)
    rest : (k, 3) float64 its point in the piece's model space
    size : (k,) float64 cloud diameter, metres
    model : (k,) int32 which of the family's MODELS clouds it shows
    yaw : (k,) float64 radians about the vertical (+y), a multiple of 2 pi / YAW_STEPS
    color : (k, 3) float32 linear RGB tint
    family : the leaf family of every cloud"""

    instance: NDArray[np.int32]
    bone: NDArray[np.int32]
    rest: F64
    size: F64
    model: NDArray[np.int32]
    yaw: F64
    color: NDArray[np.float32]
    family: Family = "broadleaf"

    def __len__(self) -> int:
        return len(self.instance)

    def positions(self, palette: F64, row_vectors: bool = False) -> F64:
        """``(k, 3)`` cloud centres: each anchor's palette matrix applied to its rest point
        (``palette`` in column-vector form, or USD's row-vector form with ``row_vectors``)."""
        return anchor_positions(palette, self.bone, self.rest, row_vectors)


def anchor_positions(
    palette: F64, bone: NDArray[np.int32], rest: F64, row_vectors: bool = False
) -> F64:
    """``palette[bone]`` applied to the points ``rest`` (see FoliageAnchors.positions)."""
    m = palette[bone]
    if row_vectors:
        return np.einsum("ni,nij->nj", rest, m[:, :3, :3]) + m[:, 3, :3]
    return np.einsum("nij,nj->ni", m[:, :3, :3], rest) + m[:, :3, 3]


def yaw_quaternions(yaw: F64) -> F64:
    """``(k, 4)`` unit quaternions, xyzw (numpy's layout of USD's quaternion arrays), of turns
    by ``yaw`` radians about +y."""
    half = 0.5 * np.asarray(yaw, np.float64)
    z = np.zeros_like(half)
    return np.stack([z, np.sin(half), z, np.cos(half)], axis=-1)


def foliage_anchors(
    instance: NDArray[np.int32],
    piece: NDArray[np.int32],
    bone_offset: NDArray[np.int32],
    hub_rest: F64,
    radius: F64,
    tree: NDArray[np.int32],
    leaves: Leaves,
    rng: np.random.Generator,
    season: Season = "summer",
    heading: F64 | None = None,
) -> FoliageAnchors:
    """Anchors at the hubs of the foliage-bearing ``instance``\\ s (k of them).

    radius : (k,) float64 the branch radius (metres) at each anchor: the cloud's diameter is
    ``leaves.size`` of it. tree : (k,) int32 the tree of each anchor (one base colour per
    tree). Model, heading and colour are drawn from ``rng``, so a seed gives the same clouds;
    ``season="autumn"`` takes the colours from ``leaves.autumn_colors`` (the summer palette
    when that is empty). heading : (k,) float64 radians, the azimuth of each anchor's branch:
    clouds turn with their branch (snapped to the YAW_STEPS headings) instead of at random."""
    if season not in SEASONS:
        raise ValueError(f"season must be one of {SEASONS}, got {season!r}")
    idx = np.asarray(instance, np.int32)
    k = len(idx)
    radius = np.asarray(radius, np.float64)
    tree = np.asarray(tree, np.int32)
    for name, arr in (("radius", radius), ("tree", tree)):
        if arr.shape != (k,):
            raise ValueError(f"{name} must have shape ({k},), got {arr.shape}")
    if not (np.isfinite(radius).all() and (radius > 0).all()):
        raise ValueError("radius must be finite and positive")
    palette = leaves.autumn_colors if season == "autumn" and leaves.autumn_colors else leaves.colors
    model = rng.integers(MODELS, size=k).astype(np.int32)
    step = rng.integers(YAW_STEPS, size=k)
    if heading is not None:  # turned with its branch: the heading nearest the branch's
        step = np.round(np.asarray(heading, np.float64) / (2 * np.pi / YAW_STEPS)).astype(int)
    yaw = (np.mod(step, YAW_STEPS) * (2 * np.pi / YAW_STEPS)).astype(np.float64)
    return FoliageAnchors(
        instance=idx,
        bone=(bone_offset[idx] + HUB).astype(np.int32),
        rest=hub_rest[piece[idx]],
        size=leaves.size * radius,
        model=model,
        yaw=yaw,
        color=cloud_colors(list(palette), tree, rng),
        family=leaves.family,
    )
