"""The task kinds a worker runs: job kind -> the code that runs it (``forest worker --list``).

Each kind's module imports the library inside its function, so the registry is cheap to
import; the kinds' queues are the farm's (:data:`farm.dispatch.KIND_QUEUES`)."""

from __future__ import annotations

from worker.jobs.chunk import run_render_chunk
from worker.jobs.context import TaskKind
from worker.jobs.forest import run_forest
from worker.jobs.render import run_render
from worker.jobs.tile import run_tile
from worker.jobs.tileset import run_tileset
from worker.jobs.tree import run_tree

KINDS: dict[str, TaskKind] = {
    "forest": run_forest,
    "render": run_render,
    "forest_tile": run_tile,
    "render_chunk": run_render_chunk,
    "tree": run_tree,
    "tileset": run_tileset,
}
