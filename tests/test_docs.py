"""The README and the documentation pages stay true to the code: no shell example escapes the
examples test, every setting is documented with its default, every path a page names exists."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from docs_pages import NOT_RUN, ROOT, SHELL_LANGS, blocks, pages
from pydantic import BaseModel

from farm.settings import FarmSettings
from forest.settings import ForestSettings
from service.settings import ServiceSettings

README_MAX_BYTES = 12 * 1024
REPO_DIRS = (
    "bench",
    "cli",
    "deploy",
    "docs",
    "farm",
    "forest",
    "schemas",
    "service",
    "shaders",
    "tests",
    "web",
    "worker",
)
# paths the pages name that a run makes, not the repository holds
MADE_BY_RUNS = ("tests/output/", "deploy/.env")
CODE_SPAN = re.compile(r"(?<!`)`([^`\n]+)`(?!`)")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def test_readme_is_short() -> None:
    size = (ROOT / "README.md").stat().st_size
    assert size < README_MAX_BYTES, f"README.md is {size} bytes: move detail into docs/"


@pytest.mark.parametrize("page", pages(), ids=lambda p: p.name)
def test_shell_blocks_run_or_say_why(page: Path) -> None:
    """Every fence names its language; a shell block that the examples test does not run
    says why on its first line; `$ ` commands appear only in console blocks (which run)."""
    for block in blocks(page):
        assert block.lang, f"{block.where}: a fence without a language"
        if block.lang in SHELL_LANGS:
            assert block.lines and block.lines[0].startswith(NOT_RUN), (
                f"{block.where}: a {block.lang} block is not run: its first line must be "
                f"'{NOT_RUN} <why>' (or make it a console block, which runs)"
            )
        if block.lang != "console":
            prompts = [line for line in block.lines if line.startswith("$ ")]
            assert not prompts, f"{block.where}: `$ ` commands outside a console block: {prompts}"


def _outside_fences(page: Path) -> str:
    return re.sub(r"(?ms)^```.*?^```", "", page.read_text(encoding="utf-8"))


@pytest.mark.parametrize("page", pages(), ids=lambda p: p.name)
def test_named_paths_exist(page: Path) -> None:
    missing = []
    for span in CODE_SPAN.findall(_outside_fences(page)):
        path = span.strip()
        if not re.fullmatch(rf"(?:{'|'.join(REPO_DIRS)})/[\w./-]*", path):
            continue
        if path.startswith(MADE_BY_RUNS):
            continue
        if not (ROOT / path).exists():
            missing.append(path)
    assert not missing, f"{page.name} names paths that do not exist: {missing}"


def test_readme_links_resolve() -> None:
    """mkdocs checks the pages' links; the README's are checked here."""
    text = _outside_fences(ROOT / "README.md")
    broken = [
        target
        for target in LINK.findall(text)
        if "://" not in target and not (ROOT / target.split("#")[0]).exists()
    ]
    assert not broken, broken


def _table_rows(section: str) -> dict[str, str]:
    """``FOREST_X`` -> the default a table row shows for it (rows may name several)."""
    rows: dict[str, str] = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 3 or not cells[0].startswith("`FOREST_"):
            continue
        names = re.findall(r"`FOREST_([A-Z0-9_]+)`", cells[0])
        defaults = [d.strip() for d in cells[1].split(", ")]
        assert len(defaults) == len(names), f"row {cells[0]}: {len(defaults)} defaults"
        rows.update(zip(names, defaults, strict=True))
    return rows


def _shown(default: str) -> Any:
    """A default as the page writes it, as a value to compare; None where it is prose (a
    derived path)."""
    default = default.strip("`")
    if default == "empty":
        return ""
    if default in ("true", "false"):
        return default == "true"
    units = {"MiB": 1 << 20, "GiB": 1 << 30}
    m = re.fullmatch(r"(\d+) (MiB|GiB)", default)
    if m:
        return float(int(m.group(1)) * units[m.group(2)])
    if re.fullmatch(r"-?\d+(\.\d+)?", default):
        return float(default)
    return None if "<" in default else default


def _sections() -> dict[str, str]:
    text = (ROOT / "docs" / "configuration.md").read_text(encoding="utf-8")
    found = {}
    for chunk in re.split(r"(?m)^## ", text)[1:]:
        m = re.search(r"\(`(\w+)/settings\.py`\)", chunk.splitlines()[0])
        if m:
            found[m.group(1)] = chunk
    return found


SETTINGS: dict[str, tuple[type[BaseModel], set[str]]] = {
    "forest": (ForestSettings, set(ForestSettings.model_fields)),
    "farm": (FarmSettings, set(FarmSettings.model_fields)),
    # the API's own settings: the farm's are in the farm's table
    "service": (
        ServiceSettings,
        set(ServiceSettings.model_fields) - set(FarmSettings.model_fields),
    ),
}


@pytest.mark.parametrize("package", SETTINGS)
def test_every_setting_documented_with_its_default(package: str) -> None:
    model, fields = SETTINGS[package]
    rows = _table_rows(_sections()[package])
    documented = {name.lower() for name in rows}
    assert documented == fields, (
        f"docs/configuration.md, {package}/settings.py: missing "
        f"{sorted(fields - documented)}, not settings {sorted(documented - fields)}"
    )
    for name, shown in rows.items():
        default = model.model_fields[name.lower()].default
        value = _shown(shown)
        if value is None or default is None:
            continue
        if isinstance(value, bool):
            same = default is value
        elif isinstance(value, float):
            same = float(default) == value
        else:
            same = str(default) == value
        assert same, f"FOREST_{name}: the page says {shown}, the code {default}"
