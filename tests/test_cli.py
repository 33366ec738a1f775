"""The `forest` command as a user runs it: one clear line and exit code 2 for bad input."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd

ROOT = Path(__file__).parents[1]


def forest(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "cli", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_presets_lists_every_preset(tmp_path: Path) -> None:
    out = forest("presets", cwd=tmp_path)
    assert out.returncode == 0
    names = [line.split()[0] for line in out.stdout.splitlines()]
    assert names == [
        "almond", "alternating", "birch", "hazel", "oak", "pine", "poplar", "spruce", "uniform",
        "willow",
    ]  # fmt: skip


def test_version_is_the_running_code_s(tmp_path: Path) -> None:
    """``forest --version`` reports ``forest.__version__`` (which the files it writes carry),
    not the installed distribution's metadata, which an editable install keeps stale."""
    from forest import __version__

    out = forest("--version", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout == f"forest, version {__version__}\n"


def test_generate_writes_a_forest(tmp_path: Path) -> None:
    out = forest(
        "generate",
        "--preset",
        "hazel",
        "--seed",
        "4",
        "--trees",
        "3",
        "--frames",
        "2",
        "--skinned",
        "-o",
        "c.usdz",
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr
    assert "3 tree(s)" in out.stdout
    stage = Usd.Stage.Open(str(tmp_path / "c.usdz"))
    assert not stage.GetPrimAtPath("/World/Forest/Pieces")  # ARKit: the skinned trees only
    assert len(stage.GetPrimAtPath("/World/Forest/Trees").GetChildren()) == 3


def test_generate_says_once_why_no_impostor_was_baked(tmp_path: Path) -> None:
    """Over the bake's tree limit the levels are written without lod3, and one note says so."""
    from forest.usd.scene import IMPOSTOR_MAX_TREES

    trees = str(IMPOSTOR_MAX_TREES + 1)
    out = forest(
        "generate", "--preset", "alternating", "--trees", trees, "-o", "m.usdc", cwd=tmp_path
    )
    assert out.returncode == 0, out.stderr
    notes = [line for line in out.stdout.splitlines() if line.startswith("note:")]
    assert len(notes) == 1 and f"over {IMPOSTOR_MAX_TREES} trees" in notes[0]


def test_generate_shows_progress_lines_unless_quiet(tmp_path: Path) -> None:
    """stderr is a pipe here, as in a CI log: plain lines with counts, not redrawn bars;
    ``--quiet`` leaves only the result line. The files are the same either way."""
    # no pictures: a.usdc and b.usdc would name their own folders, a.textures and b.textures
    args = ["generate", "--preset", "alternating", "--trees", "30", "--skinned", "--no-textures"]
    out = forest(*args, "-o", "a.usdc", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    lines = out.stderr.splitlines()
    assert "\r" not in out.stderr and "\x1b" not in out.stderr
    assert all(line.startswith("forest: ") for line in lines), lines
    assert lines[0] == "forest: generate 30 tree(s) [place] 0/5 (0%)"
    assert "forest: skinned trees 0/30 (0%)" in lines
    assert any(line.startswith("forest: skinned trees 3/30 (10%), ") for line in lines)
    assert any(line.startswith("forest: skinned trees 30/30 (100%) in ") for line in lines)
    assert lines[-1].startswith("forest: save 1/1 (100%) in ")
    assert len(lines) < 40  # every tenth, not every tree
    quiet = forest(*args, "--quiet", "-o", "b.usdc", cwd=tmp_path)
    assert quiet.returncode == 0 and quiet.stderr == ""
    # the result line; any note only without --quiet
    assert quiet.stdout == out.stdout.splitlines(keepends=True)[-1].replace("a.usdc", "b.usdc")
    assert (tmp_path / "a.usdc").read_bytes() == (tmp_path / "b.usdc").read_bytes()


def test_demo_says_what_it_wrote(tmp_path: Path) -> None:
    out = forest("demo", "-o", "d", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    written = sorted(p.name for p in (tmp_path / "d").iterdir())
    assert written == [
        "almond_skinned.usdz",
        "birches.textures",
        "birches.usdc",
        "forest.textures",
        "forest.usdc",
        "metrics.json",
        "preview.png",
    ]
    for name in written:
        if not name.endswith(".textures"):  # a scene's pictures, beside it
            assert name in out.stdout


GOOD_RULE = {"piece": "I", "successors": [None]}
BAD_INPUTS = [
    (
        {"axiom": "A", "rules": {"A": [{"piece": "I", "successors": [{"symbol": "B"}]}]}},
        "rules.A[0].successors[0].symbol: unknown symbol 'B'",
    ),
    ({"axiom": "A", "rules": {"A": [{**GOOD_RULE, "weight": -1}]}}, "rules.A[0].weight"),
    ({"axiom": "A", "rules": {"A": [{**GOOD_RULE, "weight": 0}]}}, "rules.A[0].weight"),
    (
        {
            "axiom": "A",
            "rules": {"A": [{"piece": "Y", "successors": [{"symbol": "A"}, {"symbol": "A"}]}]},
        },
        "max_depth: the rules never terminate",
    ),
    (
        {
            "axiom": "A",
            "max_depth": 40,
            "rules": {"A": [{"piece": "Y", "successors": [{"symbol": "A"}, {"symbol": "A"}]}]},
        },
        "max_pieces_per_tree",
    ),
    (
        {"axiom": "A", "rules": {"A": [{"piece": "Y", "successors": [None]}]}},
        "rules.A[0].successors: piece Y has 2 leaf rim(s)",
    ),
    (
        {
            "axiom": "R0",
            "rules": {f"R{i}": [{"piece": "I", "successors": [None]}] for i in range(300)},
        },
        "rules: 300 rules; a grammar has at most 256 (max_grammar_rules)",
    ),
]


@pytest.mark.parametrize(("grammar", "message"), BAD_INPUTS)
def test_bad_grammar_gets_one_line_and_exit_2(tmp_path: Path, grammar: dict, message: str) -> None:
    (tmp_path / "g.json").write_text(json.dumps(grammar))
    t0 = time.monotonic()
    out = forest("generate", "--grammar", "g.json", "-o", "x.usda", cwd=tmp_path)
    assert time.monotonic() - t0 < 30  # generous: interpreter start-up, not the check
    assert out.returncode == 2
    assert message in out.stderr
    assert out.stderr.count("\n") == 1 and "Traceback" not in out.stderr
    assert not (tmp_path / "x.usda").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--preset", "almond", "--trees", "1000000000"], "trees: trees must be between 1 and"),
        (["--preset", "nope"], "preset: unknown preset 'nope'"),
        (["--grammar", "missing.json"], "missing.json: no such file"),
        (["--grammar", "trunc.json"], "truncated JSON"),
        (["--grammar", "bad.json"], "malformed JSON"),
        (["--preset", "almond", "-o", "/proc/forest.usda"], "/proc: folder is not writable"),
        (["--preset", "almond", "-o", "no/such/dir/f.usda"], "folder does not exist"),
        (["--preset", "almond", "-o", "f.obj"], "unknown format '.obj'"),
        (["--preset", "almond", "--grammar", "bad.json"], "exactly one of --preset"),
        (["--preset", "almond", "--frames", "-3"], "frames must be between 0"),
        (["--preset", "almond", "--area", "0", "10"], "'--area'"),
        # the API's bounds (schemas.jobs): NaN, infinity and out of range refused alike
        (["--preset", "almond", "--wind", "nan"], "'--wind': 'nan' is not a finite number"),
        (["--preset", "almond", "--wind", "1e9"], "'--wind'"),
        (["--preset", "almond", "--fps", "inf"], "'--fps'"),
        (["--preset", "almond", "--lod", "-o", "f.glb"], "lod: a .glb's levels of detail"),
    ],
)
def test_bad_options_get_one_line_and_exit_2(tmp_path: Path, args: list[str], message: str) -> None:
    (tmp_path / "trunc.json").write_text('{"axiom": "A", "rules": {"A": [{"piece": "I", "succ')
    (tmp_path / "bad.json").write_text('{"axiom": "A",, "rules": {}}')
    if "-o" not in args:
        args = [*args, "-o", "out.usda"]
    out = forest("generate", *args, cwd=tmp_path)
    assert out.returncode == 2, out.stderr
    assert message in out.stderr
    assert "Traceback" not in out.stderr


def test_tiles_folder_sets_material_and_manifest(tmp_path: Path) -> None:
    from forest.usd.read import read_scene

    (tmp_path / "tiles").mkdir()
    (tmp_path / "tiles" / "manifest.json").write_text(
        json.dumps(
            {
                "classes": [
                    {"name": "bark", "id": 1, "first": 0, "count": 3},
                    {"name": "fork", "id": 2, "first": 3, "count": 2},
                ]
            }
        )
    )
    out = forest(
        "generate", "--preset", "uniform", "--tiles", "tiles", "-o", "f.usda", cwd=tmp_path
    )
    assert out.returncode == 0, out.stderr
    assert "tiles/bark.<UDIM>.png" in (tmp_path / "f.usda").read_text()
    scene = read_scene(tmp_path / "f.usda")
    used = scene.tile_indices[scene.tile_indices >= 0]
    assert set(np.unique(used)) == set(range(5))
    assert scene.manifest.classes[0].count == 3

    (tmp_path / "tiles" / "manifest.json").write_text('{"classes": []}')
    out = forest(
        "generate", "--preset", "uniform", "--tiles", "tiles", "-o", "g.usda", cwd=tmp_path
    )
    assert out.returncode == 2
    assert "tiles/manifest.json: classes" in out.stderr
    out = forest("generate", "--preset", "uniform", "--tiles", "none", "-o", "g.usda", cwd=tmp_path)
    assert out.returncode == 2 and "tile-set folder does not exist" in out.stderr


def test_palette_size_is_capped(tmp_path: Path) -> None:
    env_cap = {"FOREST_MAX_PALETTE_MATRICES": "1000"}
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "cli",
            "generate",
            "--preset",
            "almond",
            "--trees",
            "20",
            "--frames",
            "48",
            "-o",
            "f.usdc",
        ],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT), **env_cap},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2
    assert "max_palette_matrices" in out.stderr and "use fewer frames" in out.stderr


def test_bench_generate_prints_both_sides(tmp_path: Path) -> None:
    out = forest("bench", "generate", "--trees", "30", "--repeat", "1", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    for label in (
        "vectorised (per depth level)",
        "baseline (per-piece Python loop)",
        "speed-up",
        "write .usdc",
        "x Save   (target <= 1x)",
        "peak RSS",
    ):
        assert label in out.stdout
