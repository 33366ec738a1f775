"""Every ``console`` example of the README and of ``docs/`` runs as shown.

Each page runs in a fresh folder, in one bash session (a variable or a file one command makes
is there for the next), with this environment's ``forest`` command on ``PATH`` and ``.venv`` in
the folder pointing at this environment, so ``source .venv/bin/activate`` works as pasted. A
page whose commands use ``$FOREST_URL`` gets ``forest serve`` started in its folder first, the
way its text says, on a free loopback port that replaces ``127.0.0.1:8000`` in its commands.
A command must exit 0, or non-zero where the page shows an ``error:`` line for it; where the
page shows output, the printed output (stdout and stderr together) must match it (``...``
wildcards, see ``docs_pages.matches``). Blocks that cannot run here are checked to say why in
``tests/test_docs.py``.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import socket
import subprocess
import sys
import time
import urllib.request
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from docs_pages import ROOT, Block, Command, blocks, matches, pages, session

DEFAULT_ADDRESS = "127.0.0.1:8000"  # the address the pages' examples show
SERVER_VARIABLE = "FOREST_URL"
COMMAND_TIMEOUT_S = 180  # a job poll loop included
SERVE_TIMEOUT_S = 90


def console_blocks(page: Path) -> list[Block]:
    return [b for b in blocks(page) if b.lang == "console"]


PAGES = [p for p in pages() if console_blocks(p)]


def page_env() -> dict[str, str]:
    bin_dir = Path(sys.executable).parent
    if not (bin_dir / "forest").exists():
        pytest.fail(f"no `forest` command beside {sys.executable}: install the package (make test)")
    # the pages' settings are the defaults: none of the caller's FOREST_* may leak in
    env = {k: v for k, v in os.environ.items() if not k.startswith("FOREST_")}
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    env["PYTHONUNBUFFERED"] = "1"  # stdout and stderr interleave as on a terminal
    return env


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def served(folder: Path, env: dict[str, str]) -> Iterator[int]:
    """``forest serve`` in ``folder`` (its default ``--data forest-data``), one job worker."""
    port = free_port()
    log = open(folder / "serve.log", "wb")  # noqa: SIM115
    proc = subprocess.Popen(
        ["forest", "serve", "--port", str(port), "--workers", "1"],
        cwd=folder,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    log.close()
    try:
        deadline = time.monotonic() + SERVE_TIMEOUT_S
        while True:
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"forest serve did not start:\n{(folder / 'serve.log').read_text()}")
            url = f"http://127.0.0.1:{port}/readyz"
            with contextlib.suppress(OSError), urllib.request.urlopen(url, timeout=2) as r:
                if r.status == 200:
                    break
            time.sleep(0.3)
        yield port
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        for pid_file in (folder / "forest-data" / "run").glob("worker-*.pid"):
            with contextlib.suppress(ProcessLookupError, ValueError):
                os.kill(int(pid_file.read_text()), signal.SIGKILL)


class Shell:
    """One bash for a page: each command's output and exit status, read up to a marker."""

    def __init__(self, folder: Path, env: dict[str, str]) -> None:
        self.proc = subprocess.Popen(
            ["bash", "--noprofile", "--norc"],
            cwd=folder,
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )

    def run(self, command: str) -> tuple[int, str]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        marker = f"__docs_{uuid.uuid4().hex}__"
        # stdin from /dev/null: a command must not read the rest of this script; the status
        # is restored after the marker, so `echo $?` on the next line sees it
        script = (
            f"{{ {command}\n}} </dev/null\n"
            f"__rc=$?; printf '\\n{marker} %d\\n' $__rc; (exit $__rc)\n"
        )
        self.proc.stdin.write(script.encode())
        self.proc.stdin.flush()
        fd = self.proc.stdout.fileno()
        out = b""
        end = f"\n{marker} ".encode()
        deadline = time.monotonic() + COMMAND_TIMEOUT_S
        while end not in out or not out.endswith(b"\n"):
            left = deadline - time.monotonic()
            ready, _, _ = select.select([fd], [], [], max(left, 0))
            if not ready:
                raise TimeoutError(out.decode(errors="replace")[-3000:])
            chunk = os.read(fd, 65536)
            if not chunk:
                raise EOFError(out.decode(errors="replace")[-3000:])
            out += chunk
        printed, status = out.rsplit(end, 1)
        return int(status.decode().split()[0]), printed.decode(errors="replace")

    def close(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()
        for pipe in (self.proc.stdin, self.proc.stdout):
            if pipe is not None:
                pipe.close()


def check(command: Command, status: int, printed: str) -> None:
    shows_error = any(line.startswith("error:") for line in command.expected)
    if shows_error and status == 0:
        pytest.fail(f"{command.where}: `{command.text}` shows an error but exited 0:\n{printed}")
    if not shows_error and status != 0:
        pytest.fail(f"{command.where}: `{command.text}` exited {status}:\n{printed}")
    if command.expected and not matches(command.expected, printed):
        shown = "\n".join(command.expected)
        pytest.fail(
            f"{command.where}: `{command.text}` printed\n{printed}\n--- the page shows\n{shown}"
        )


@pytest.mark.slow
@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_examples_run_as_shown(page: Path, tmp_path: Path) -> None:
    commands = [c for b in console_blocks(page) for c in session(b)]
    env = page_env()
    venv = Path(sys.prefix)
    if not (venv / "bin" / "activate").exists():
        pytest.fail(f"the pages activate .venv: run the tests in a virtual environment, not {venv}")
    (tmp_path / ".venv").symlink_to(venv)
    with contextlib.ExitStack() as stack:
        if any(f"${SERVER_VARIABLE}" in c.text for c in commands):
            port = stack.enter_context(served(tmp_path, env))
            address = f"127.0.0.1:{port}"
            commands = [
                Command(c.text.replace(DEFAULT_ADDRESS, address), c.expected, c.where)
                for c in commands
            ]
        shell = Shell(tmp_path, env)
        stack.callback(shell.close)
        for command in commands:
            try:
                status, printed = shell.run(command.text)
            except (TimeoutError, EOFError) as exc:
                pytest.fail(f"{command.where}: `{command.text}` did not finish: {exc}")
            check(command, status, printed)


def test_every_page_with_examples_is_run() -> None:
    """The examples test covers every page that has a console block (none left out by a
    filter), and every console block parses into commands."""
    for page in pages():
        for block in console_blocks(page):
            assert session(block), block.where
    assert {p.name for p in PAGES} >= {"README.md", "getting-started.md", "http-api.md"}
