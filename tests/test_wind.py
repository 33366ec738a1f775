"""Wind: clips loop, motion layered by depth, trees out of phase, gusts travel downwind."""

from __future__ import annotations

import numpy as np
import pytest

from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.growth.wind import Wind


def forest(name: str, trees: int = 3, frames: int = 48, fps: float = 24.0) -> Forest:
    return generate_forest(load_preset(name), 5, ForestOptions(trees=trees, frames=frames, fps=fps))


@pytest.mark.parametrize("name", ["alternating", "oak"])
@pytest.mark.parametrize(("frames", "fps"), [(48, 24.0), (37, 30.0)])
def test_clip_loops(name: str, frames: int, fps: float) -> None:
    f = forest(name, 2, frames, fps)
    assert f.options.wind.loop_s == pytest.approx(frames / fps)
    p0, p_end = f.palette(0.0), f.palette(frames / fps)
    np.testing.assert_allclose(p_end, p0, rtol=0, atol=1e-9)
    # and it does move within the clip
    assert np.abs(f.palette(0.5 * frames / fps) - p0).max() > 1e-3


def test_frequencies_snap_to_distinct_multiples() -> None:
    w = Wind(loop_s=2.0)
    fs = np.array(w.frequencies())
    k = fs * 2.0
    np.testing.assert_allclose(k, np.round(k), atol=1e-12)
    assert (np.diff(k) >= 1).all() and k[0] >= 1
    assert Wind().frequencies() == (0.4, 0.7, 0.7 * 2.3, 2.6)  # no loop: as asked
    # a clip far shorter than the sway's period keeps them (no 8 Hz sway for 3 frames): it
    # closes its loop by blending instead (test_every_clip_loops)
    assert Wind(loop_s=3 / 24).frequencies() == Wind().frequencies()
    assert not Wind(loop_s=3 / 24).snaps and Wind(loop_s=2.0).snaps


@pytest.mark.parametrize(("frames", "fps"), [(2, 24.0), (5, 24.0), (12, 24.0), (15, 24.0),
                                             (24, 24.0), (37, 30.0)])  # fmt: skip
def test_every_clip_loops(frames: int, fps: float) -> None:
    """The joints' pose one frame after the last (at frames / fps, where a looping player
    wraps) is frame 0's, whether the clip is long enough for the frequencies to snap or not,
    and the step from the last frame back to the first is a step like the clip's others."""
    from forest.usd.skinned import joint_frames

    f = forest("alternating", 1, frames, fps)
    joints = joint_frames(f)
    times = [i / fps for i in range(frames + 1)]
    pose = np.stack([joints.locals(f, t) for t in times])
    np.testing.assert_allclose(pose[-1], pose[0], rtol=0, atol=1e-9)
    steps = np.abs(np.diff(pose, axis=0)).max(axis=(1, 2, 3))
    assert steps[:-1].max() > 1e-4  # it moves
    assert steps[-1] <= 1.5 * steps[:-1].max(), steps


def _hub_positions(f: Forest, times: np.ndarray) -> np.ndarray:
    """``(frames, n, 3)`` each instance's hub position in its tree's frame."""
    hubs = f.bones.offset + 1
    inv = np.linalg.inv(f.tree_transforms)[f.graph.tree]
    out = []
    for t in times:
        pal = f.palette(float(t))
        # the hub joint's rest origin mapped by the hub's palette entry
        rest = f.bones.rest[f.graph.piece, 1, :, 3]
        world = np.einsum("nij,nj->ni", pal[hubs], rest)
        out.append(np.einsum("nij,nj->ni", inv, world)[:, :3])
    return np.stack(out)


def test_tips_move_more_than_the_trunk() -> None:
    f = forest("alternating", 1)
    times = np.linspace(0, 2, 17)
    pos = _hub_positions(f, times)
    motion = np.linalg.norm(pos - pos.mean(axis=0), axis=2).max(axis=0)
    depth = f.graph.depth
    trunk = motion[depth <= 1].max()
    tips = motion[depth >= depth.max() - 1].mean()
    assert tips > 3 * trunk, (tips, trunk)


def test_neighbouring_trees_are_out_of_phase() -> None:
    f = forest("alternating", 4)
    poser = f.poser()
    roots = np.nonzero(f.graph.parent < 0)[0]
    wind = f.options.wind
    times = np.linspace(0, 2, 49)[:-1]
    vecs = [poser._wind(roots, wind, float(t)) for t in times]
    vec = np.stack([v for v in vecs if v is not None])  # (T, 3, trees)
    # the sway about the across axis, per tree, in the world frame
    world = np.einsum("tij,Tjt->Tit", f.transforms[roots, :3, :3], vec)
    sway = world[:, 2, :]  # direction 0: across axis is -z
    c = np.corrcoef(sway.T)
    off = c[~np.eye(len(roots), dtype=bool)]
    assert off.min() < 0.9, c


def test_gust_arrives_later_downwind() -> None:
    f = forest("alternating", 6, frames=0)
    wind = Wind(direction_deg=0.0)  # towards +x
    poser = f.poser()
    roots = np.nonzero(f.graph.parent < 0)[0]
    x = f.tree_transforms[:, 0, 3]
    times = np.linspace(0, 1 / wind.gust_hz, 2001)
    env = np.stack([poser.gust_envelope(roots, wind, float(t)) for t in times])
    peak = times[env.argmax(axis=0)]
    # one period of the envelope: unwrap the peak times relative to the most upwind tree
    order = np.argsort(x)
    rel = (peak[order] - peak[order[0]]) % (1 / wind.gust_hz)
    expect = (x[order] - x[order[0]]) / wind.gust_speed % (1 / wind.gust_hz)
    np.testing.assert_allclose(rel, expect, atol=2 / 2000 / wind.gust_hz + 1e-9)
    assert np.ptp(x) > 1.0  # the trees do spread along the wind


def test_wind_leans_downwind_and_still_pose_is_windless() -> None:
    f = forest("alternating", 1)
    assert not np.allclose(f.palette(0.0), f.palette(None))
