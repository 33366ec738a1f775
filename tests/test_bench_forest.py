"""``forest bench forest`` and the write floor: they run end to end and refuse bad input (no
timing is asserted: figures are the benchmark's business)."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from bench.floor import page_cache_write_seconds, timed_saves
from bench.forest import run_forest_bench
from cli import main
from forest.usd import files


def test_floor_writes_and_removes_its_file(tmp_path: Path) -> None:
    seconds = page_cache_write_seconds(tmp_path, 3 << 20, repeat=2)
    assert seconds > 0
    assert list(tmp_path.iterdir()) == []


def test_timed_saves_restores_the_writer() -> None:
    real = files.finish
    with timed_saves() as saves:
        assert files.finish is not real
    assert files.finish is real and saves == []


def test_bench_forest_runs_tiles_in_worker_processes(tmp_path: Path) -> None:
    lines: list[str] = []
    out = run_forest_bench(
        12, 12.0, "alternating", frames=2, workers=(1,), folder=tmp_path, echo=lines.append
    )
    pieces, nbytes, floor_s = out["pieces"], out["bytes"], out["floor_s"]
    assert out["trees"] == 12 and isinstance(pieces, float) and pieces > 0
    assert isinstance(nbytes, float) and nbytes > 0
    assert isinstance(floor_s, float) and floor_s > 0
    per_bone = out["bytes_per_bone_frame"]
    assert isinstance(per_bone, float) and 0 < per_bone <= 16  # float32 quaternions of some bones
    assert any("bytes per bone per frame" in line for line in lines)
    assert list(tmp_path.iterdir()) == []  # the tiles are removed


def test_bench_forest_refuses_bad_worker_counts() -> None:
    runner = CliRunner()
    for workers in ("x", "0", "1,-2"):
        result = runner.invoke(main, ["bench", "forest", "--trees", "10", "--workers", workers])
        assert result.exit_code == 2, result.output
        assert "workers" in result.output
