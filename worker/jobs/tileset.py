"""The ``tileset`` job kind (``POST /v1/tilesets``): a bark tile set quilted from uploaded
photographs; and how the jobs that name one in ``tiles`` get its files."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from forest.errors import ForestError
from worker.jobs.context import JobContext, Outcome

if TYPE_CHECKING:
    from schemas.tileset import TileSetManifest

TILES_FOLDER = "tiles"  # in a job's scratch folder, beside the scene that names it


def run_tileset(ctx: JobContext) -> Outcome:
    """A tile-set job (``params``: :class:`schemas.jobs.TileSetJob`): read its photographs
    (the job's own input files), quilt the tiles, and publish the set's files as artifacts."""
    from forest.bark.tileset import default_classes, make_tileset
    from schemas.jobs import TileSetJob
    from schemas.tileset import MANIFEST_FILE

    job = TileSetJob.model_validate(ctx.params)
    examples = []
    for k, name in enumerate(job.examples):
        path = ctx.artifacts.path(ctx.job_id, name)
        if path is None:
            raise ForestError("the photograph is gone from its store", path=f"examples.{k}")
        examples.append(path)
    folder = ctx.scratch / TILES_FOLDER
    classes = default_classes(job.per_class, job.per_class)

    def note(stage: str, done: int, total: int) -> None:
        ctx.report(stage, 0.05 + 0.9 * done / max(total, 1))

    ctx.report("quilt", 0.05)
    ts = make_tileset(examples, folder, classes, job.size, job.seed, progress=note)
    files = {p.name: p for p in sorted(folder.iterdir()) if p.is_file()}
    result = {
        "tiles": len(ts.tiles),
        "tile_size": job.size,
        "classes": {c.name: c.count for c in ts.manifest.classes},
        "repeated": ts.reused,  # tiles that partly repeat others (too few photographs)
        "manifest": MANIFEST_FILE,
    }
    return Outcome(files, result)


def fetch_tileset(ctx: JobContext, job_id: str) -> Path:
    """The tile set of tile-set job ``job_id`` copied into this job's scratch folder
    (``tiles/``, so a scene beside it names it by that relative path): its manifest and what
    a reader of the set opens, its texture array and per-slice pictures (the edge and corner
    patterns only make new tiles). The service checked the job is the caller's tenant's and
    completed before this job ran."""
    from forest.bark.tiles import manifest_for
    from schemas.tileset import MANIFEST_FILE

    folder = ctx.scratch / TILES_FOLDER
    folder.mkdir(exist_ok=True)

    def copy(name: str) -> None:
        src = ctx.artifacts.path(job_id, name)
        if src is None:
            raise ForestError(f"the tile set's {name} is gone from its store", path="tiles")
        shutil.copyfile(src, folder / name)

    copy(MANIFEST_FILE)
    files = manifest_for(folder).files  # a set the tileset job made always names them
    if files is not None:
        for name in [files.array, *files.slices] if files.array else files.slices:
            copy(name)
    return folder


def request_tiles(
    ctx: JobContext, job_id: str | None, scene: str
) -> tuple[TileSetManifest | None, str | None]:
    """A tree or forest request's ``tiles``: the tile set's manifest (its tile indices) and,
    where the scene file carries pictures (``.usdz``, ``.glb``), the folder beside it that
    its writer bakes them from; (None, None) for the species' shipped set."""
    from forest.bark.tiles import manifest_for
    from forest.export import single_file

    if job_id is None:
        return None, None
    folder = fetch_tileset(ctx, job_id)
    return manifest_for(folder), TILES_FOLDER if single_file(scene) else None
