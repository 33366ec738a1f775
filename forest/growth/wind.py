"""Wind (paper 4.3): a few layered sines per piece bending it about horizontal axes, and their
sampling: the time-independent field per instance (:func:`wind_field`) and the rotation
vectors at a time (:func:`wind_vectors`). :class:`forest.growth.poser.Poser` turns these into
bone rotations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from forest.geometry.transforms import F64
from forest.growth.expand import PieceGraph

# a clip's frequencies snap to its loop when it lasts at least this many periods of the slow
# sway (the sway then runs at most four times as fast as asked); a shorter clip keeps the
# frequencies as asked and closes its loop by a linear blend (see wind_vectors)
LOOP_MIN_CYCLES = 0.25


@dataclass(frozen=True)
class Wind:
    """Wind as a few layered sines per piece, all bending about axes in the horizontal plane.

    Each piece's rotation vector (radians, in its root frame) is ``amp * (lean + sway + gust)``
    about the axis across ``direction`` plus ``amp * side`` about the axis along it, with

    * ``sway``: a slow sine at ``frequency_hz`` with the tree's own phase (neighbours differ);
    * ``gust``: an envelope at ``gust_hz`` that travels downwind at ``gust_speed`` m/s (its
      arrival time grows with distance along the wind) times a faster wobble at about
      ``2.3 * gust_hz`` with a per-piece phase (branch-level motion);
    * ``flutter``: a small fast term at ``flutter_hz`` on the deepest pieces (leaf clouds ride
      their hub bones, so they flutter with them).

    ``amp`` grows linearly with depth from ``strength * base`` at the trunk to ``strength`` at
    the deepest pieces, and with thinness: times ``(trunk radius / radius) ** radius_power``,
    at most ``4``. With ``loop_s`` (a clip of that many seconds; ForestOptions sets it to
    ``frames / fps``) the clip loops, the pose at ``loop_s`` equal to the pose at 0: a clip
    of at least ``LOOP_MIN_CYCLES`` sway periods rounds every frequency to a distinct
    non-zero multiple of ``1 / loop_s``; a shorter one keeps them and blends its motion
    linearly back to the start (:func:`wind_vectors`).
    """

    strength_deg: float = 4.0
    frequency_hz: float = 0.4
    direction_deg: float = 0.0
    base: float = 0.15
    sway: float = 0.5
    gust_hz: float = 0.7
    gust: float = 0.8
    gust_speed: float = 6.0
    flutter_hz: float = 2.6
    flutter: float = 0.15
    radius_power: float = 0.25
    loop_s: float = 0.0

    @property
    def snaps(self) -> bool:
        """Whether the clip is long enough for its frequencies to snap to the loop."""
        return self.loop_s * self.frequency_hz >= LOOP_MIN_CYCLES

    def frequencies(self) -> tuple[float, float, float, float]:
        """``(sway, gust envelope, gust wobble, flutter)`` in Hz, snapped to the loop."""
        want = (self.frequency_hz, self.gust_hz, 2.3 * self.gust_hz, self.flutter_hz)
        if not self.snaps:
            # too short a clip to loop: its sway would have to run many times too fast
            return want
        out: list[float] = []
        k_prev = 0
        for f in want:
            # distinct multiples: two terms on one frequency would beat in lockstep
            k = max(k_prev + 1, round(f * self.loop_s))
            out.append(k / self.loop_s)
            k_prev = k
        return out[0], out[1], out[2], out[3]


@dataclass(frozen=True, eq=False)
class WindField:
    """A wind's time-independent part per instance: amplitude ``amp`` ``(n,)`` radians, the
    axes across and along the wind in each instance's root frame ``(3, n)``, the flutter weight
    ``(n,)``, the gust's delay ``(n,)`` seconds and a per-piece phase ``(n,)`` radians."""

    amp: F64
    across: F64
    along: F64
    flutter: F64
    delay: F64
    piece_phase: F64


def wind_field(wind: Wind, graph: PieceGraph, transforms: F64, tree_transforms: F64) -> WindField:
    """The time-independent part of ``wind`` on the instances of ``graph`` (their
    topological ``transforms`` ``(n, 4, 4)``, their trees' ``tree_transforms`` ``(t, 4, 4)``),
    computed once for all of its frames."""
    g = graph
    # depth of each tree's deepest piece
    tree_depth = np.zeros(int(g.tree.max()) + 1, np.int32)
    np.maximum.at(tree_depth, g.tree, g.depth)
    d = np.deg2rad(wind.direction_deg)
    across = np.array([np.sin(d), 0.0, -np.cos(d)])  # up x direction
    along = np.array([np.cos(d), 0.0, np.sin(d)])
    rot_t = transforms[:, :3, :3]
    deepest = np.maximum(np.take(tree_depth, g.tree), 1)
    rel = g.depth / deepest
    trunk_r = np.zeros(len(tree_depth))
    np.maximum.at(trunk_r, g.tree, g.scale)
    thin = np.clip(
        (np.take(trunk_r, g.tree) / np.maximum(g.scale, 1e-6)) ** wind.radius_power,
        1.0,
        4.0,
    )
    amp = np.deg2rad(wind.strength_deg) * (wind.base + (1 - wind.base) * rel) * thin
    # only the last quarter of each tree's depth flutters, growing to the tips
    flutter = wind.flutter * np.clip((rel - 0.75) / 0.25, 0.0, 1.0) ** 2
    # downwind distance of each tree's base: the gust's delay there
    dist = tree_transforms[:, :3, 3] @ along
    delay = np.take(dist, g.tree) / max(wind.gust_speed, 1e-6)
    # a per-piece phase from the instance index (golden-ratio hashing): branch motion
    # out of step with its neighbours, reproducible without a random stream
    piece_phase: F64 = np.mod(np.arange(len(g)) * 0.6180339887498949, 1.0) * (2 * np.pi)
    return WindField(
        amp=amp,
        # contiguous: every frame takes columns of these (einsum returns them
        # Fortran-ordered, and a take along axis 1 of that copies each time)
        across=np.ascontiguousarray(np.einsum("nji,j->in", rot_t, across)),  # R^T a
        along=np.ascontiguousarray(np.einsum("nji,j->in", rot_t, along)),
        flutter=flutter,
        delay=delay,
        piece_phase=piece_phase,
    )


def gust_envelope(field: WindField, wind: Wind, idx: NDArray[np.intp], time: float) -> F64:
    """``(m,)`` the gust's strength in [0, 1] at the instances ``idx`` at ``time``: a
    peaked (squared) sine travelling downwind at ``wind.gust_speed``."""
    f_env = wind.frequencies()[1]
    delay = field.delay[idx]
    return (0.5 + 0.5 * np.sin(2 * np.pi * f_env * (time - delay))) ** 2


def wind_vectors(
    field: WindField, wind: Wind, idx: NDArray[np.intp], phase: F64, time: float
) -> F64:
    """Per instance of ``idx``: the wind's rotation vector ``(3, m)`` (radians about its
    direction) in the instance's root frame at ``time``; ``phase`` ``(n,)`` is each
    instance's wind phase (its pose's). A clip too short for its frequencies to snap
    (``wind.loop_s`` > 0, not :attr:`Wind.snaps`) repeats every ``loop_s`` and gives back,
    linearly over the clip, the difference between its end and its start: its last frame
    leads back to its first in a step like any other."""
    if wind.loop_s <= 0 or wind.snaps:
        return _wind_vectors(field, wind, idx, phase, time)
    t = time % wind.loop_s
    start = _wind_vectors(field, wind, idx, phase, 0.0)
    end = _wind_vectors(field, wind, idx, phase, wind.loop_s)
    return _wind_vectors(field, wind, idx, phase, t) - (t / wind.loop_s) * (end - start)


def _wind_vectors(
    field: WindField, wind: Wind, idx: NDArray[np.intp], phase: F64, time: float
) -> F64:
    """:func:`wind_vectors` of the sines alone (no loop closed)."""
    f_sway, _, f_wob, f_flut = wind.frequencies()
    tau = 2 * np.pi * time
    tree_phase = phase[idx]
    own = field.piece_phase[idx]
    env = gust_envelope(field, wind, idx, time)
    bend = (
        0.35  # the mean lean downwind
        + wind.sway * np.sin(tau * f_sway + tree_phase)
        + wind.gust * env * (1.0 + 0.35 * np.sin(tau * f_wob + own))
    )
    flut = field.flutter[idx]
    side = 0.25 * env * np.sin(tau * f_wob + 1.3 * own) + flut * np.sin(tau * f_flut + 2.0 * own)
    bend = bend + flut * np.sin(tau * f_flut + own)
    amp = field.amp[idx]
    return (amp * bend) * np.take(field.across, idx, axis=1) + (amp * side) * np.take(
        field.along, idx, axis=1
    )
