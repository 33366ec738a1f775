"""``forest bench render`` runs end to end on a tiny forest (its timings are never asserted:
budgets belong to the benchmark, not to tests)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from bench.render import run_render_bench
from cli import main
from cli.app import parse_counts


@pytest.mark.slow  # 20 bench rows; 10 s on llvmpipe
def test_bench_compares_instanced_with_a_draw_per_piece(gl_session: Any, tmp_path: Path) -> None:
    lines: list[str] = []
    rows = run_render_bench(
        [1, 2], levels=[1.0, 3.0], size=(32, 32), frames=1, plot=tmp_path / "b.png",
        echo=lines.append,
    )  # fmt: skip
    # 2 counts x 2 levels x 5 modes (instanced, per piece, lod, staged, staged_lod)
    assert len(rows) == 20
    for r in rows:
        # I and Y pieces; staged: the sun's shadow pass draws them again
        want = {"per_instance": r.pieces, "instanced": 2, "lod": 2, "staged": 4}
        assert r.draw_calls == want.get(r.mode, 4), r
        assert (r.drawn is not None) == r.mode.endswith("lod")
    by = {(r.trees, r.level, r.mode): r for r in rows}
    for n in (1, 2):  # the framing camera sees every piece, and 32 pixels show their trunks
        lod = by[(n, 1.0, "lod")]
        assert lod.drawn is not None and 0 < lod.drawn <= lod.pieces
        assert any("the cull pass draws" in line for line in lines)
    # the staged rows: the bare frame's triangles plus the shadow pass's (at most level 4)
    for n in (1, 2):
        bare, staged = by[(n, 3.0, "instanced")], by[(n, 3.0, "staged")]
        assert staged.triangles > bare.triangles
    assert by[(2, 3.0, "instanced")].triangles == by[(2, 3.0, "per_instance")].triangles
    assert by[(2, 3.0, "instanced")].triangles == 9 * by[(2, 1.0, "instanced")].triangles
    assert lines[0].startswith("renderer: ")
    assert (tmp_path / "b.png").stat().st_size > 1000


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--trees", "1,x"], "error: trees: expected comma-separated integers, got '1,x'\n"),
        (["--trees", "0"], "error: trees: counts must be positive integers\n"),
        (["--levels", "0.5"], "error: levels: levels must be in [1, 64]\n"),
        (
            ["--foliage-trees", "x"],
            "error: foliage_trees: expected comma-separated integers, got 'x'\n",
        ),
    ],
)
def test_bench_render_bad_options(args: list[str], message: str) -> None:
    res = CliRunner().invoke(main, ["bench", "render", *args])
    assert res.exit_code == 2
    assert res.output == message


def test_parse_counts() -> None:
    assert parse_counts("1, 10,50", "trees") == [1, 10, 50]


def test_saturated_gpu_timer_reports_no_gpu_time() -> None:
    """moderngl's 32-bit GL_TIME_ELAPSED saturates at 2**32 - 1 ns on NVIDIA (a 1,000-oak
    frame at level 4 read 4294.97 ms): such a pass has no GPU time, not a wrong one."""
    from types import SimpleNamespace

    from forest.gl.context import TIMER_SATURATED_NS, elapsed_ms

    assert elapsed_ms(SimpleNamespace(elapsed=5_000_000)) == 5.0  # type: ignore[arg-type]
    assert elapsed_ms(SimpleNamespace(elapsed=TIMER_SATURATED_NS)) is None  # type: ignore[arg-type]
