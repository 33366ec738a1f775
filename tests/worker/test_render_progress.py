"""Render progress: ``forest render`` says how many frames are drawn (plain lines where stderr
is not a terminal, nothing with ``--quiet``), and a render job reports each frame."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.scene import write_scene

ROOT = Path(__file__).parents[2]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    forest = generate_forest(load_preset("alternating"), 2, ForestOptions(trees=1, frames=3))
    return write_scene(forest, tmp_path_factory.mktemp("progress") / "tiny.usdc")


def forest(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    return subprocess.run(
        [sys.executable, "-m", "cli", *args], cwd=cwd, env=env, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip


def test_render_shows_frames_unless_quiet(gl_session: Any, tiny: Path, tmp_path: Path) -> None:
    args = ["render", str(tiny), "--frames", "3", "--width", "32", "--height", "24"]
    out = forest(*args, "-o", "a.png", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    lines = out.stderr.splitlines()
    starts = [
        "warm-up 0/1 (0%)", "warm-up 1/1 (100%) in ",
        "frames 0/3 (0%)", "frames 1/3 (33%), ", "frames 2/3 (66%), ", "frames 3/3 (100%) in ",
        "write 0/1 (0%)", "write 1/1 (100%) in ",
    ]  # fmt: skip
    assert len(lines) == len(starts), out.stderr
    for line, start in zip(lines, starts, strict=True):
        assert line.startswith(f"render: {start}"), out.stderr
    assert out.stdout.startswith("wrote a.png: 32x24")
    quiet = forest(*args, "-o", "b.png", "--quiet", cwd=tmp_path)
    assert quiet.returncode == 0 and quiet.stderr == ""
    assert quiet.stdout.startswith("wrote b.png: 32x24")


def test_render_job_reports_every_frame(gl_session: Any, tiny: Path, tmp_path: Path) -> None:
    """The job's progress (GET /v1/jobs/{id}: progress and stage) moves with each frame."""
    from farm.artifacts import ArtifactStore
    from schemas.jobs import RenderRequest
    from worker.jobs.context import JobContext
    from worker.jobs.render import run_render

    store = ArtifactStore(tmp_path / "artifacts")
    store.publish("a" * 32, tiny, "scene.usdc")
    req = RenderRequest(forest_job="a" * 32, width=32, height=24, tess_max=1, frames=3)
    params = req.model_dump(mode="json") | {"scene": "scene.usdc"}
    reports: list[tuple[str, float]] = []
    ctx = JobContext("b" * 32, params, store.scratch("b" * 32), store)
    ctx.on_report = lambda stage, fraction: reports.append((stage, fraction))
    run_render(ctx)
    frames = [(s, f) for s, f in reports if s.endswith(" frames")]
    assert [s for s, _ in frames] == [f"render {k}/3 frames" for k in range(4)]
    fractions = [f for _, f in frames]
    assert fractions == sorted(fractions) and fractions[0] == pytest.approx(0.3)
    assert fractions[-1] == pytest.approx(0.95)
