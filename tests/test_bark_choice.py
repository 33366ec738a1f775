"""A shipped bark tile set in place of the grammar's own: the CLI's --bark, the API's bark."""

from __future__ import annotations

import typing
from pathlib import Path

import click
from click.testing import CliRunner
from pxr import Usd

from cli.app import main
from forest.bark.tilesets import SETS
from schemas.jobs import BarkSet, TreeRequest


def test_the_schema_and_the_cli_name_every_shipped_set() -> None:
    """The names are spelled out where they are read at start-up (no tile-set import for a
    schema or the command's options): both lists follow the shipped sets."""
    assert typing.get_args(BarkSet) == SETS
    generate = main.get_command(click.Context(main), "generate")
    bark = next(p for p in generate.params if p.name == "bark")
    assert tuple(bark.type.choices) == SETS


def bark_set(path: Path) -> str:
    stage = Usd.Stage.Open(str(path))
    found = {
        str(a.Get())
        for p in stage.Traverse()
        if (a := p.GetAttribute("forest:barkTileSet")) and a.HasAuthoredValue()
    }
    assert len(found) == 1, found
    return found.pop()


def test_cli_bark_replaces_the_species_set(tmp_path: Path) -> None:
    runner = CliRunner()
    for bark, want in ((None, "almond"), ("birch", "birch")):
        out = tmp_path / f"{bark}.usda"
        args = ["generate", "--preset", "almond", "--no-lod", "-o", str(out)]
        r = runner.invoke(main, args + (["--bark", bark] if bark else []))
        assert r.exit_code == 0, r.output
        assert bark_set(out) == want
        if bark:  # the scene's pictures are that set's
            assert (tmp_path / f"{bark}.textures" / "bark.1001.png").is_file()
    r = runner.invoke(
        main, ["generate", "--recipe", "orchard", "--bark", "oak", "-o", str(tmp_path / "s.usda")]
    )
    assert r.exit_code != 0 and "--bark" in r.output
    r = runner.invoke(
        main, ["generate", "--preset", "oak", "--bark", "maple", "-o", str(tmp_path / "m.usda")]
    )
    assert r.exit_code == 2 and "maple" in r.output


def test_request_bark_is_checked() -> None:
    assert TreeRequest(preset="oak", bark="pine").bark == "pine"
    for bad in ({"preset": "oak", "bark": "maple"}, {"recipe": "orchard", "bark": "oak"}):
        try:
            TreeRequest.model_validate(bad)
        except ValueError as exc:
            assert "bark" in str(exc)
        else:
            raise AssertionError(bad)
