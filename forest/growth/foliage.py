"""Foliage (paper 6): the leaf-spray models built in code, their procedural leaf pictures, and
the anchors that tie each spray to the bone of the piece it grows from.

A leaf spray is one small shoot of the last order with its leaves, in metres at the species'
real size: a thin stem (cards showing the picture's petiole) carrying leaf cards (quads,
double sided, cut to the leaf by the picture's alpha) with the species' phyllotaxis. The
shoot leaves its attachment point (the model's origin) along +z, rising or hanging as the
species grows, so a turn about the vertical (``yaw``) points it away from its branch. Each
leaf family (``Leaves.family`` of the grammar) has MODELS sprays of its own (different shoot
lengths, leaf counts, curvature) and its own picture:

* ``oak``: lobed leaves crowded at the shoot's end, alternate spiral, facing the light;
* ``birch``: small triangular leaves on long stalks along pendulous shoots;
* ``hazel``: round toothed leaves, alternate in two ranks, facing the light;
* ``willow``: narrow leaves along long shoots that hang straight down;
* ``almond``: narrow toothed leaves, spiral, facing the light;
* ``poplar``: triangular leaves on long stalks, spiral;
* ``pine``: tufts of needle pairs round the end of upturned shoots;
* ``spruce``: branchlets with side shoots, short needles all round every shoot;
* the older names ``broadleaf`` (ovate leaves, spiral), ``needles`` (spruce-like sprigs) and
  ``strands`` (hanging narrow leaves) keep working for user grammars.

Every foliage instance shows one model (``model``), turned about the vertical by ``yaw`` (a
turn about the vertical only, so hanging shoots keep hanging and leaves keep facing up; one of
YAW_STEPS headings, so a renderer can keep one impostor picture per model and heading), scaled
by its size (a small jitter about 1: the models are in metres), tinted by ``color`` (linear
RGB: the pictures are neutral detail, the colour comes from the grammar's palette, one base
colour per tree and a small jitter per spray).

An anchor is a point in a piece's model space (on the piece's axis between its hub and a
terminal) and the palette entry of that piece's hub bone; the spray's origin at any frame is
that palette matrix applied to the rest point, so foliage follows the wind with its branch.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal, get_args

import numpy as np
from numpy.typing import NDArray

from forest.bark.images import srgb_to_linear
from forest.geometry.pieces import HUB, TIP0
from forest.geometry.transforms import BLOCK, F64
from schemas.grammar import Leaves

Family = Literal[
    "broadleaf", "needles", "strands",
    "oak", "birch", "hazel", "willow", "almond", "poplar", "pine", "spruce",
]  # fmt: skip
FAMILIES: tuple[Family, ...] = get_args(Family)
Phyllotaxis = Literal["spiral", "alternate", "opposite", "whorled"]
Season = Literal["summer", "autumn"]
SEASONS: tuple[Season, ...] = get_args(Season)
MODELS = 8  # spray models per family (8 x 8 headings: 64 impostor pictures)
YAW_STEPS = 8  # headings a spray may take (the renderer's impostor pictures per model)
LEAF_SEED = 6
TEXTURE_SIZE = 512
# a card's corners in its own (across, along) frame and their st, in the order base-left,
# base-right, tip-right, tip-left (split into triangles along the 0-2 diagonal)
RECT = np.array([[-0.5, 0.0], [0.5, 0.0], [0.5, 1.0], [-0.5, 1.0]])
RECT_ST = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
CARD, CARD_ST = RECT, RECT_ST
# where each picture lies in a family's texture (s from, s to, t from, t to): one leaf, a
# cluster of ROSETTE leaves seen from above, and the stalk that stem cards show
LEAF_ST = (0.0, 0.5, 0.0, 1.0)
ROSETTE_ST = (0.5, 1.0, 0.5, 1.0)
ROSETTE = 6
ROSETTE_LEAF = 0.96  # the longest leaf of a cluster over the picture's half width
# the lower right quarter: a branched side shoot of SPRAY_LEAVES leaves seen from above, on a
# card SPRAY_LONG leaf lengths long and SPRAY_WIDE wide, so its leaves are drawn at their size
SPRAY_ST = (0.5, 1.0, 0.0, 0.5)
SPRAY_LONG, SPRAY_WIDE = 3.6, 4.2
# its layout in leaf lengths (x across, y along): leaves along the main twig (base x, base y,
# heading from +y in degrees, size), then twigs (base, heading in degrees, length) each ending
# in a fan of leaves (their headings off the twig's): the leaves of an oak or poplar shoot
# crowd towards its end. The first twig is the main one, up the middle.
_SPRAY_MAIN_LEAVES = ((0.0, 0.3, -60.0, 0.88), (0.0, 0.62, 58.0, 0.9), (0.0, 1.1, 34.0, 0.9),
                      (0.0, 1.5, -30.0, 0.9))  # fmt: skip
_FOUR = (-62, -22, 22, 62)
_SPRAY_TWIGS = (((0.0, 0.0), 0.0, SPRAY_LONG - 1.0, (-72, -36, 0, 36, 72)),
                ((0.0, 0.45), -58.0, 1.15, _FOUR), ((0.0, 0.85), 56.0, 1.1, _FOUR),
                ((0.0, 1.35), -48.0, 0.95, _FOUR), ((0.0, 1.7), 46.0, 0.85, _FOUR))  # fmt: skip
SPRAY_LEAVES = len(_SPRAY_MAIN_LEAVES) + sum(len(fan) for *_, fan in _SPRAY_TWIGS)
STEM, LEAF, CLUSTER, SPRAY = 0, 1, 2, 3  # what a card shows (LeafCloud.kind)
# a spruce sprig card is SPRIG_RATIO times as long as it is wide (its width twice a needle's
# reach), so the picture draws its needles at their metric size: 1-2.5 cm, not streaks along
# the card (a card per needle would cost ~30x the triangles)
SPRIG_RATIO = 8.0
SPRIG_NEEDLE_ANGLE = 55.0  # degrees between a needle and its twig, pointing forwards
STEM_S = (0.245, 0.255)
STEM_T = (0.015, 0.05)
LEAF_GREEN = (0.22, 0.42, 0.13)  # linear RGB of sprays that carry no colour (older scenes)
# per-spray jitter about its tree's base colour: hue in turns, saturation and value as
# log-normal factors (small: a tree reads as one colour, its sprays do not look pasted)
HUE_JITTER = 0.012
SAT_JITTER = 0.08
VALUE_JITTER = 0.12
UP = np.array([0.0, 1.0, 0.0])
GOLDEN = 137.5


@dataclass(frozen=True)
class SprayForm:
    """How a family's shoots carry their leaves (all lengths in metres).

    length: leaf card length range (stalk included); aspect: card width over length;
    petiole: the stalk's share of the card; leaves: leaf count range per shoot; shoot: shoot
    length range; crowd: > 1 crowds the leaves towards the shoot's end; habit: ``spread``
    (leaves turned to face the light), ``hanging`` (shoot and leaves hang), ``tuft`` (needle
    fans round the shoot's end), ``sprig`` (needle sprigs all round a branchlet); rise: the
    shoot's start above the horizontal, degrees; stem: stem card width; sides: range of the
    side shoots of the last order on the spray's shoot (so a spray is a branchlet of the
    last two orders), side: their length range; rosette: every shoot ends in a cluster of
    leaves (one card showing ROSETTE leaves from above); tilt: habit ``spread``, the largest
    angle in degrees by which a blade rolls out of level about its own axis (a cluster leans
    out over its shoot's heading by 35-70 % of it): the sun leaves of a crown's outer shell
    stand at many angles, so a crown seen from the side reads as leafy, not as level blades
    seen edge-on (0: level blades, clusters leaning about 27 degrees); flat_sides: each side
    shoot is one card of a shoot's leaves seen from above (SPRAY_ST) and the leaf below it,
    not a stem card and its leaves one by one (two cards where it took about nine, so more
    sprays fit a tree's triangle budget; the card leans out over the shoot's heading by
    60-120 % of ``tilt``, so a crown seen from the side shows its leaves). Leaf counts are
    per shoot, besides the rosette's."""

    length: tuple[float, float]
    aspect: float
    petiole: float
    phyllotaxis: Phyllotaxis
    leaves: tuple[int, int]
    shoot: tuple[float, float]
    crowd: float = 1.0
    habit: Literal["spread", "hanging", "tuft", "sprig"] = "spread"
    rise: tuple[float, float] = (5.0, 35.0)
    stem: float = 0.004
    sides: tuple[int, int] = (0, 0)
    side: tuple[float, float] = (0.1, 0.2)
    rosette: bool = False
    tilt: float = 0.0
    spurs: tuple[int, int] = (0, 0)
    flat_sides: bool = False


FORMS: dict[str, SprayForm] = {
    "oak": SprayForm((0.08, 0.14), 0.62, 0.06, "spiral", (8, 11), (0.8, 1.3), crowd=1.8,
                     sides=(4, 7), side=(0.25, 0.55), rosette=True, tilt=40.0, spurs=(1, 1),
                     rise=(-15.0, 45.0), flat_sides=True),
    "birch": SprayForm((0.05, 0.08), 0.62, 0.32, "spiral", (5, 8), (0.4, 0.8),
                       habit="hanging", rise=(0.0, 25.0), stem=0.003, sides=(2, 4),
                       side=(0.15, 0.3)),
    "hazel": SprayForm((0.07, 0.12), 0.82, 0.12, "alternate", (4, 7), (0.35, 0.6),
                       sides=(2, 3), side=(0.15, 0.3)),
    "willow": SprayForm((0.08, 0.14), 0.2, 0.05, "spiral", (16, 24), (0.8, 1.6),
                        habit="hanging", rise=(10.0, 30.0), stem=0.003, sides=(1, 2),
                        side=(0.4, 0.8)),
    "almond": SprayForm((0.08, 0.12), 0.3, 0.12, "spiral", (4, 6), (0.3, 0.5), crowd=1.4,
                        sides=(2, 4), side=(0.1, 0.22), rosette=True),
    "poplar": SprayForm((0.06, 0.11), 0.7, 0.3, "spiral", (5, 8), (0.3, 0.5),
                        rise=(25.0, 60.0), sides=(2, 3), side=(0.1, 0.2), flat_sides=True),
    "pine": SprayForm((0.045, 0.07), 0.8, 0.0, "spiral", (10, 14), (0.25, 0.45),
                      habit="tuft", rise=(20.0, 55.0), stem=0.006, sides=(1, 3),
                      side=(0.1, 0.2)),
    "spruce": SprayForm((0.014, 0.024), 1.0, 0.0, "spiral", (4, 7), (0.8, 1.3),
                        habit="sprig", rise=(-15.0, 10.0)),
    "broadleaf": SprayForm((0.07, 0.12), 0.6, 0.1, "spiral", (4, 6), (0.3, 0.55), crowd=1.6,
                           sides=(2, 4), side=(0.1, 0.2), rosette=True),
    "strands": SprayForm((0.07, 0.12), 0.24, 0.06, "spiral", (12, 18), (0.6, 1.2),
                         habit="hanging", rise=(10.0, 30.0), stem=0.003, sides=(1, 2),
                         side=(0.3, 0.6)),
}  # fmt: skip
FORMS["needles"] = FORMS["spruce"]


@dataclass(frozen=True, eq=False)
class LeafCloud:
    """One spray model. positions, normals : (4 c, 3) metres   st : (4 c, 2)
    quads : (c, 4) int32 (one card each).

    Each card owns its four vertices (flat normal); the shoot starts at the origin;
    ``family`` names the picture its st coordinates index; ``kind`` (c,) says what each card
    shows (STEM, LEAF, a cluster of ROSETTE leaves or a SPRAY of SPRAY_LEAVES), None where
    unknown (a model read back from a scene)."""

    positions: F64
    normals: F64
    st: F64
    quads: NDArray[np.int32]
    family: Family = "broadleaf"
    kind: NDArray[np.int8] | None = None

    @property
    def leaf(self) -> NDArray[np.bool_] | None:
        """``(c,)`` the cards that show one leaf (None where unknown)."""
        return None if self.kind is None else np.asarray(self.kind == LEAF)

    @property
    def n_leaves(self) -> int:
        """Leaves shown: one per leaf card, ROSETTE per cluster card, SPRAY_LEAVES per spray."""
        if self.kind is None:
            return self.n_cards
        k = self.kind
        return int(
            (k == LEAF).sum() + ROSETTE * (k == CLUSTER).sum() + SPRAY_LEAVES * (k == SPRAY).sum()
        )

    @property
    def n_cards(self) -> int:
        return len(self.quads)

    @property
    def radius(self) -> float:
        """Largest distance of a vertex from the origin (the billboard's half size)."""
        return float(np.linalg.norm(self.positions, axis=1).max())

    def triangles(self) -> NDArray[np.int32]:
        """``(2 c, 3)`` the cards split along their base-tip diagonal."""
        q = self.quads
        return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]).astype(np.int32)

    def leaf_lengths(self) -> F64:
        """Base-to-tip length of every leaf card, the longest leaf of every cluster card (half
        its side) and the leaves of every spray card (its length over SPRAY_LONG), metres."""
        q = self.quads if self.leaf is None else self.quads[self.leaf]
        one = np.linalg.norm(self.positions[q[:, 3]] - self.positions[q[:, 0]], axis=1)
        if self.kind is None:
            return np.asarray(one)

        def long(kind: int) -> F64:
            q = self.quads[self.kind == kind]
            return np.asarray(
                np.linalg.norm(self.positions[q[:, 3]] - self.positions[q[:, 0]], axis=1)
            )

        return np.concatenate([one, 0.5 * ROSETTE_LEAF * long(CLUSTER), long(SPRAY) / SPRAY_LONG])


def _unit(v: F64) -> F64:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _side(t: F64) -> F64:
    """A horizontal direction across each direction ``t`` (x where ``t`` is vertical)."""
    s = np.cross(t, UP)
    flat = np.linalg.norm(s, axis=-1) < 1e-6
    s[flat] = np.array([1.0, 0.0, 0.0])
    return _unit(s)


class _Cards:
    """Cards collected for one model: base points, along and across directions, lengths,
    widths and st rectangles."""

    def __init__(self) -> None:
        self.parts: list[tuple[F64, F64, F64, F64, F64, F64, int]] = []

    def add(
        self, base: F64, along: F64, across: F64, length: F64, width: F64,
        st: tuple[float, float, float, float] = LEAF_ST, kind: int = LEAF,
    ) -> None:  # fmt: skip
        n = len(base)
        rect = np.broadcast_to(np.asarray(st, np.float64), (n, 4))
        self.parts.append((base, _unit(along), _unit(across), np.broadcast_to(length, (n,)),
                           np.broadcast_to(width, (n,)), rect, kind))  # fmt: skip

    def cloud(self, family: Family) -> LeafCloud:
        pos, nrm, st, kinds = [], [], [], []
        for base, along, across, length, width, rect, kind in self.parts:
            across = _unit(across - (across * along).sum(1, keepdims=True) * along)
            normal = np.cross(across, along)
            p = (
                base[:, None]
                + RECT[None, :, 0:1] * width[:, None, None] * across[:, None]
                + RECT[None, :, 1:2] * length[:, None, None] * along[:, None]
            )
            pos.append(p.reshape(-1, 3))
            nrm.append(np.repeat(normal, 4, axis=0))
            s = rect[:, None, 0] + RECT_ST[None, :, 0] * (rect[:, None, 1] - rect[:, None, 0])
            t = rect[:, None, 2] + RECT_ST[None, :, 1] * (rect[:, None, 3] - rect[:, None, 2])
            st.append(np.stack([s, t], axis=-1).reshape(-1, 2))
            kinds.append(np.full(len(base), kind, np.int8))
        positions = np.concatenate(pos)
        c = len(positions) // 4
        return LeafCloud(
            positions=positions,
            normals=np.concatenate(nrm),
            st=np.concatenate(st),
            quads=np.arange(4 * c, dtype=np.int32).reshape(c, 4),
            family=family,
            kind=np.concatenate(kinds),
        )


def _shoot(
    rng: np.random.Generator, form: SprayForm, length: float, segs: int,
    start: F64 | None = None, azimuth: float = 0.0, rise: float | None = None,
) -> F64:  # fmt: skip
    """``(segs + 1, 3)`` a shoot's polyline from ``start`` (the origin) heading ``azimuth``
    radians from +z about +y: rising by the form's angle (or ``rise`` degrees) and curving a
    little, or (hanging) arching over and falling straight down."""
    rise_r = np.radians(rng.uniform(*form.rise) if rise is None else rise)
    step = length / segs
    pts = [np.zeros(3) if start is None else np.asarray(start, np.float64)]
    for i in range(segs):
        f = (i + 0.5) / segs
        if form.habit == "hanging":
            # out and up for a little, then over and down, hanging straight at the end
            ang = rise_r - (rise_r + np.radians(88)) * min(1.0, f / 0.35) ** 0.8
        else:
            ang = rise_r + np.radians(rng.normal(0, 6)) - 0.25 * rise_r * f
        side = azimuth + rng.normal(0, 0.08)
        d = np.array([np.sin(side) * np.cos(ang), np.sin(ang), np.cos(side) * np.cos(ang)])
        pts.append(pts[-1] + step * d)
    return np.array(pts)


def _side_shoots(rng: np.random.Generator, form: SprayForm, main: F64, segs: int) -> list[F64]:
    """The side shoots of the last order on ``main``: alternately left and right, 35-65
    degrees off its heading, between a fifth and 85 % of its length, shorter towards the
    tip."""
    n = int(rng.integers(form.sides[0], form.sides[1] + 1))
    if n == 0:
        return []
    length = float(np.linalg.norm(np.diff(main, axis=0), axis=1).sum())
    s = length * (np.linspace(0.2, 0.85, n) + rng.uniform(-0.05, 0.05, n))
    at, tangent = _along(main, s)
    out = []
    first = rng.choice([-1.0, 1.0])
    for i in range(n):
        azimuth = float(np.arctan2(tangent[i, 0], tangent[i, 2]))
        if np.hypot(tangent[i, 0], tangent[i, 2]) < 0.3:  # a hanging shoot: any side
            azimuth = rng.uniform(0, 2 * np.pi)
        turn = first * (1 if i % 2 else -1) * np.radians(rng.uniform(35, 65))
        ln = rng.uniform(*form.side) * (1.0 - 0.3 * i / max(n - 1, 1))
        rise = float(np.degrees(np.arcsin(np.clip(tangent[i, 1], -1, 1))))
        rise = rng.uniform(*form.rise) if form.habit == "hanging" else max(rise, 0) * 0.5 + 10
        out.append(_shoot(rng, form, ln, segs, at[i], azimuth + turn, rise))
    return out


def _along(path: F64, s: F64) -> tuple[F64, F64]:
    """Points and unit tangents of the polyline ``path`` at arc lengths ``s``."""
    seg = np.diff(path, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    f = ((s - cum[i]) / seg_len[i])[:, None]
    return path[i] + f * seg[i], _unit(seg[i])


def _rolls(n: int, phyllotaxis: Phyllotaxis, rng: np.random.Generator) -> tuple[F64, F64]:
    """Node index (float, 0..nodes) and roll angle (radians) of ``n`` leaves."""
    start = rng.uniform(0, 2 * np.pi)
    i = np.arange(n)
    if phyllotaxis == "opposite":  # decussate pairs
        node, roll = i // 2, (i // 2) * np.pi / 2 + (i % 2) * np.pi
    elif phyllotaxis == "whorled":  # whorls of three, alternating
        node, roll = i // 3, (i // 3) * np.pi / 3 + (i % 3) * 2 * np.pi / 3
    elif phyllotaxis == "alternate":  # two ranks
        node, roll = i, i * np.pi
    else:
        node, roll = i, i * np.radians(GOLDEN)
    roll = roll + start + rng.normal(0, 0.12, n)
    return node.astype(np.float64), roll


def _frame(tangent: F64, roll: F64) -> F64:
    """Radial directions round each ``tangent`` at angle ``roll`` (0: the upper side)."""
    b = _side(tangent)
    n = np.cross(b, tangent)
    return np.cos(roll)[:, None] * n + np.sin(roll)[:, None] * b


def _stem_cards(cards: _Cards, path: F64, width: float) -> None:
    base = path[:-1]
    along = np.diff(path, axis=0)
    length = np.linalg.norm(along, axis=1)
    cards.add(base, along, _side(_unit(along)), length, np.full(len(base), width),
              (STEM_S[0], STEM_S[1], STEM_T[0], STEM_T[1]), STEM)  # fmt: skip


def _leafy(rng: np.random.Generator, form: SprayForm, lengths: tuple[float, float],
           phyllotaxis: Phyllotaxis, family: Family) -> LeafCloud:  # fmt: skip
    """A branchlet with broad or narrow leaves (habits spread and hanging): its shoot and
    side shoots, each with a stem and its leaves."""
    hanging = form.habit == "hanging"
    main = _shoot(rng, form, rng.uniform(*form.shoot), 6 if hanging else 3)
    cards = _Cards()
    for i, path in enumerate([main, *_side_shoots(rng, form, main, 4 if hanging else 1)]):
        if i and form.flat_sides:
            _flat_side(cards, rng, form, lengths, path)
        else:
            _leaves_on(cards, rng, form, lengths, phyllotaxis, path, hanging)
    return cards.cloud(family)


def _flat_side(
    cards: _Cards, rng: np.random.Generator, form: SprayForm, lengths: tuple[float, float],
    path: F64,
) -> None:  # fmt: skip
    """A side shoot as one SPRAY card along ``path``'s heading, facing up and leaning out
    over it (as a cluster does), its leaves the size of ``lengths``; and the leaf in whose
    axil it grew, at its base."""
    heading = _unit(path[-1] - path[0])
    lean = np.tan(np.radians(rng.uniform(0.6, 1.2) * form.tilt)) if form.tilt else 0.5
    normal = _unit(UP + lean * heading * np.array([1.0, 0.0, 1.0]) + rng.normal(0, 0.15, 3))
    a = _unit(heading - (heading @ normal) * normal)
    leaf = rng.uniform(*lengths)
    cards.add(path[:1], a[None], np.cross(a, normal)[None], np.array([SPRAY_LONG * leaf]),
              np.array([SPRAY_WIDE * leaf]), SPRAY_ST, SPRAY)  # fmt: skip
    # the subtending leaf: out to the side, level, a little drooping
    out = _unit(_side(heading[None])[0] * rng.choice([-1.0, 1.0]) + 0.6 * heading)
    out[1] = -rng.uniform(0.0, 0.2)
    out = _unit(out)[None]
    size = rng.uniform(*lengths)
    cards.add(path[:1], out, _side(out), np.array([size]), np.array([form.aspect * size]))


def _lean(v: F64, angle: F64) -> F64:
    """``v`` (n, 3) turned about +x by ``angle`` (n,) radians: +y towards +z (a level blade
    facing up then faces up and out along +z, the spray's heading)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([v[:, 0], c * v[:, 1] - s * v[:, 2], s * v[:, 1] + c * v[:, 2]], axis=1)


def _leaves_on(
    cards: _Cards, rng: np.random.Generator, form: SprayForm, lengths: tuple[float, float],
    phyllotaxis: Phyllotaxis, path: F64, hanging: bool,
) -> None:  # fmt: skip
    """One shoot's stem cards and its leaves along it by ``phyllotaxis``."""
    length = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    n = int(rng.integers(form.leaves[0], form.leaves[1] + 1))
    node, roll = _rolls(n, phyllotaxis, rng)
    nodes = node.max() + 1
    u = (node + 0.5 + rng.uniform(-0.25, 0.25, n)) / nodes
    s = length * (0.12 + 0.86 * (1 - (1 - u) ** form.crowd))
    at, tangent = _along(path, s)
    radial = _frame(tangent, roll)
    # the youngest leaves near the tip are smaller
    size = rng.uniform(*lengths, n) * (1 - 0.3 * np.clip((s / length - 0.85) / 0.15, 0, 1))
    if hanging:
        # leaves hang along their shoot, splayed outwards a little, blades facing out
        along = _unit(tangent + 0.55 * radial + rng.normal(0, 0.12, (n, 3)))
        along[:, 1] = np.minimum(along[:, 1], -0.35)
        along = _unit(along)
        across = np.cross(radial, along) + rng.normal(0, 0.3, (n, 3))
    else:
        # leaves leave the shoot at 50-70 degrees and turn their blades to the light: mostly
        # level, a little drooping, a mosaic round the shoot
        ins = np.radians(rng.uniform(50, 70, n))[:, None]
        along = np.cos(ins) * tangent + np.sin(ins) * radial
        along[:, 1] = 0.25 * along[:, 1] - rng.uniform(0.0, 0.25, n)
        along = _unit(along)
        across = _side(along) + rng.normal(0, 0.25, (n, 3)) * np.array([0.0, 1.0, 0.0])
        if form.tilt:  # lean each blade out towards the spray's heading (+z), off level
            t = np.radians(rng.uniform(0.3, 1.0, n) * form.tilt)
            along, across = _lean(along, t), _lean(_unit(across), t)
    # a hanging shoot's curve takes many segments for its leaves; its thin stem (mm across)
    # shows the same curve from every other point, half the cards
    _stem_cards(cards, path[::2] if hanging and len(path) % 2 else path, form.stem)
    # a stalk begins at the shoot's surface
    cards.add(at + 0.5 * form.stem * radial, along, across, size, form.aspect * size)
    if form.rosette:  # the cluster at the shoot's end, facing up and a little forwards
        _cluster(cards, rng, form, lengths, path[-1], _unit(path[-1] - path[-2]))
    spurs = int(rng.integers(form.spurs[0], form.spurs[1] + 1)) if form.spurs[1] else 0
    if spurs:  # clusters on short spur shoots along the shoot, a few cm above it
        s = length * (np.linspace(0.3, 0.8, spurs) + rng.uniform(-0.08, 0.08, spurs))
        at, tangent = _along(path, s)
        for i in range(spurs):
            _cluster(cards, rng, form, lengths, at[i] + 0.04 * UP, tangent[i])


def _cluster(
    cards: _Cards, rng: np.random.Generator, form: SprayForm, lengths: tuple[float, float],
    centre: F64, heading: F64,
) -> None:  # fmt: skip
    """One card of ROSETTE leaves round ``centre``, facing up and leaning over ``heading``
    (about 27 degrees, or by the form's tilt)."""
    lean = np.tan(np.radians(rng.uniform(0.35, 0.7) * form.tilt)) if form.tilt else 0.5
    normal = _unit(UP + lean * heading * np.array([1.0, 0.0, 1.0]) + rng.normal(0, 0.15, 3))
    a = _unit(heading - (heading @ normal) * normal + 0.3 * rng.normal(size=3))
    a = _unit(a - (a @ normal) * normal)
    r = rng.uniform(*lengths) / ROSETTE_LEAF
    cards.add((centre - r * a)[None], a[None], np.cross(a, normal)[None],
              np.array([2 * r]), np.array([2 * r]), ROSETTE_ST, CLUSTER)  # fmt: skip


def _tuft(rng: np.random.Generator, form: SprayForm, lengths: tuple[float, float],
          phyllotaxis: Phyllotaxis, family: Family) -> LeafCloud:  # fmt: skip
    """A pine branchlet: a shoot and its side shoots, each with fans of needle pairs all
    round its last half, pointing forwards and out (closer to the shoot towards its tip),
    and a tuft straight ahead at its tip."""
    main = _shoot(rng, form, rng.uniform(*form.shoot), 3)
    cards = _Cards()
    for path in [main, *_side_shoots(rng, form, main, 2)]:
        length = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
        n = int(rng.integers(form.leaves[0], form.leaves[1] + 1))
        node, roll = _rolls(n, phyllotaxis, rng)
        u = (node + rng.uniform(0, 0.5, n)) / (node.max() + 1)
        s = length - min(0.15, 0.6 * length) * (1 - u)
        at, tangent = _along(path, s)
        radial = _frame(tangent, roll)
        spread = np.radians(60 - 35 * u + rng.normal(0, 6, n))[:, None]
        along = np.cos(spread) * tangent + np.sin(spread) * radial
        size = rng.uniform(*lengths, n)
        _stem_cards(cards, path, form.stem)
        cards.add(at, along, np.cross(tangent, radial), size, form.aspect * size)
        tip, t_end = path[-1][None], _unit(path[-1] - path[-2])[None]
        for turn in (0.0, np.pi / 2):  # two crossed fans on the tip
            r = _frame(t_end, np.array([turn]))
            ln = np.array([0.8 * lengths[1]])
            cards.add(tip - 0.01 * t_end, t_end, np.cross(t_end, r), ln, form.aspect * ln)
    return cards.cloud(family)


def _sprig(rng: np.random.Generator, form: SprayForm, lengths: tuple[float, float],
           phyllotaxis: Phyllotaxis, family: Family) -> LeafCloud:  # fmt: skip
    """A spruce branchlet: a main shoot with a few side shoots (alternately left and right,
    at 40-60 degrees), every shoot in segments each shown by two crossed needle sprigs (the
    picture: a twig with needles all round), so needles stand all round the shoots; a
    segment is about SPRIG_RATIO times as long as a sprig is wide, the needles' size in the
    picture."""
    length = rng.uniform(*form.shoot)
    needle = rng.uniform(*lengths)
    width = 2 * needle * form.aspect
    main = _shoot(rng, form, length, _sprig_segments(length, width))
    cards = _Cards()

    def clothe(path: F64) -> None:
        base = path[:-1]
        along = np.diff(path, axis=0)
        seg = np.linalg.norm(along, axis=1)
        t = _unit(along)
        turn = rng.uniform(0, np.pi)
        for k in (0.0, np.pi / 2):
            r = _frame(t, np.full(len(t), turn + k))
            cards.add(base, t, r, seg, np.full(len(t), width))

    clothe(main)
    sides = int(rng.integers(form.leaves[0], form.leaves[1] + 1))
    s = length * np.linspace(0.12, 0.8, sides) + rng.uniform(-0.02, 0.02, sides)
    at, tangent = _along(main, s)
    for i in range(sides):
        side = _side(tangent[i : i + 1])[0] * (1 if i % 2 else -1)
        ang = np.radians(rng.uniform(40, 65))
        d = _unit(np.cos(ang) * tangent[i] + np.sin(ang) * side)
        ln = max(length - s[i], 0.1) * rng.uniform(0.5, 0.8)
        # side shoots sag and, on the lower side, hang (the comb of a spruce's branches)
        k = np.linspace(0, 1, _sprig_segments(ln, width) + 1)[:, None]
        droop = np.array([0.0, -rng.uniform(0.15, 0.6), 0.0]) * k**1.5 * ln
        clothe(at[i] + k * ln * d + droop)
    # branchlets that hang from under the shoot, curtains between a spruce's tiers (the comb
    # habit: they hide the trunk between whorls from a distance)
    hangs = int(rng.integers(1, 3))
    s = length * rng.uniform(0.35, 0.85, hangs)
    at, tangent = _along(main, s)
    for i in range(hangs):
        ln = rng.uniform(0.3, 0.6) * length
        k = np.linspace(0, 1, _sprig_segments(ln, width) + 1)[:, None]
        out = _side(tangent[i : i + 1])[0] * rng.uniform(-0.25, 0.25) + 0.15 * tangent[i]
        clothe(at[i] + k * ln * _unit(out + np.array([0.0, -1.0, 0.0])) - 0.01 * UP)
    return cards.cloud(family)


def _sprig_segments(length: float, width: float) -> int:
    """Cards along a sprig shoot ``length`` metres long: each about SPRIG_RATIO times its
    ``width``, so the picture's needles keep their size."""
    return int(np.clip(round(length / (SPRIG_RATIO * width)), 1, 6))


_BUILDERS = {"spread": _leafy, "hanging": _leafy, "tuft": _tuft, "sprig": _sprig}


def leaf_cloud(
    family: Family = "broadleaf",
    model: int = 0,
    seed: int = LEAF_SEED,
    length: tuple[float, float] | None = None,
    phyllotaxis: Phyllotaxis | None = None,
) -> LeafCloud:
    """Spray ``model`` (0 .. MODELS - 1) of ``family`` in metres: its leaf cards ``length``
    metres long (the family's own range without), its leaves set by ``phyllotaxis`` (the
    family's own without). The same arguments give the same spray."""
    if family not in FORMS:
        raise ValueError(f"leaves.family must be one of {FAMILIES}, got {family!r}")
    if not 0 <= model < MODELS:
        raise ValueError(f"model must be in [0, {MODELS}), got {model}")
    form = FORMS[family]
    rng = np.random.default_rng([seed, FAMILIES.index(family), model])
    return _BUILDERS[form.habit](
        rng, form, length or form.length, phyllotaxis or form.phyllotaxis, family
    )


@lru_cache(maxsize=4 * len(FAMILIES))
def cloud_models(
    family: Family = "broadleaf",
    length: tuple[float, float] | None = None,
    phyllotaxis: Phyllotaxis | None = None,
) -> tuple[LeafCloud, ...]:
    """The MODELS sprays of ``family`` (built once; do not modify their arrays)."""
    return tuple(leaf_cloud(family, m, LEAF_SEED, length, phyllotaxis) for m in range(MODELS))


def _saw(u: F64, teeth: float) -> F64:
    """A sawtooth 0..1 along the margin: ``teeth`` teeth over the blade."""
    return np.asarray((u * teeth) % 1.0)


def _outline(family: Family, u: F64) -> F64:
    """Half width of the blade (0..1 of the card's half width) at ``u`` from the blade's base
    (0) to its tip (1): the species' leaf outline with its margin."""
    u = np.clip(u, 0.0, 1.0)
    if family == "oak":
        # obovate, widest beyond the middle, with 4-5 rounded lobes a side cut by deep sinuses
        # and small ear-shaped lobes at the base
        env = np.sin(np.pi * np.clip(u, 0, 1) ** 0.8) ** 0.7 * (0.55 + 0.45 * u)
        lobes = 0.5 + 0.5 * np.abs(np.cos(np.pi * (4.5 * u + 0.2))) ** 0.6
        ear = 0.35 * np.exp(-(((u - 0.04) / 0.04) ** 2))
        return np.asarray(np.maximum(env * lobes * 1.05, ear))
    if family in ("birch", "poplar"):
        # triangular (deltoid): broad straight base, straight sides to a drawn-out tip
        widest = 0.2 if family == "birch" else 0.15
        rise = np.clip(u / widest, 0, 1) ** 0.45
        fall = np.clip((1 - u) / (1 - widest), 0, 1) ** (1.25 if family == "birch" else 1.1)
        teeth = 1 - (0.08 if family == "birch" else 0.05) * _saw(u, 11)
        return np.asarray(rise * fall * teeth)
    if family == "hazel":
        # round with a heart-shaped base and a short point, doubly toothed
        env = np.sqrt(np.clip(1 - ((u - 0.47) / 0.49) ** 2, 0, 1))
        point = np.clip((1 - u) / 0.2, 0, 1) ** 0.7  # the short drawn-out tip
        env = np.minimum(env, point) * (1 - 0.35 * np.exp(-((u / 0.07) ** 2)))
        return np.asarray(env * (1 - 0.06 * _saw(u, 12) - 0.03 * _saw(u, 36)))
    if family in ("willow", "strands", "almond"):
        # lanceolate: narrow, widest a third up, a long fine point, finely toothed
        widest = 0.35 if family == "almond" else 0.3
        rise = np.sin(0.5 * np.pi * np.clip(u / widest, 0, 1)) ** 0.8
        fall = np.sin(0.5 * np.pi * np.clip((1 - u) / (1 - widest), 0, 1)) ** 1.1
        return np.asarray(rise * fall * (1 - 0.07 * _saw(u, 24)))
    # broadleaf: ovate, widest at 40 %
    rise = np.sin(0.5 * np.pi * np.clip(u / 0.4, 0, 1)) ** 0.8
    fall = np.cos(0.5 * np.pi * np.clip((u - 0.4) / 0.6, 0, 1)) ** 0.8
    return np.asarray(np.where(u < 0.4, rise, fall) * 0.95)


def _segments(px: F64, py: F64, a: F64, b: F64, half: float) -> NDArray[np.bool_]:
    """Where the pixels ``(px, py)`` lie within ``half`` of any segment ``a[i] -> b[i]``."""
    hit = np.zeros(px.shape, bool)
    for (ax, ay), (bx, by) in zip(a, b, strict=True):
        dx, dy = bx - ax, by - ay
        f = np.clip(((px - ax) * dx + (py - ay) * dy) / (dx * dx + dy * dy), 0, 1)
        hit |= np.hypot(px - ax - f * dx, py - ay - f * dy) < half
    return hit


def _sprig_picture(x: F64, tt: F64) -> tuple[NDArray[np.bool_], F64]:
    """A spruce shoot on a card SPRIG_RATIO times as long as wide: the twig down the middle
    and needles all round it at their metric size. Those either side leave the twig at
    SPRIG_NEEDLE_ANGLE, forwards, every 1/64 of the card (4-6 mm on a 25-40 cm card: a real
    shoot's are 1-3 mm apart, past what 256 texels show) staggered left and right, each
    reaching 75-95 % of the half width (the card's half width is a needle's length); the
    needles on top, seen end-on, are shorter and steeper, between them. Together they cover
    about two thirds of the card, so mip levels keep the sprig above the 0.5 alpha cut."""
    ax = np.abs(x)
    twig = (ax < 0.07) & (tt > 0.005) & (tt < 0.995)
    slope = 0.5 / np.tan(np.radians(SPRIG_NEEDLE_ANGLE)) / SPRIG_RATIO  # t per unit of |x|
    # the last needles at the shoot's end are shorter: the bud's
    tip = np.clip((1.0 - tt) / 0.06, 0.35, 1.0)
    needle = np.zeros(x.shape, bool)
    value = np.zeros(x.shape)
    layers = ((slope, 0.5 * (x > 0), 0.75, 0.95), (2.4 * slope, 0.5 + 0.25 * (x > 0), 0.4, 0.65))
    for rise, offset, lo, hi in layers:
        phase = (tt - rise * ax) * 64.0 + offset
        k = np.round(phase)
        reach = (lo + (hi - lo) * _hash01(k + 97.0 * (x > 0))) * tip
        hit = (np.abs(phase - k) < 0.3) & (ax < reach) & (tt - rise * ax > 0.004) & ~needle
        value = np.where(hit, 0.7 + 0.28 * ax / np.maximum(reach, 1e-6), value)
        needle |= hit
    return twig | needle, np.where(twig, 0.5, value)


def _hash01(k: F64) -> F64:
    """A repeatable value in [0, 1) for each whole ``k`` (a needle's index)."""
    return np.asarray(np.modf(np.abs(np.sin(k * 12.9898) * 43758.5453))[0])


def _picture(family: Family, x: F64, tt: F64) -> tuple[NDArray[np.bool_], F64]:
    """Where the family's leaf is (x across its card in -1..1, tt along it in 0..1, the stalk
    at 0) and its neutral value there."""
    form = FORMS[family]
    stalk = (np.abs(x) < 0.06) & (tt > 0.005) & (tt < max(form.petiole, 0.08) + 0.02)
    if form.habit == "sprig":
        return _sprig_picture(x, tt)
    if form.habit == "tuft":
        # pairs of needles from a sheath at the base, fanned out
        # seven pairs, each pair's two needles splayed from one sheath up the shoot: a
        # brush of fine needles rather than a palm of leaflets
        fan = np.linspace(-0.8, 0.8, 7)
        ends = np.concatenate([fan - 0.08, fan + 0.08])
        a = np.zeros((len(ends), 2)) + np.array([0.0, 0.06])
        a[:, 0] = 0.08 * np.concatenate([fan, fan])
        a[:, 1] += 0.3 * (1 - np.abs(a[:, 0]) / 0.08)
        b = np.stack([ends, 0.97 - 0.15 * np.abs(ends)], axis=1)
        # the picture's x spans the card's width, its t the length: the thickness in x
        # units is about a needle's width (1.2 mm) over the card's half width
        needle = _segments(x, tt, a, b, 0.03)
        return needle | stalk, np.where(stalk, 0.5, 0.75 + 0.2 * tt)
    p = form.petiole
    u = (tt - p) / (1 - p)
    half = 0.94 * _outline(family, u) * np.clip(u / 0.03, 0, 1)  # a margin for mip levels
    blade = (np.abs(x) <= half) & (u > 0) & (u < 0.995)
    rib = np.abs(x) < 0.035
    veins_per = {"oak": 5.0, "hazel": 7.0, "birch": 7.0, "poplar": 6.0}.get(family, 12.0)
    vein_phase = (u - 0.5 * np.abs(x)) * veins_per
    veins = (np.abs(vein_phase - np.round(vein_phase)) < 0.06) & (u > 0.05)
    value = 0.7 + 0.25 * (1 - np.abs(x)) * np.clip(u * 1.5, 0, 1)
    value = np.where(rib | veins, value * 1.15, value)
    return blade | stalk, np.where(stalk & ~blade, 0.55, value)


def _rosette(family: Family, n: int) -> tuple[NDArray[np.bool_], F64]:
    """An ``n`` x ``n`` picture of the family's leaves in a cluster seen from above: ROSETTE
    leaves from the centre, each as long as the picture's half width."""
    c = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    px, py = np.meshgrid(c, c)
    shape = np.zeros((n, n), bool)
    value = np.zeros((n, n))
    for j in range(ROSETTE):
        # the youngest leaves in the middle of the cluster are smaller
        turn = 2 * np.pi * j / ROSETTE + 0.25 * np.sin(3.0 * j)
        scale = ROSETTE_LEAF - 0.12 * (j % 2)
        _draw_leaf(family, px, py, (np.sin(turn), np.cos(turn)), scale, j, shape, value)
    return shape, value


def _draw_leaf(
    family: Family, px: F64, py: F64, heading: tuple[float, float], size: float, j: int,
    shape: NDArray[np.bool_], value: F64,
) -> None:  # fmt: skip
    """Leaf ``j`` of a picture of several, into ``shape`` and ``value``: its stalk at the
    origin of the pixel coordinates ``(px, py)``, pointing along the unit ``heading``,
    ``size`` long; the leaves drawn first lie on top, every third a shade lighter."""
    # only the pixels within the leaf's reach of its stalk can show it (a picture of 25
    # leaves would otherwise shade every pixel 25 times)
    half_width = 0.5 * FORMS[family].aspect  # of the blade, over its length
    reach = size * math.hypot(1.0, half_width)
    rows = np.flatnonzero((np.abs(py) <= reach).any(axis=1))
    cols = np.flatnonzero((np.abs(px) <= reach).any(axis=0))
    if not len(rows) or not len(cols):
        return
    box = np.s_[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
    px, py, shape, value = px[box], py[box], shape[box], value[box]
    hx, hy = heading
    along = (px * hx + py * hy) / size
    across = (px * hy - py * hx) / size / half_width
    inside = (along > 0) & (along < 1) & (np.abs(across) < 1)
    sh, val = _picture(family, np.clip(across, -1, 1), np.clip(along, 0, 1))
    sh &= inside & ~shape
    value[sh] = (val * (0.9 + 0.1 * (j % 3) / 2))[sh]
    shape |= sh


def _spray(family: Family, n: int) -> tuple[NDArray[np.bool_], F64]:
    """An ``n`` x ``n`` picture of a side shoot seen from above (row: along, from its base;
    column: across), on a card SPRAY_LONG leaf lengths long and SPRAY_WIDE wide: its twig up
    the middle with four side twigs, alternately left and right, 46-58 degrees off it; a few
    leaves along the main twig and a fan round the end of every twig (_SPRAY_MAIN_LEAVES,
    _SPRAY_TWIGS), SPRAY_LEAVES in all. Branched, so one card fills about as much of a crown
    as a shoot with its side shoots."""
    c = (np.arange(n) + 0.5) / n
    tt, x = np.meshgrid(c, c * 2.0 - 1.0, indexing="ij")
    px, py = x * SPRAY_WIDE / 2, tt * SPRAY_LONG  # in leaf lengths
    leaves = list(_SPRAY_MAIN_LEAVES)
    bases, tips = [], []
    for (ax, ay), turn, length, fan in _SPRAY_TWIGS:
        d = np.radians(turn)
        tip = (ax + np.sin(d) * length, ay + np.cos(d) * length)
        bases.append((ax, ay))
        tips.append(tip)
        for j, off in enumerate(fan):
            heading = turn + off + 4.0 * np.sin(3.0 * j)
            leaves.append((tip[0], tip[1], heading, 0.94 - 0.05 * (j % 2)))
    # twigs a few mm across, and never under a texel (a coarse picture still shows them)
    twig = max(0.022, 0.6 * SPRAY_WIDE / n)
    top = tips[0][1]
    shape = (np.abs(px) < twig) & (py > 0.004 * SPRAY_LONG) & (py < top)
    shape |= _segments(px, py, np.array(bases), np.array(tips), 0.8 * twig)
    value = np.where(shape, 0.5, 0.0)
    for j, (bx, by, angle, size) in enumerate(leaves):
        heading = (np.sin(np.radians(angle)), np.cos(np.radians(angle)))
        _draw_leaf(family, px - bx, py - by, heading, size, j, shape, value)
    return shape, value


def leaf_texture(family: Family = "broadleaf", size: int = TEXTURE_SIZE) -> NDArray[np.uint8]:
    """``(size, size, 4)`` RGBA8 (row 0 is t = 0, the stem end), rgb sRGB-encoded: the family's
    pictures, alpha 255 on them and 0 around them. The rgb is neutral detail (midrib, veins,
    mottle, shading) that the renderer multiplies by each spray's colour. Made from code, so
    nothing of unclear origin ships and any worker can rebuild it.

    The left half (LEAF_ST) is one leaf, its stalk at t = 0; a stalk (or twig) runs down the
    middle of its base (STEM_S x STEM_T), which stem cards show. The upper right quarter
    (ROSETTE_ST) is a cluster of ROSETTE leaves seen from above (the leaves crowded at a
    shoot's end, one card for several); the lower right (SPRAY_ST) a side shoot of
    SPRAY_LEAVES leaves seen from above. Broad leaves: the species' outline (lobed oak,
    triangular birch and poplar on long stalks, round toothed hazel, narrow willow and
    almond) with midrib and side veins; ``pine``: a fan of needle pairs from a sheath;
    ``spruce``/``needles``: a sprig, a twig along the middle with short needles either side
    pointing forwards."""
    if family not in FORMS:
        raise ValueError(f"leaves.family must be one of {FAMILIES}, got {family!r}")
    half = size // 2
    t = (np.arange(size) + 0.5) / size
    s = (np.arange(half) + 0.5) / half
    x, tt = np.meshgrid((s - 0.5) * 2.0, t)  # x across (column) -1..1, t along (row)
    shape = np.zeros((size, size), bool)
    value = np.zeros((size, size))
    shape[:, :half], value[:, :half] = _picture(family, x, tt)
    shape[half:, half:], value[half:, half:] = _rosette(family, size - half)
    shape[:half, half:], value[:half, half:] = _spray(family, half)
    rng = np.random.default_rng([size, FAMILIES.index(family)])
    value = value * (1.0 + 0.06 * rng.standard_normal((size, size)))
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
    return srgb_to_linear(srgb / 255.0)


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
    # a tree's colour converted once, then gathered (the same values as per cloud)
    hsv = _rgb_to_hsv(base)[tree] if k else np.zeros((0, 3))
    hsv[:, 0] += HUE_JITTER * rng.standard_normal(k)
    hsv[:, 1] = np.clip(hsv[:, 1] * np.exp(SAT_JITTER * rng.standard_normal(k)), 0, 1)
    hsv[:, 2] = np.clip(hsv[:, 2] * np.exp(VALUE_JITTER * rng.standard_normal(k)), 0, 1)
    return _hsv_to_rgb(hsv).astype(np.float32)


# -- anchors -----------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FoliageAnchors:
    """instance : (k,) int32 piece instance each spray grows from
    bone : (k,) int32 the palette entry it follows (the instance's bone offset + HUB)
    rest : (k, 3) float64 its point in the piece's model space
    size : (k,) float64 the spray's scale (its model is in metres: a jitter about 1)
    model : (k,) int32 which of the family's MODELS sprays it shows
    yaw : (k,) float64 radians about the vertical (+y), a multiple of 2 pi / YAW_STEPS
    color : (k, 3) float32 linear RGB tint
    family : the leaf family of every spray; length, phyllotaxis: the grammar's overrides of
    the family's leaf length and arrangement (None: the family's own), which pick the
    models (:meth:`models`)"""

    instance: NDArray[np.int32]
    bone: NDArray[np.int32]
    rest: F64
    size: F64
    model: NDArray[np.int32]
    yaw: F64
    color: NDArray[np.float32]
    family: Family = "broadleaf"
    length: tuple[float, float] | None = None
    phyllotaxis: Phyllotaxis | None = None

    def __len__(self) -> int:
        return len(self.instance)

    def models(self) -> tuple[LeafCloud, ...]:
        """The spray models the anchors' ``model`` indexes."""
        return cloud_models(self.family, self.length, self.phyllotaxis)

    def positions(self, palette: F64, row_vectors: bool = False) -> F64:
        """``(k, 3)`` spray origins: each anchor's palette matrix applied to its rest point
        (``palette`` in column-vector form, or USD's row-vector form with ``row_vectors``)."""
        return anchor_positions(palette, self.bone, self.rest, row_vectors)

    def select(self, pick: NDArray[np.intp]) -> FoliageAnchors:
        """The anchors ``pick`` (indices), same family and models."""
        return FoliageAnchors(
            instance=self.instance[pick], bone=self.bone[pick], rest=self.rest[pick],
            size=self.size[pick], model=self.model[pick], yaw=self.yaw[pick],
            color=self.color[pick], family=self.family, length=self.length,
            phyllotaxis=self.phyllotaxis,
        )  # fmt: skip


def anchor_positions(
    palette: F64, bone: NDArray[np.int32], rest: F64, row_vectors: bool = False
) -> F64:
    """``palette[bone]`` applied to the points ``rest`` (see FoliageAnchors.positions), a
    block at a time: a (k, 4, 4) gather was 200 MB for 1,000 oaks' sprays."""
    out = np.empty((len(bone), 3))
    for a in range(0, len(bone), BLOCK):
        m, r = palette[bone[a : a + BLOCK]], rest[a : a + BLOCK]
        if row_vectors:
            out[a : a + BLOCK] = np.einsum("ni,nij->nj", r, m[:, :3, :3]) + m[:, 3, :3]
        else:
            out[a : a + BLOCK] = np.einsum("nij,nj->ni", m[:, :3, :3], r) + m[:, :3, 3]
    return out


def yaw_quaternions(yaw: F64) -> F64:
    """``(k, 4)`` unit quaternions, xyzw (numpy's layout of USD's quaternion arrays), of turns
    by ``yaw`` radians about +y."""
    half = 0.5 * np.asarray(yaw, np.float64)
    z = np.zeros_like(half)
    return np.stack([z, np.sin(half), z, np.cos(half)], axis=-1)


def snap_yaw(yaw: F64) -> F64:
    """``yaw`` (radians) rounded to the nearest of the YAW_STEPS headings, in [0, 2 pi)."""
    step = np.round(np.asarray(yaw, np.float64) / (2 * np.pi / YAW_STEPS)).astype(np.int64)
    return (np.mod(step, YAW_STEPS) * (2 * np.pi / YAW_STEPS)).astype(np.float64)


def _outer(pos: F64, tree: NDArray[np.int32], bands: int = 10, groups: Groups | None = None) -> F64:
    """``(k,)`` how far out in its tree's crown each point lies: 0 on the crown's axis at mid
    height, 1 on its outer surface: across, the distance from the axis over the crown's
    radius at that height (95th percentile of a tenth of the crown's height, so a cone's
    narrow top is as much outside as its broad base); up and down, over the half height.

    A tree's points are a slice of one grouping (``groups``, :func:`group_by`; a mask per
    tree made 1,000 oaks' anchors grow with the square of the trees) and its percentiles are
    read from sorted slices (:func:`sorted_quantile`, numpy's own interpolation): the values
    of ``np.percentile`` on each tree's points, bit for bit, so the same sprays are kept."""
    out = np.zeros(len(pos))
    order, bounds = groups if groups is not None else group_by(tree)
    for a, z in itertools.pairwise(bounds):
        sel = order[a:z]
        p = pos[sel]
        y = np.sort(p[:, 1])
        lo, hi = sorted_quantile(y, 0.02), sorted_quantile(y, 0.98)
        h = max(0.5 * (hi - lo), 1e-6)
        across = np.hypot(p[:, 0] - p[:, 0].mean(), p[:, 2] - p[:, 2].mean())
        band = np.clip(((p[:, 1] - lo) / (2 * h) * bands).astype(np.int64), 0, bands - 1)
        by_band = np.lexsort((across, band))
        sorted_across, sorted_band = across[by_band], band[by_band]
        ends = np.searchsorted(sorted_band, np.arange(bands + 1))
        radius = np.ones(bands)
        for b in np.flatnonzero(ends[1:] > ends[:-1]):
            radius[b] = max(sorted_quantile(sorted_across[ends[b] : ends[b + 1]], 0.95), 1e-6)
        out[sel] = np.maximum(across / radius[band], np.abs(p[:, 1] - lo - h) / h)
    return out


Groups = tuple[NDArray[np.intp], NDArray[np.intp]]


def group_by(key: NDArray[np.integer]) -> Groups:
    """``(order, bounds)``: the indices of ``key`` (small non-negative ints, e.g. trees) by
    key, in index order within a key (a stable sort; a radix sort when the keys fit 16
    bits), group ``g`` being ``order[bounds[g]:bounds[g + 1]]`` (keys with no index left
    out)."""
    key = np.asarray(key)
    if not len(key):
        return np.zeros(0, np.intp), np.zeros(1, np.intp)
    small = int(key.max()) < 2**15 and int(key.min()) >= 0
    order = np.argsort(key.astype(np.int16) if small else key, kind="stable")
    k = key[order]
    bounds = np.flatnonzero(np.r_[True, k[1:] != k[:-1], True])
    return order, bounds


def sorted_quantile(values: F64, q: float) -> float:
    """The ``q`` quantile of the sorted ``values`` as ``np.percentile(values, 100 * q)``
    gives it (the default 'linear' method: ``(n - 1) * q`` into the sorted values, numpy's
    lerp, which takes the upper end's form from half way on), without its sort and
    overhead: a tree's anchors ask for eleven."""
    n = len(values)
    virtual = (n - 1) * q
    if virtual >= n - 1:
        return float(values[-1])
    prev = math.floor(virtual)
    gamma = virtual - prev
    a, b = float(values[prev]), float(values[prev + 1])
    diff = b - a
    return b - diff * (1 - gamma) if gamma >= 0.5 else a + diff * gamma


def _fit_low(
    model: NDArray[np.int32],
    size: F64,
    keep: NDArray[np.bool_],
    low: NDArray[np.bool_],
    room: F64,
    drop: F64,
    min_size: float,
) -> None:
    """In place, each ``low`` spray (reaching lower than its ``room``): the longest model whose
    ``drop`` fits at its size, else the shortest shrunk to fit (no smaller than
    ``min_size``), else not kept. Every low spray at once, not a Python loop over them (a
    willow's hanging curtains have a few hundred in 20 trees)."""
    order = np.argsort(drop)
    low_i = np.flatnonzero(low)
    fits = size[low_i, None] * drop[order][None, :] <= room[low_i, None]
    some = fits.any(axis=1)
    last = len(order) - 1 - np.argmax(fits[:, ::-1], axis=1)  # the last model that fits
    with np.errstate(divide="ignore", invalid="ignore"):  # a model that never drops fits
        shrunk = room[low_i] / drop[order[0]]
    smaller = ~some & (room[low_i] > 0) & (shrunk >= min_size)
    model[low_i[some]] = order[last[some]]
    model[low_i[smaller]] = order[0]
    size[low_i[smaller]] = shrunk[smaller]
    keep[low_i[~some & ~smaller]] = False


def _cap_triangles(
    keep: NDArray[np.bool_],
    score: F64,
    tree: NDArray[np.int32],
    tris: NDArray[np.int64],
    cap: int,
    groups: Groups | None = None,
) -> None:
    """In place: per tree, its kept sprays by falling ``score`` (ties in index order) until
    their triangles pass ``cap``; the rest are not kept. A tree's sprays are a slice of one
    grouping (``groups``, :func:`group_by`): a mask per tree grew with the square of the
    trees."""
    order, bounds = groups if groups is not None else group_by(tree)
    for a, z in itertools.pairwise(bounds):
        sel = order[a:z]
        sel = sel[keep[sel]]
        sel = sel[np.argsort(-score[sel], kind="stable")]
        keep[sel[np.cumsum(tris[sel]) > cap]] = False


def spray_anchors(
    instance: NDArray[np.int32],
    piece: NDArray[np.int32],
    bone_offset: NDArray[np.int32],
    joint_rest: list[F64],
    hub_frame: F64,
    tree: NDArray[np.int32],
    ground: F64,
    leaves: Leaves,
    rng: np.random.Generator,
    season: Season = "summer",
) -> FoliageAnchors:
    """Leaf sprays on the foliage-bearing ``instance``\\ s (k of them).

    piece : (n,) the piece of every instance; joint_rest : per piece its joints' rest frames
    (model space); hub_frame : (k, 4, 4) each bearer's hub bone as the tree stands (palette,
    column vectors); tree : (k,) its tree (one base colour per tree); ground : (k,) the height
    of its tree's foot.

    Each bearer carries ``leaves.sprays`` sprays on its axis between the hub and a terminal,
    denser towards the terminal, turned out to the sides of the branch (the last one or two
    ahead), every spray a random model, scale and colour. Then, per tree: none below
    ``leaves.min_height`` above the foot; none reaching lower than 0.3-0.8 m above the ground
    (a shorter model or a smaller scale first, so willow curtains end above the grass); none
    inside ``leaves.shell`` of the crown; and when a tree's leaves would pass
    ``leaves.max_triangles``, the innermost sprays go. The same rng gives the same sprays."""
    if season not in SEASONS:
        raise ValueError(f"season must be one of {SEASONS}, got {season!r}")
    idx = np.asarray(instance, np.int32)
    k = len(idx)
    tree = np.asarray(tree, np.int32)
    ground = np.asarray(ground, np.float64)
    for name, arr in (("tree", tree), ("ground", ground)):
        if arr.shape != (k,):
            raise ValueError(f"{name} must have shape ({k},), got {arr.shape}")
    form_len = leaves.length
    models = cloud_models(leaves.family, form_len, leaves.phyllotaxis)
    palette = leaves.autumn_colors if season == "autumn" and leaves.autumn_colors else leaves.colors
    lo, hi = leaves.sprays
    count = rng.integers(lo, hi + 1, size=k)
    bearer = np.repeat(np.arange(k), count)
    m = len(bearer)
    bp = piece[idx][bearer]
    hub = np.stack([joint_rest[p][HUB, :3, 3] for p in range(len(joint_rest))])
    n_tips = np.array([len(j) - TIP0 for j in joint_rest])
    tips = np.zeros((len(joint_rest), max(int(n_tips.max()), 1), 3))
    for p, j in enumerate(joint_rest):
        tips[p, : n_tips[p]] = j[TIP0:, :3, 3]
    which = (rng.random(m) * np.maximum(n_tips[bp], 1)).astype(np.int64)
    # hub to terminal per piece and terminal (a piece without one: straight up)
    tip = np.where((n_tips > 0)[:, None, None], tips, (hub + UP)[:, None])
    span_of = tip - hub[:, None]
    # density grows along the piece towards its terminal (pdf 2 f)
    f = np.sqrt(rng.random(m))
    rest, world, axis = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
    # a block of sprays at a time: a (m, 4, 4) gather of the hub frames was the anchors'
    # peak memory (400 MB for 1,000 oaks); the same products, row for row
    for a in range(0, m, BLOCK):
        z = min(m, a + BLOCK)
        span = span_of[bp[a:z], which[a:z]]
        rest[a:z] = hub[bp[a:z]] + f[a:z, None] * span
        frame = hub_frame[bearer[a:z]]
        world[a:z] = np.einsum("nij,nj->ni", frame[:, :3, :3], rest[a:z]) + frame[:, :3, 3]
        axis[a:z] = np.einsum("nij,nj->ni", frame[:, :3, :3], span)
    ax, ay, az = axis.T
    # np.linalg.norm(axis, axis=1) in its own order of sums, without its strided reduction
    flat = np.hypot(ax, az) < 0.2 * np.sqrt(ax * ax + ay * ay + az * az)
    heading = np.where(flat, rng.uniform(0, 2 * np.pi, m), np.arctan2(ax, az))
    ahead = (f > 0.85) & (rng.random(m) < 0.5)
    side = np.where(rng.random(m) < 0.5, -1.0, 1.0) * np.radians(rng.uniform(35, 100, m))
    yaw = snap_yaw(heading + np.where(ahead, np.radians(rng.normal(0, 15, m)), side))
    model = rng.integers(MODELS, size=m).astype(np.int32)
    size = rng.uniform(*leaves.scale, m)
    keep = world[:, 1] - ground[bearer] >= leaves.min_height
    # nothing below the ground: a spray that would reach lower than its clearance takes the
    # longest model that fits, else the shortest at a smaller scale, else none
    drop = np.array([-min(c.positions[:, 1].min(), 0.0) for c in models])
    clearance = ground[bearer] + rng.uniform(0.3, 0.8, m)
    room = world[:, 1] - clearance
    low = keep & (size * drop[model] > room)
    _fit_low(model, size, keep, low, room, drop, 0.6 * leaves.scale[0])
    groups = group_by(tree[bearer])  # each tree's sprays, for the per-tree passes below
    out = _outer(world, tree[bearer], groups=groups)
    keep &= out >= leaves.shell
    if leaves.max_triangles is not None:
        tris = np.array([2 * c.n_cards for c in models])[model]
        score = out + 0.15 * rng.random(m)  # outer sprays first, a little shuffled
        _cap_triangles(keep, score, tree[bearer], tris, leaves.max_triangles, groups)
    pick = np.flatnonzero(keep)
    b = bearer[pick]
    return FoliageAnchors(
        instance=idx[b],
        bone=(bone_offset[idx[b]] + HUB).astype(np.int32),
        rest=rest[pick],
        size=size[pick],
        model=model[pick],
        yaw=yaw[pick],
        color=cloud_colors(list(palette), tree[b], rng),
        family=leaves.family,
        length=form_len,
        phyllotaxis=leaves.phyllotaxis,
    )
