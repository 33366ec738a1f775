"""Input of the wrong kind gets one line naming the file and what it is; a grammar's errors
come all at once, each with its JSON path and, for a misspelt field or symbol, a suggestion."""

from __future__ import annotations

import io
import json
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import Any

import pytest

from forest.errors import GrammarError, SceneError
from forest.growth.compile import compile_grammar
from forest.growth.grammar import load_grammar, parse_grammar
from forest.growth.grammar_errors import GrammarErrors, did_you_mean, fields_at
from forest.sniff import sniff_bytes
from forest.usd.read import open_stage, pxr_reason

ROOT = Path(__file__).resolve().parent.parent


def usdz_bytes(first: str) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
        z.writestr(first, "#usda 1.0\n")
    return buf.getvalue()


@pytest.mark.parametrize(
    ("head", "kind"),
    [
        (b"PXR-USDC\x00\x00", "usdc"),
        (b"#usda 1.0\n", "usda"),
        (usdz_bytes("scene.usdc"), "usdz"),
        (usdz_bytes("readme.txt"), "zip"),
        (b"glTF\x02\x00\x00\x00", "glb"),
        (b'{"asset": {"version": "2.0"}}', "gltf"),
        (b'  {"axiom": "A"}', "json"),
        (b"\x89PNG\r\n\x1a\n....", "png"),
        (b"\xff\xd8\xff\xe0", "jpeg"),
        (b"II*\x00", "tiff"),
        (b"", "empty"),
        (b"plain words\n", "text"),
        (b"\x00\x01\x02\xfe\xff" * 20, "binary"),
    ],
)
def test_sniff_names_the_kind(head: bytes, kind: str) -> None:
    assert sniff_bytes(head) == kind


def forest(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cli", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
    )


def test_a_glb_given_to_render_is_named_in_one_line(tmp_path: Path) -> None:
    (tmp_path / "pine.glb").write_bytes(b"glTF\x02\x00\x00\x00" + bytes(64))
    res = forest("render", "pine.glb", "-o", "p.png", cwd=tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip() == (
        "error: pine.glb: is glTF (binary .glb), not USD; render reads .usd/.usda/.usdc/.usdz"
    )
    assert not (tmp_path / "p.png").exists()


def test_an_image_given_as_a_grammar_is_named(tmp_path: Path) -> None:
    (tmp_path / "g.json").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(32))
    res = forest("generate", "--grammar", "g.json", "-o", "x.usda", cwd=tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip() == "error: g.json: is a PNG image, not a grammar (JSON)"


def test_a_scene_given_to_tiles_is_named(tmp_path: Path) -> None:
    (tmp_path / "a.usdc").write_bytes(b"PXR-USDC" + bytes(64))
    res = forest("tiles", "a.usdc", "-o", "t", cwd=tmp_path)
    assert res.returncode == 2
    assert "a.usdc: is a USD crate file (.usdc), not an image" in res.stderr


def test_unreadable_usd_has_no_pxr_internals(tmp_path: Path) -> None:
    bad = tmp_path / "broken.usda"
    bad.write_text('#usda 1.0\ndef Xform "a" { bad')
    with pytest.raises(SceneError) as info:
        open_stage(bad)
    assert "pxrInternal" not in str(info.value) and ".cpp" not in str(info.value)
    assert str(info.value).startswith(f"{bad}: not a readable USD file")
    with pytest.raises(SceneError, match="is glTF"):
        open_stage(Path(tmp_path / "x.usd").write_bytes(b"glTF\x02") and tmp_path / "x.usd")


def test_pxr_reason_drops_the_cpp_location() -> None:
    raw = (
        "\tError in 'pxrInternal_v0_26_11__pxrReserved__::UsdStage::Open' at line 1287 in "
        "file /opt/USD/pxr/usd/usd/stage.cpp : 'Failed to open layer @b.usda@'"
    )
    assert pxr_reason(RuntimeError(raw)) == "Failed to open layer b.usda"
    assert pxr_reason(RuntimeError("")) == "RuntimeError"


def two_bad_fields_and_a_bad_symbol() -> dict[str, Any]:
    return {
        "axiom": "A",
        "rules": {"A": [{"piece": "I", "wieght": 2, "successors": [{"symbol": "Bee"}]}]},
        "leavs": {},
    }


def test_every_grammar_error_at_once_with_suggestions() -> None:
    with pytest.raises(GrammarErrors) as info:
        parse_grammar(two_bad_fields_and_a_bad_symbol())
    assert sorted(info.value.lines()) == [
        "leavs: unknown field; did you mean 'leaves'?",
        "rules.A[0].successors[0].symbol: unknown symbol 'Bee'",
        "rules.A[0].wieght: unknown field; did you mean 'weight'?",
    ]
    assert isinstance(info.value, GrammarError)  # callers that catch one error still do


def test_cross_references_are_all_reported_by_compile() -> None:
    g = parse_grammar(
        {
            "axiom": "Trunk",
            "rules": {
                "Trunk": [{"piece": "I", "successors": [{"symbol": "Brnch"}]}],
                "Branch": [{"piece": "I", "successors": [{"symbol": "Trunk"}]}],
            },
            "foliage": ["Leaf"],
            "bark": "oka",
        }
    )
    with pytest.raises(GrammarErrors) as info:
        compile_grammar(g)
    lines = info.value.lines()
    assert (
        "rules.Trunk[0].successors[0].symbol: unknown symbol 'Brnch'; did you mean "
        "'Branch'?" in lines
    )
    assert "foliage[0]: unknown symbol 'Leaf'" in lines
    assert any(
        line.startswith("bark: no shipped bark tile set 'oka'")
        and line.endswith("did you mean 'oak'?")
        for line in lines
    )


def test_a_single_error_stays_a_plain_grammar_error() -> None:
    data = two_bad_fields_and_a_bad_symbol()
    data["rules"]["A"][0] = {"piece": "I", "successors": [{"symbol": "A"}]}
    data["leaves"] = data.pop("leavs")
    data["axiom"] = "B"
    with pytest.raises(GrammarError) as info:
        compile_grammar(parse_grammar(data))
    assert not isinstance(info.value, GrammarErrors)
    assert info.value.path == "axiom"


def test_cli_prints_one_line_per_error(tmp_path: Path) -> None:
    (tmp_path / "g.json").write_text(json.dumps(two_bad_fields_and_a_bad_symbol()))
    res = forest("generate", "--grammar", "g.json", "-o", "x.usda", cwd=tmp_path)
    assert res.returncode == 2
    assert res.stderr.count("error: ") == 3, res.stderr
    with pytest.raises(GrammarErrors):
        load_grammar(tmp_path / "g.json")


def test_the_service_answers_every_grammar_error() -> None:
    from service.errors import forest_error

    with pytest.raises(GrammarErrors) as info:
        parse_grammar(two_bad_fields_and_a_bad_symbol())
    detail = forest_error(info.value, ["grammar"]).errors()
    assert sorted(tuple(d["loc"]) for d in detail) == [
        ("body", "grammar", "leavs"),
        ("body", "grammar", "rules", "A", 0, "successors", 0, "symbol"),
        ("body", "grammar", "rules", "A", 0, "wieght"),
    ]


def test_suggestions_come_from_the_right_object() -> None:
    assert "bend" in fields_at(("rules", "A", 0, "pose"))
    assert "weight" not in fields_at(("rules", "A", 0, "pose"))
    assert did_you_mean("zzz", ["weight"]) == ""


def test_the_api_suggests_misspelt_body_fields() -> None:
    from service.errors import suggest_fields

    errors = [
        {
            "type": "extra_forbidden",
            "loc": ["body", "tress"],
            "msg": "Extra inputs are not permitted",
        },
        {
            "type": "extra_forbidden",
            "loc": ["body", "grammar", "rules", "A", 0, "wieght"],
            "msg": "Extra inputs are not permitted",
        },
        {"type": "missing", "loc": ["body", "seed"], "msg": "Field required"},
    ]
    out = suggest_fields("/v1/forests", errors)
    assert out[0]["msg"] == "Extra inputs are not permitted; did you mean 'trees'?"
    assert out[1]["msg"] == "Extra inputs are not permitted; did you mean 'weight'?"
    assert out[2] == errors[2]
    assert suggest_fields("/v1/jobs", errors) == errors  # no body model there
