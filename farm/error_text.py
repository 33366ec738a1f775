"""A job's stored error, kept short: repeated lines folded, then capped.

A failed write in pxr repeats one C++ error per buffer flushed (close to a megabyte of text),
and a database error carries its whole SQL statement: stored as they come, a page of jobs
would run to megabytes. The first lines say what went wrong; the rest is noise.
"""

from __future__ import annotations

MAX_ERROR_CHARS = 4096


def fold_repeats(text: str) -> str:
    """Each distinct line once, where it first appeared, followed by ``... (repeated N
    times)`` (N in all) when it came back (pxr's errors alternate between a few lines, so
    repeats need not be adjacent)."""
    counts: dict[str, int] = {}
    for line in text.splitlines():
        counts[line] = counts.get(line, 0) + 1
    if len(counts) == sum(counts.values()):
        return text  # nothing repeated: as it was
    out: list[str] = []
    for line, n in counts.items():
        out.append(line)
        if n > 1 and line.strip():
            out.append(f"... (repeated {n} times)")
    return "\n".join(out)


def capped(text: str | None, limit: int = MAX_ERROR_CHARS) -> str | None:
    """``text`` folded and cut to at most ``limit`` characters (saying how much was cut)."""
    if text is None:
        return None
    folded = fold_repeats(text)
    if len(folded) <= limit:
        return folded
    # room for the note at its longest (the cut count has at most as many digits)
    cut = limit - len(f" ... ({len(folded)} more characters)")
    return folded[:cut] + f" ... ({len(folded) - cut} more characters)"
