"""One job attempt in a child process of its own, supervised by the worker.

The worker (parent) claims the job, starts a child from a fork server (clean: no threads, no
database connections; the heavy modules preloaded once) and then only waits: it extends the
lease every ``heartbeat_s`` whatever the child does (a long GL draw or a big write holds the
child's GIL, not the parent's), kills the child when cancel is asked or the lease is lost, and
reads how the child ended:

- a message ``ok`` (artifact files in the scratch folder + result), ``bad`` (the input cannot
  work, or the data volume is full: a permanent failure) or ``error`` (anything else:
  retried);
- no message and a signal: a crash (SIGSEGV in the USD reader on a crafted file), a CPU limit
  (SIGXCPU) or the kernel's OOM killer: permanent failures of the job, not a lost worker.

Resource limits (``RLIMIT_AS``, ``RLIMIT_CPU``) are set in the child before it runs anything, so
a time-sample bomb ends as a MemoryError of one child, not an OOM of the worker.

The child also sends events on a second pipe, read as they come: each stage change with its
time, and its warnings and errors (Python's ``logging`` at WARNING and up, and ``warnings``),
at most :data:`CHILD_EVENTS` an attempt; the worker writes them into the job's log.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import re
import resource
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from multiprocessing.context import BaseContext
from pathlib import Path
from typing import Any

PRELOAD = [
    "forest.usd.scene",
    "forest.growth.generate",
    "forest.export",
    "worker.render.render_file",
    "worker.jobs.tasks",
]
STAGE_BYTES = 64
CHILD_EVENTS = 500  # events one attempt's child sends at most (the log is capped anyway)
Event = tuple[str, float, str, str]
"""A child's event: ``("stage", time, name, "")`` or ``("log", time, level, message)``."""
_CRASH_SIGNALS = {signal.SIGSEGV, signal.SIGBUS, signal.SIGABRT, signal.SIGILL, signal.SIGFPE}
# an absolute path in a message: /a/b/c -> c (job errors never show server paths)
# a path's part: no quotes, brackets, commas, colons or spaces; an @ only inside it (a
# scratch folder is named ``<job>.<pid>@<host>...``), not one closing a USD @asset path@
_PART = r"(?:[^\s@'\"(),:/]|@(?=[^\s@'\"(),:/]))"
_ABS_PATH = re.compile(rf"(?:(?<=[\s@'\"(=:])|^)/(?:{_PART}+/)*({_PART}*)")


def scrub_paths(text: str) -> str:
    """``text`` with every absolute file path replaced by its last part."""
    return _ABS_PATH.sub(lambda m: m.group(1) or ".", text)


@dataclass(frozen=True)
class Limits:
    """Resource limits of a job's child process; None: unlimited."""

    memory_bytes: int | None = None
    cpu_s: int | None = None


@dataclass(frozen=True)
class ChildEnd:
    """How a child ended. ``status``: ok, bad (permanent), error (retry), crash (permanent),
    canceled, lost (lease lost: record nothing)."""

    status: str
    message: str = ""
    files: dict[str, str] | None = None
    result: dict[str, Any] | None = None


_context: BaseContext | None = None


def context() -> BaseContext:
    """The fork-server context (children start from a clean, preloaded process)."""
    global _context
    if _context is None:
        _context = mp.get_context("forkserver")
    return _context


def preload(modules: list[str] | None = None) -> None:
    """Import ``modules`` once in the fork server (a worker calls this before its first job)."""
    from multiprocessing import forkserver

    ctx = context()
    ctx.set_forkserver_preload(modules or PRELOAD)
    # started and warmed now, not inside the first job's claim: its start (seconds of
    # imports) would come before that job's first heartbeat
    forkserver.ensure_running()
    warm = ctx.Process(target=_noop)  # type: ignore[attr-defined]
    warm.start()
    warm.join()


def _noop() -> None:
    pass


def _die_with_parent() -> None:
    with contextlib.suppress(OSError, AttributeError):
        import ctypes

        ctypes.CDLL("libc.so.6").prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG


def _set_limits(limits: Limits) -> None:
    if limits.memory_bytes is not None:
        resource.setrlimit(resource.RLIMIT_AS, (limits.memory_bytes, limits.memory_bytes))
    if limits.cpu_s is not None:
        # soft: SIGXCPU (the parent reports it); hard a little later: SIGKILL
        resource.setrlimit(resource.RLIMIT_CPU, (limits.cpu_s, limits.cpu_s + 5))


class _Events:
    """The child's side of the event pipe: at most :data:`CHILD_EVENTS`, then one saying so."""

    def __init__(self, conn: Connection | None) -> None:
        self.conn, self.sent, self.stage = conn, 0, ""

    def send(self, kind: str, a: str, b: str = "") -> None:
        if self.conn is None or self.sent > CHILD_EVENTS:
            return
        self.sent += 1
        if self.sent > CHILD_EVENTS:
            kind, a, b = (
                "log",
                "warning",
                f"further events of this attempt dropped ({CHILD_EVENTS} sent)",
            )
        with contextlib.suppress(OSError, ValueError):
            self.conn.send((kind, time.time(), a, b))


class _ToParent(logging.Handler):
    """The child's warnings and errors (its libraries' included) as events."""

    def __init__(self, events: _Events) -> None:
        super().__init__(logging.WARNING)
        self.events = events

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
        except Exception:
            text = str(record.msg)
        level = "error" if record.levelno >= logging.ERROR else "warning"
        self.events.send("log", level, scrub_paths(f"{record.name}: {text}"))


def _child_main(
    target: Callable[..., Any],
    args: tuple[Any, ...],
    limits: Limits,
    progress: Any,
    stage: Any,
    conn: Connection,
    events_conn: Connection | None = None,
) -> None:
    """Runs in the child: limits, then ``target(report, *args)``; one message to the parent
    (and events on ``events_conn``)."""
    _die_with_parent()
    _set_limits(limits)
    events = _Events(events_conn)
    if events_conn is not None:
        logging.captureWarnings(True)  # warnings.warn -> logging "py.warnings"
        logging.getLogger().addHandler(_ToParent(events))

    def report(name: str, fraction: float) -> None:
        progress.value = float(fraction)
        stage.value = name.encode("utf-8", "replace")[: STAGE_BYTES - 1]
        if name != events.stage:  # a stage change, with its time: the log's timings
            events.stage = name
            events.send("stage", name)

    try:
        files, result = target(report, *args)
        msg: tuple[Any, ...] = ("ok", files, result)
    except Exception as exc:
        msg = failure(exc, limits)
    if events_conn is not None:
        events_conn.close()
    conn.send(msg)
    conn.close()


def failure(exc: Exception, limits: Limits) -> tuple[str, str]:
    """The child's message of a failed attempt: ``bad`` (permanent) or ``error`` (retried)."""
    if isinstance(exc, MemoryError):  # first: importing takes memory
        mib = (limits.memory_bytes or 0) >> 20
        return ("bad", f"the job ran out of memory (its limit is {mib} MiB)")
    from farm import volume
    from forest.errors import ForestError

    if volume.is_full(exc):  # before ForestError: a failed write is an OutputError too
        return ("bad", volume.FULL)  # a retry finds no more room
    if isinstance(exc, ForestError):  # bad input: retrying cannot help
        return ("bad", scrub_paths(str(exc)))
    return ("error", scrub_paths(f"{type(exc).__name__}: {exc}"))


def crash_message(exitcode: int, stage: str, limits: Limits) -> str:
    """What a child that died of a signal (``exitcode`` = -signal) tells the job's owner."""
    sig = -exitcode
    name = signal.Signals(sig).name if sig in signal.Signals.__members__.values() else str(sig)
    if sig == signal.SIGXCPU:
        return f"the job used up its CPU time limit ({limits.cpu_s} s)"
    if sig == signal.SIGKILL:
        return "the job's process was killed (SIGKILL: most likely out of memory)"
    if stage in ("check", "read"):
        return f"the scene could not be read: the USD reader crashed ({name})"
    return f"the job's process crashed ({name}) during {stage or 'start'}"


def supervise(
    target: Callable[..., Any],
    args: tuple[Any, ...],
    limits: Limits,
    heartbeat: Callable[[float, str], bool | None],
    heartbeat_s: float,
    on_event: Callable[[Event], None] | None = None,
) -> ChildEnd:
    """Run ``target(report, *args) -> (files, result)`` in a child; call
    ``heartbeat(progress, stage)`` every ``heartbeat_s`` (True: cancel asked, None: lease lost)
    until it ends, and ``on_event`` with each of the child's events as it comes. The child is
    killed on cancel or a lost lease."""
    ctx = context()
    progress = ctx.Value("d", 0.0, lock=False)
    stage = ctx.Array("c", STAGE_BYTES, lock=False)
    recv, send = ctx.Pipe(duplex=False)
    events_recv, events_send = ctx.Pipe(duplex=False) if on_event else (None, None)
    proc = ctx.Process(  # type: ignore[attr-defined]
        target=_child_main,
        args=(target, args, limits, progress, stage, send, events_send),
        daemon=True,
    )
    proc.start()
    send.close()
    if events_send is not None:
        events_send.close()
    watched: list[Any] = [recv, proc.sentinel] + ([events_recv] if events_recv else [])
    msg: tuple[Any, ...] | None = None
    end: ChildEnd | None = None
    next_beat = time.monotonic()  # at once: starting the child may have taken a while
    try:
        while True:
            ready = wait(watched, timeout=max(0.0, next_beat - time.monotonic()))
            # the child closed its end (it is ending): no more waiting on it
            if events_recv in ready and not _drain(events_recv, on_event):
                watched.remove(events_recv)
            if recv in ready:
                with contextlib.suppress(EOFError, OSError):
                    msg = recv.recv()
                break
            if proc.sentinel in ready:
                break
            if time.monotonic() >= next_beat:
                next_beat = time.monotonic() + heartbeat_s
                flag = heartbeat(float(progress.value), stage.value.decode("utf-8", "replace"))
                if flag is None:
                    end = ChildEnd("lost")
                    break
                if flag:
                    end = ChildEnd("canceled", "canceled on request")
                    break
    finally:
        if end is not None and proc.is_alive():  # canceled or lost: stop it now
            proc.kill()
        proc.join(10)
        if proc.is_alive():
            proc.kill()
            proc.join(5)
        recv.close()
        if events_recv is not None:
            _drain(events_recv, on_event, block=False)  # what came after the last wait
            events_recv.close()
    if end is not None:
        return end
    last_stage = stage.value.decode("utf-8", "replace")
    if msg is not None:
        if msg[0] == "ok":
            return ChildEnd("ok", files=msg[1], result=msg[2])
        return ChildEnd(msg[0], msg[1])
    code = proc.exitcode if proc.exitcode is not None else 0
    if code < 0:
        return ChildEnd("crash", crash_message(code, last_stage, limits))
    return ChildEnd("error", f"the job's process exited with status {code} during {last_stage}")


def _drain(conn: Connection, on_event: Callable[[Event], None] | None, block: bool = True) -> bool:
    """Read the events waiting on ``conn`` (at least one when ``block``); False once the
    child closed its end."""
    try:
        while block or conn.poll():
            block = False
            event = conn.recv()
            if on_event is not None:
                on_event(event)
    except (EOFError, OSError):
        return False
    return True


def job_limits(memory_mb: int, cpu_s: int) -> Limits:
    """Settings -> limits (0: unlimited)."""
    return Limits(memory_mb << 20 if memory_mb > 0 else None, cpu_s if cpu_s > 0 else None)


def under(root: Path, path: Path) -> bool:
    """``path`` lies inside ``root`` (both resolved)."""
    try:
        path.resolve().relative_to(root.resolve())
    except ValueError:
        return False
    return True
