"""The write floor: how long this machine takes to write a number of bytes into a folder with
plain file writes, no fsync (the page cache, as a scene's Save sees it). A scene writer's time
is reported against it, measured in the same run and the same folder."""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

CHUNK = 8 << 20  # bytes per write call: large enough that the call's own cost vanishes


def page_cache_write_seconds(folder: Path, nbytes: int, repeat: int = 3) -> float:
    """Best of ``repeat`` timings of writing ``nbytes`` to a new file in ``folder`` (removed
    after each run). Non-zero bytes, so no filesystem can store them as holes."""
    block = memoryview(bytes(range(256)) * (CHUNK // 256))
    best = float("inf")
    for _ in range(repeat):
        fd, name = tempfile.mkstemp(prefix=".floor.", dir=folder)
        try:
            t0 = time.perf_counter()
            left = nbytes
            while left > 0:
                left -= os.write(fd, block[: min(left, CHUNK)])
            os.close(fd)
            fd = -1
            best = min(best, time.perf_counter() - t0)
        finally:
            if fd >= 0:
                os.close(fd)
            os.unlink(name)
    return best


@contextmanager
def timed_saves() -> Iterator[list[float]]:
    """Within the block, the seconds of every scene Save (``forest.usd.files.finish``: the
    layer serialised to its file and moved into place), one entry per scene written, so a
    writer's time splits into authoring and saving without a hook in the writer."""
    from forest.usd import files, scene, tiled

    seconds: list[float] = []
    real = files.finish

    def finish(*args: Any, **kwargs: Any) -> None:
        t0 = time.perf_counter()
        try:
            real(*args, **kwargs)
        finally:
            seconds.append(time.perf_counter() - t0)

    modules = (files, scene, tiled)
    for m in modules:
        m.finish = finish  # type: ignore[attr-defined]
    try:
        yield seconds
    finally:
        for m in modules:
            m.finish = real  # type: ignore[attr-defined]
