"""The README and the documentation pages as the tests read them: fenced blocks, the shell
sessions of ``console`` blocks (commands and the output shown after them), and matching shown
output against printed output with ``...`` wildcards."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from cli.progress import is_progress_line

ROOT = Path(__file__).resolve().parent.parent
NOT_RUN = "# not run by the docs test:"
SHELL_LANGS = ("bash", "sh", "shell", "zsh")
WILDCARD = "..."
# a heredoc's opening (<<EOF, <<'EOF', <<-"EOF"): its lines belong to the command
HEREDOC = re.compile(r"<<-?\s*(['\"]?)(\w+)\1")


def pages() -> list[Path]:
    """The README and every page of the site (the hooks folder holds code, not pages)."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


@dataclass(frozen=True)
class Block:
    path: Path
    line: int  # 1-based line of the opening fence
    lang: str
    lines: tuple[str, ...]

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def blocks(path: Path) -> list[Block]:
    """Every fenced block of a Markdown file, in order (fences at the start of a line)."""
    found: list[Block] = []
    lines = path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        if lines[i].startswith("```"):
            lang = lines[i][3:].strip()
            end = next((j for j in range(i + 1, len(lines)) if lines[j].startswith("```")), None)
            if end is None:
                raise ValueError(f"{path}:{i + 1}: a fence that is never closed")
            found.append(Block(path, i + 1, lang, tuple(lines[i + 1 : end])))
            i = end + 1
        else:
            i += 1
    return found


@dataclass(frozen=True)
class Command:
    text: str  # what the shell runs: continuation lines and heredoc bodies included
    expected: tuple[str, ...]  # the output the page shows after it (may be empty)
    where: str


def session(block: Block) -> list[Command]:
    """A ``console`` block's commands: a line starting with ``$ `` starts one, a trailing
    backslash or a heredoc carries it onto the next lines, and the lines up to the next ``$ ``
    are its shown output."""
    commands: list[Command] = []
    lines = list(block.lines)
    i = 0
    if lines and not lines[0].startswith("$ "):
        raise ValueError(f"{block.where}: a console block must start with a `$ ` command")
    while i < len(lines):
        start = i
        text = [lines[i][2:]]
        i += 1
        while text[-1].endswith("\\") and i < len(lines):
            text.append(lines[i])
            i += 1
        heredoc = HEREDOC.search("\n".join(text))
        if heredoc:
            end = heredoc.group(2)
            while i < len(lines) and lines[i].strip() != end:
                text.append(lines[i])
                i += 1
            text.append(lines[i] if i < len(lines) else end)
            i += 1
        expected = []
        while i < len(lines) and not lines[i].startswith("$ "):
            expected.append(lines[i])
            i += 1
        where = f"{block.where} (line {block.line + 1 + start})"
        commands.append(Command("\n".join(text), tuple(expected), where))
    return commands


def _normal(line: str) -> str:
    """Runs of blanks compare equal (tabs and column padding)."""
    return " ".join(line.split())


def output_pattern(expected: tuple[str, ...]) -> re.Pattern[str]:
    """``...`` alone on a line: any lines (none included); ``...`` within a line: any text."""
    parts = []
    for line in expected:
        if line.strip() == WILDCARD:
            parts.append(r"(?:[^\n]*\n)*?")
        else:
            pieces = [re.escape(p) for p in _normal(line).split(WILDCARD)]
            parts.append("[^\n]*?".join(pieces) + r"\n")
    return re.compile("".join(parts))


def matches(expected: tuple[str, ...], printed: str) -> bool:
    # progress lines on stderr are left out, as a terminal's bars go when a command ends
    lines = [_normal(x) for x in printed.splitlines() if not is_progress_line(x)]
    while lines and not lines[-1]:
        lines.pop()
    shown = list(expected)
    while shown and not shown[-1].strip():
        shown.pop()
    text = "".join(line + "\n" for line in lines)
    return output_pattern(tuple(shown)).fullmatch(text) is not None
