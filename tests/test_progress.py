"""cli.progress: live bars on a terminal, plain lines elsewhere, nothing when quiet."""

from __future__ import annotations

import io

import pytest

from cli.progress import LiveBars, PlainLines, Quiet, duration, show_progress


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_plain_lines_at_start_each_tenth_and_end() -> None:
    out, clock = io.StringIO(), Clock()
    bar = PlainLines("forest", out, clock)
    for k in range(31):
        clock.t = 0.5 * k
        bar("skinned trees", k, 30)
    lines = out.getvalue().splitlines()
    assert lines[0] == "forest: skinned trees 0/30 (0%)"
    assert lines[1] == "forest: skinned trees 3/30 (10%), 1.5 s, about 13.5 s left"
    assert lines[-1] == "forest: skinned trees 30/30 (100%) in 15.0 s"
    assert len(lines) == 11  # the start, 10 %, 20 %, ..., 90 %, the end


def test_plain_steps_restarts_and_small_stages() -> None:
    out, clock = io.StringIO(), Clock()
    bar = PlainLines("forest", out, clock)
    grow = bar.steps("generate 2 tree(s)")
    grow("place", 0, 5)
    clock.t = 0.25
    grow("grow", 1, 5)
    bar("save", 0, 1)
    clock.t = 2.0
    bar("save", 1, 1)
    bar("save", 1, 1)  # said once
    bar("save", 0, 1)  # a second file: a stage of its own
    assert out.getvalue().splitlines() == [
        "forest: generate 2 tree(s) [place] 0/5 (0%)",
        "forest: generate 2 tree(s) [grow] 1/5 (20%), 0.2 s, about 1.0 s left",
        "forest: save 0/1 (0%)",
        "forest: save 1/1 (100%) in 1.8 s",
        "forest: save 0/1 (0%)",
    ]


@pytest.mark.parametrize(
    ("seconds", "text"), [(8.14, "8.1 s"), (185, "3 min 05 s"), (3720, "1 h 02 min")]
)
def test_duration(seconds: float, text: str) -> None:
    assert duration(seconds) == text


def test_a_terminal_gets_live_bars_anything_else_plain_lines(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv("TERM", raising=False)
    tty = Terminal()
    with show_progress("render", stream=tty) as bar:
        assert isinstance(bar, LiveBars)
        bar("frames", 2, 4)
    assert "render: frames" in tty.getvalue() and "2/4" in tty.getvalue()
    assert "\x1b[" in tty.getvalue()  # drawn with terminal controls

    pipe = io.StringIO()
    with show_progress("render", stream=pipe) as bar:
        assert isinstance(bar, PlainLines)
        bar("frames", 2, 4)
    assert pipe.getvalue() == "render: frames 2/4 (50%)\n"

    monkeypatch.setenv("TERM", "dumb")  # a terminal that cannot redraw a line
    with show_progress("render", stream=Terminal()) as bar:
        assert isinstance(bar, PlainLines)


@pytest.mark.parametrize("stream", [io.StringIO(), Terminal()])
def test_quiet_shows_nothing(stream: io.StringIO) -> None:
    with show_progress("tiles", quiet=True, stream=stream) as bar:
        assert type(bar) is Quiet
        bar("patches", 1, 2)
        bar.steps("generate")("grow", 1, 5)
    assert stream.getvalue() == ""
