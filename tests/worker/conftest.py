"""GL fixtures for the render worker's tests: one EGL context per test session (made by
``forest.gl.context``, the one place that creates contexts), reset around each test, with
``ctx.error == "GL_NO_ERROR"`` asserted after each. Features are skipped by capability
(``ctx.version_code``), never by guessing the machine. Without any EGL context the GL tests
skip, unless ``FOREST_REQUIRE_GL=1`` (CI sets it) turns that into a failure.

GL calls go to the thread's current context, not to the moderngl context they are made on.
Creating a context makes it current, and releasing it leaves the released one current (EGL
frees it only once it is unbound) or none: after ``forest render``, ``forest gallery`` or
a test's own context ran in this process, the session's calls went to a dead context (its
buffers read back the other context's data) or to none ("cannot create buffer", limits read
as 0). So every test that uses the session makes it current first and again before the
checks after it, and a marker buffer made at the start proves the calls reach it."""

from __future__ import annotations

import gc
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from forest.growth.generate import ForestOptions, generate_forest
from forest.usd.read import SceneArrays, read_scene
from forest.usd.scene import write_scene
from schemas.grammar import Grammar

# Every piece type, with bends, spreads and thinner side branches, so rims meet in all the
# ways a grammar can make them meet.
ALL_PIECES = {
    "name": "all-pieces",
    "axiom": "A",
    "max_depth": 4,
    "trunk_radius": 0.2,
    # the four branching pieces with open tips, as the paper draws them (caps and flares are
    # drawn by tests/worker/test_pieces_gl.py)
    "close_tips": False,
    "rules": {
        "A": [
            {
                "piece": "T",
                "successors": [{"symbol": "B"}, {"symbol": "C", "radius": [0.6, 0.7]}],
                "pose": {"bend": [5, 10], "spread": [10, 20]},
            }
        ],
        "B": [
            {
                "piece": "Psi",
                "successors": [
                    {"symbol": "C"},
                    {"symbol": "C", "radius": [0.7, 0.8]},
                    {"symbol": "C", "radius": [0.7, 0.8]},
                ],
                "pose": {"spread": [10, 20]},
            }
        ],
        "C": [
            {
                "piece": "Y",
                "max_depth": 3,
                "successors": [{"symbol": "D"}, {"symbol": "D", "length": [0.7, 0.9]}],
                "pose": {"bend": [0, 10], "spread": [5, 20]},
            },
            {"piece": "I", "successors": [None], "pose": {"bend": [5, 15]}},
        ],
        "D": [{"piece": "I", "successors": [None], "pose": {"bend": [5, 15]}}],
    },
}


SESSION_MARKER = b"forest gl session marker"


def make_current(session: Any) -> None:
    """Make the session's context current on this thread, check that its objects answer, and
    collect what tests dropped now (gc_mode "auto" releases it in the context that is
    current when Python collects it)."""
    session.__enter__()  # eglMakeCurrent; never __exit__, which would leave no context
    try:
        seen = session.extra["marker"].read()
    except Exception as exc:  # moderngl.Error: the name is not a buffer in the current context
        seen = repr(exc).encode()
    assert seen == SESSION_MARKER, f"GL calls do not reach the session's context: {seen!r}"
    gc.collect()


@pytest.fixture(scope="session")
def gl_session() -> Iterator[Any]:
    from forest.gl.context import GLUnavailableError, create_context

    try:
        # the renderer's version first: NVIDIA's EGL gives exactly the version asked for
        # (4.3 for 430, 3.3 for 330) where Mesa gives its highest; then any version, so that
        # each test checks and skips by the capability it needs
        try:
            ctx = create_context()
        except GLUnavailableError:
            ctx = create_context(require=330)
    except GLUnavailableError as exc:
        if os.environ.get("FOREST_REQUIRE_GL") == "1":
            raise
        pytest.skip(f"no EGL context: {exc}")
    ctx.gc_mode = "auto"  # objects a test drops are released when Python collects them
    ctx.extra = {"marker": ctx.buffer(SESSION_MARKER)}
    yield ctx
    # every test that used it checked the marker before and after; at the session's end only
    # release it (a later non-GL test may have made and dropped contexts of its own)
    ctx.__enter__()
    ctx.release()


@pytest.fixture(autouse=True)
def _gl_session_current(request: pytest.FixtureRequest) -> Iterator[None]:
    """Every test that uses the session context (directly or through ``ctx``/``gl43``)
    starts and ends with it current."""
    if "gl_session" not in request.fixturenames:
        yield
        return
    session = request.getfixturevalue("gl_session")
    make_current(session)
    yield
    make_current(session)


@pytest.fixture
def ctx(gl_session: Any) -> Iterator[Any]:
    """The session's context, current, reset before and checked after the test."""
    import moderngl

    make_current(gl_session)
    gl_session.clear_errors()
    gl_session.enable_only(moderngl.NOTHING)
    yield gl_session
    make_current(gl_session)  # the test may have made (and released) a context of its own
    gl_session.finish()
    assert gl_session.error == "GL_NO_ERROR"
    gl_session.enable_only(moderngl.NOTHING)


@pytest.fixture
def gl43(ctx: Any) -> Any:
    """The context, for tests of the tessellation pipeline (GL 4.3: tessellation + SSBOs)."""
    if ctx.version_code < 430:
        pytest.skip(f"needs OpenGL 4.3, the context has {ctx.version_code}")
    return ctx


@pytest.fixture(scope="session")
def mixed_scene_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two posed trees of every piece type with 3 wind frames, as a USD file."""
    forest = generate_forest(
        Grammar.model_validate(ALL_PIECES), 7, ForestOptions(trees=2, frames=3, area=(6.0, 6.0))
    )
    return write_scene(forest, tmp_path_factory.mktemp("worker") / "mixed.usda")


@pytest.fixture(scope="session")
def mixed_scene(mixed_scene_path: Path) -> SceneArrays:
    return read_scene(mixed_scene_path)
