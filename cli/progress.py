"""Progress of the long commands, on stderr: live bars on a terminal, plain lines elsewhere
(CI logs, pipes, files), nothing with ``--quiet``. Every long command reports through here,
so all of them look alike; stdout keeps only the result lines.

A report is ``(stage, done, total)``, the callback the library's generators, writers and the
renderer take (``forest.growth.generate.Progress``). Each stage gets a bar, or lines, of its
own: the count, the share done, the time taken and an estimate of the time left. A stage that
starts again (the same name with a smaller count) is a new one.
"""

from __future__ import annotations

import os
import re
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TextIO

import click

Report = Callable[[str, int, int], None]
F = Callable[..., Any]
TENTHS = 10  # plain lines: one as a stage starts, one per tenth of it done, one as it ends


def quiet_option(fn: F) -> F:
    """The ``-q/--quiet`` flag of a long command: its ``quiet`` argument."""
    return click.option(
        "-q", "--quiet", is_flag=True, help="Show no progress on stderr, only the results."
    )(fn)


# a plain progress line as PlainLines prints it (the docs' examples leave these out)
PLAIN_LINE = re.compile(r"^\S+: .*? \d+/\d+(?: \(\d+%\))?(?: in .+|, .+ left)?$")


def is_progress_line(line: str) -> bool:
    return PLAIN_LINE.fullmatch(line) is not None


class Quiet:
    """Shows nothing: ``--quiet``. The interface of every display."""

    def __call__(self, stage: str, done: int, total: int) -> None:
        self.report(stage, done, total)

    def report(self, stage: str, done: int, total: int, detail: str = "") -> None:
        """``done`` of ``total`` of ``stage``; ``detail`` says what it is at."""

    def steps(self, stage: str) -> Report:
        """A report whose stage names are steps of one ``stage``, shown beside its count
        (``forest.growth.generate`` names its steps place, grow, ..., each at ``k/5``)."""
        return lambda step, done, total: self.report(stage, done, total, step)

    def echo(self, text: str) -> None:
        """A result line on stdout while progress shows."""
        click.echo(text)

    def close(self) -> None:
        """End the display (live bars clear: the terminal keeps the result lines)."""


def duration(seconds: float) -> str:
    """``8.1 s``, ``3 min 05 s``, ``1 h 02 min``."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    m = int(seconds // 60)
    if m < 60:
        return f"{m} min {int(seconds % 60):02d} s"
    return f"{m // 60} h {m % 60:02d} min"


@dataclass
class _Stage:
    total: int
    start: float
    first: int  # the count at the first report: the rate counts from there
    done: int
    tenth: int  # the last tenth a line was printed for
    ended: bool = False


class PlainLines(Quiet):
    """One line as a stage starts, one each time another tenth of it is done, one as it
    ends: ``forest: skinned trees 3/30 (10%), 0.9 s, about 8.1 s left``; a step of a stage
    in brackets: ``forest: generate 30 tree(s) [grow] 1/5 (20%), ...``."""

    def __init__(
        self, label: str, stream: TextIO, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.label, self.stream, self.clock = label, stream, clock
        self.stages: dict[str, _Stage] = {}

    def report(self, stage: str, done: int, total: int, detail: str = "") -> None:
        now = self.clock()
        tenth = TENTHS * done // total if total > 0 else 0
        s = self.stages.get(stage)
        if s is None or done < s.done or total != s.total:
            s = self.stages[stage] = _Stage(total, now, done, done, tenth)
        elif tenth > s.tenth or (done >= total and not s.ended):
            s.done, s.tenth = done, tenth
        else:
            s.done = done
            return
        s.ended = done >= total
        text = f"{self.label}: {stage}" + (f" [{detail}]" if detail else "") + f" {done}/{total}"
        if total > 0:
            text += f" ({100 * done // total}%)"
        if s.ended:
            text += f" in {duration(now - s.start)}"
        elif done > s.first and now > s.start:
            left = (total - done) * (now - s.start) / (done - s.first)
            text += f", {duration(now - s.start)}, about {duration(left)} left"
        print(text, file=self.stream, flush=True)


class LiveBars(Quiet):
    """rich's live progress display: a bar per stage with its count, share, elapsed time and
    time left, redrawn in place."""

    def __init__(self, label: str, stream: TextIO) -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TaskID,
            TaskProgressColumn,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.label = label
        self.bars = Progress(
            TextColumn("{task.description}", markup=False),
            BarColumn(),
            MofNCompleteColumn(),
            TaskProgressColumn(),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=Console(file=stream),
            # stdout stays ours (echo); stray stderr lines (warnings) print above the bars
            redirect_stdout=False,
            # the bars go when the command ends: the terminal keeps the result lines alone
            transient=True,
        )
        self.tasks: dict[str, tuple[TaskID, int]] = {}
        self.bars.start()

    def report(self, stage: str, done: int, total: int, detail: str = "") -> None:
        text = f"{self.label}: {stage}" + (f" [{detail}]" if detail else "")
        known = self.tasks.get(stage)
        if known is None or done < known[1]:
            task = self.bars.add_task(text, total=max(total, 1), completed=done)
        else:
            task = known[0]
            self.bars.update(task, description=text, total=max(total, 1), completed=done)
        self.tasks[stage] = (task, done)

    def echo(self, text: str) -> None:
        # a line written past the live display would land inside it: on the same terminal it
        # goes above the bars; stdout elsewhere (a file, a pipe) gets it as it is
        if sys.stdout.isatty():
            self.bars.console.print(text, markup=False, highlight=False, soft_wrap=True)
        else:
            click.echo(text)

    def close(self) -> None:
        self.bars.stop()


def is_terminal(stream: TextIO) -> bool:
    """Whether ``stream`` is a terminal that can redraw a line (``TERM=dumb`` cannot)."""
    try:
        tty = stream.isatty()
    except (AttributeError, ValueError):  # no isatty, or closed
        return False
    return tty and os.environ.get("TERM") != "dumb"


@contextmanager
def show_progress(label: str, quiet: bool = False, stream: TextIO | None = None) -> Iterator[Quiet]:
    """The progress display of a command named ``label`` on ``stream`` (default stderr):
    nothing when ``quiet``, live bars on a terminal, plain lines elsewhere."""
    stream = sys.stderr if stream is None else stream
    display = (
        Quiet()
        if quiet
        else LiveBars(label, stream)
        if is_terminal(stream)
        else PlainLines(label, stream)
    )
    try:
        yield display
    finally:
        display.close()
