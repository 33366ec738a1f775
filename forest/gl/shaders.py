"""GLSL sources from the top-level ``shaders`` package, loaded by name and cached.

The only templating is a block of ``#define`` lines inserted right after the ``#version``
line. A define a shader never mentions is an error, so a misspelt variant fails loudly
instead of silently compiling the default.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from functools import cache
from importlib import resources

from forest.errors import ForestError

STAGES = ("vert", "tesc", "tese", "frag")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_VERSION = re.compile(r"^#version[^\n]*\n", re.MULTILINE)

Defines = Mapping[str, object]


class ShaderError(ForestError):
    """A shader source is missing, malformed, or asked for a define it does not know."""


@cache
def load(filename: str) -> str:
    """Text of ``shaders/<filename>`` (e.g. ``piece.vert``)."""
    if "/" in filename or "\\" in filename:
        raise ShaderError("shader names are plain file names", path=filename)
    try:
        return (resources.files("shaders") / filename).read_text(encoding="utf-8")
    except (FileNotFoundError, IsADirectoryError):
        raise ShaderError("no such shader in the shaders package", path=filename) from None


def compose(filename: str, defines: Defines | None = None) -> str:
    """The source of ``filename`` with ``#define NAME VALUE`` lines after ``#version``.

    A value of ``True`` or ``None`` defines the bare name; ``False`` leaves it undefined.
    """
    src = load(filename)
    m = _VERSION.match(src)
    if m is None:
        raise ShaderError("first line must be #version", path=filename)
    lines = []
    for name, value in sorted((defines or {}).items()):
        if not _NAME.match(name):
            raise ShaderError(f"bad define name {name!r}", path=filename)
        if value is False:
            continue
        if not re.search(rf"\b{name}\b", src[m.end() :]):
            raise ShaderError(f"define {name} is not used by this shader", path=filename)
        lines.append(f"#define {name}" if value in (True, None) else f"#define {name} {value}")
    if not lines:
        return src
    # keep line numbers of compiler messages right: #line resets the count after the block
    return src[: m.end()] + "\n".join(lines) + "\n#line 2\n" + src[m.end() :]


def sources(stem: str, defines: Defines | None = None) -> dict[str, str]:
    """Keyword arguments for ``moderngl.Context.program``: every stage of ``stem`` that exists.

    A define goes to every stage that mentions it and must be mentioned by at least one.
    """
    out: dict[str, str] = {}
    used: set[str] = set()
    defines = dict(defines or {})
    for stage in STAGES:
        filename = f"{stem}.{stage}"
        try:
            text = load(filename)
        except ShaderError:
            continue
        mine = {k: v for k, v in defines.items() if re.search(rf"\b{k}\b", text)}
        used |= mine.keys()
        out[_KWARG[stage]] = compose(filename, mine)
    if not out:
        raise ShaderError("no shader stages found", path=stem)
    unknown = sorted(set(defines) - used)
    if unknown:
        raise ShaderError(f"defines not used by any stage: {', '.join(unknown)}", path=stem)
    return out


_KWARG = {
    "vert": "vertex_shader",
    "tesc": "tess_control_shader",
    "tese": "tess_evaluation_shader",
    "frag": "fragment_shader",
}
