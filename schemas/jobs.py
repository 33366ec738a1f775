"""Wire models of the HTTP service: tree, forest and render requests, job records, presets.

Static bounds live here (they are part of the published schema); the service's configurable
caps (``service/settings.py``) are checked on top and answered with the same 422 shape.
"""

from __future__ import annotations

import math
import re
from datetime import datetime
from enum import StrEnum
from typing import Annotated, Any, Literal

from pydantic import (
    Discriminator,
    Field,
    GetCoreSchemaHandler,
    Tag,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import core_schema

from schemas.base import FieldValueError, StrictModel
from schemas.grammar import Grammar
from schemas.recipe import RECIPE_NAME_PATTERN, Recipe
from schemas.tiles import MAX_TILED_TREES, MAX_TILES, tile_grid


class JobState(StrEnum):
    """A job's state. Members equal their strings: the job table and the wire hold the strings."""

    QUEUED = "queued"
    ACTIVE = "active"
    COMPLETED = "completed"
    FAILED = "failed"
    CANCELED = "canceled"

    @classmethod
    def __get_pydantic_core_schema__(
        cls, source: Any, handler: GetCoreSchemaHandler
    ) -> core_schema.CoreSchema:
        # published as an inline string enum (as a Literal is), not a $defs entry of its own
        literal = core_schema.literal_schema([state.value for state in cls])
        return core_schema.no_info_after_validator_function(cls, literal)


JobKind = Literal["forest", "render", "forest_tile", "render_chunk", "tree", "tileset"]
"""``forest_tile``: one tile of a tiled forest job (``tile_size``), made by that job;
``render_chunk``: some frames of a render job of more than ``FOREST_RENDER_CHUNK_FRAMES``
frames, made by that job; ``tree``:
the job of a ``POST /v1/trees`` (the tree is made by a worker, not by the API process)."""
MAX_UNTILED_TREES = 200_000
UsdFormat = Literal["usda", "usdc", "usdz"]
SceneFormat = Literal["usda", "usdc", "usdz", "glb"]
"""USD, or glTF 2.0 binary (skinned trees, wind animation, textures inside) for game engines."""

Seed = Annotated[int, Field(ge=0, le=2**63 - 1)]
JOB_ID_PATTERN = r"^[0-9A-Za-z_-]{1,64}$"
"""What a job id can be (the store makes 32 hex digits): anything else is no such job, found
without asking the store (PostgreSQL refuses a NUL in text: that was answered 503)."""
BarkSet = Literal[
    "default", "oak", "almond", "birch", "pine", "spruce", "willow", "poplar", "hazel"
]
"""The shipped bark tile sets (:data:`forest.bark.tilesets.SETS`)."""
JobId = Annotated[str, Field(min_length=1, max_length=64, pattern=JOB_ID_PATTERN)]
Priority = Annotated[int, Field(ge=0, le=9)]
"""0-9: among one tenant's waiting work, higher first (tenants take turns whatever it says)."""
WebhookUrl = Annotated[str, Field(min_length=8, max_length=2048, pattern=r"^https?://")]
"""Called (POST, HMAC-signed) once the job has ended; its host must be one the server allows
(``FOREST_WEBHOOK_HOSTS``)."""


def _bad_text(text: str) -> str | None:
    """Why ``text`` cannot be stored or answered: a NUL (PostgreSQL's text refuses it) or a
    lone surrogate (JSON's ``"\\ud800"``, which no UTF-8 encoder writes); None when fine."""
    if "\x00" in text:
        return "must not contain NUL (U+0000)"
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return "must be valid Unicode (no lone surrogate code points)"
    return None


def unfit(value: Any, path: str = "") -> tuple[str, str] | None:
    """The path (``grammar.rules.A[0].weight``; ``""``: the body) and fault of the first value
    in a JSON value that no job can hold: a NaN or infinite float (JSON parsers accept ``NaN``,
    ``Infinity`` and ``1e400``), or a string (a key too) with a NUL or a lone surrogate; or
    None."""
    if isinstance(value, float):
        return None if math.isfinite(value) else (path, NON_FINITE)
    if isinstance(value, str):
        bad = _bad_text(value)
        return None if bad is None else (path, bad)
    if isinstance(value, dict):
        for k, v in value.items():
            where = f"{path}.{k}" if path else str(k)
            bad = _bad_text(str(k))
            if bad is not None:
                return path, f"a key {bad}"
            found = unfit(v, where)
            if found is not None:
                return found
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            found = unfit(v, f"{path}[{i}]")
            if found is not None:
                return found
    return None


NON_FINITE = "must be a finite number (not NaN or infinite)"


class FiniteModel(StrictModel):
    """A request: every float in it, however deep, is finite, and every string one that a job
    store and a UTF-8 answer can hold (checked before field parsing, so neither a NaN in a field
    without bounds nor a NUL in a name can reach the library or the store)."""

    @model_validator(mode="before")
    @classmethod
    def _finite(cls, data: Any) -> Any:
        found = unfit(data)
        if found is not None:
            raise FieldValueError(*found)
        return data


def _recipe_tag(value: Any) -> str:
    return "name" if isinstance(value, str) else "object"


RecipeRef = Annotated[
    Annotated[Annotated[str, Field(pattern=RECIPE_NAME_PATTERN)], Tag("name")]
    | Annotated[Recipe, Tag("object")],
    Discriminator(_recipe_tag),
]
"""A built-in recipe's name (``GET /v1/recipes``) or an inline recipe object (its images as
``data:`` URIs)."""


def _loc_path(loc: tuple[int | str, ...]) -> str:
    """``("layers", 0, "share")`` -> ``layers[0].share``."""
    out = ""
    for p in loc:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out


def recipe_value(value: Any) -> Any:
    """A request's ``recipe`` read once, its first fault a :class:`FieldValueError` at its
    path under ``recipe`` (``recipe.layers[0].share``), not pydantic's union branches."""
    if value is None or isinstance(value, Recipe):
        return value
    if isinstance(value, str):
        if not re.fullmatch(RECIPE_NAME_PATTERN, value):
            raise FieldValueError("recipe", "not a recipe name (GET /v1/recipes lists them)")
        return value
    if not isinstance(value, dict):
        raise FieldValueError("recipe", "give a built-in recipe's name or a recipe object")
    try:
        return Recipe.model_validate(value)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        found = (err.get("ctx") or {}).get("error")
        path, reason = _loc_path(tuple(err["loc"])), err["msg"].removeprefix("Value error, ")
        if isinstance(found, FieldValueError):
            inner = found.path.split(".") if found.path else []
            parts: list[int | str] = [int(p) if p.isdigit() else p for p in inner]
            path = _loc_path((*err["loc"], *parts))
            reason = found.reason
        more = exc.error_count() - 1
        if more:
            reason += f" (and {more} more error{'s' if more > 1 else ''})"
        raise FieldValueError(f"recipe.{path}" if path else "recipe", reason) from None


class TreeRequest(FiniteModel):
    """One tree from a preset name or a grammar object, answered synchronously as USD or
    glTF (``format``); or, from a ``recipe``, a small mixed stand as one USD file."""

    preset: Annotated[str, Field(min_length=1, max_length=64)] | None = None
    """Name of a shipped grammar (``GET /v1/presets``); give this, ``grammar`` or ``recipe``."""
    grammar: Grammar | None = None
    recipe: RecipeRef | None = None
    """A mixed forest: a built-in recipe's name (``GET /v1/recipes``) or a recipe object
    (``schemas/json/recipe.schema.json``; density maps and heightfields as ``data:`` URIs).
    A forest job writes a USD root layer and one file per layer; ``POST /v1/trees`` answers
    the stand as one file (``usda``, ``usdc``, or a textured ``usdz``)."""
    trees: Annotated[int, Field(ge=1, le=MAX_TILED_TREES)] | None = None
    """With a recipe only: the stand's trees (shares of the layers; default one per layer)."""
    area: (
        tuple[
            Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)],
            Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)],
        ]
        | None
    ) = None
    """With a recipe only: the stand's width and depth, metres (default 20 x 20)."""
    seed: Seed = 0
    format: SceneFormat = "usdc"
    frames: Annotated[int, Field(ge=0, le=10_000)] = 0
    """Wind frames to sample (0: a still, posed tree)."""
    fps: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] = 24.0
    wind_deg: Annotated[float, Field(ge=0, le=90, allow_inf_nan=False)] = 4.0
    segments: Annotated[int, Field(ge=1, le=8)] = 1
    webhook: WebhookUrl | None = None
    """A URL called (POST, JSON, HMAC-signed) once the job has ended; its host must be one of
    the server's ``FOREST_WEBHOOK_HOSTS``."""
    season: Literal["summer", "autumn"] = "summer"
    """The leaves' palette: the species' summer colours, or its autumn ones (as the CLI's
    ``--season``)."""
    bark: BarkSet | None = None
    """A shipped bark tile set in place of the grammar's own (as the CLI's ``--bark``): the
    scene's bark pictures, and the renderer's. Not with a recipe (its layers keep theirs)."""
    tiles: JobId | None = None
    """A bark tile set of your own: the id of a ``POST /v1/tilesets`` job (as the CLI's
    ``--tiles``). Its tiles are the bark pictures of a ``.usdz`` or ``.glb`` and of renders of
    the scene, and the tile indices of every format follow its manifest. A forest waits for
    the tile set's job; a tree needs it completed. Not with ``bark`` or a recipe."""
    skinned: bool | None = None
    """USD only: bake each tree as a skinned mesh (the default representation where it is
    written); unset: skinned for small scenes (up to 64 trees and 20,000 pieces), posed above
    that, always in a .usdz (a glb is always skinned)."""
    priority: Priority = 5
    """0-9: among the tenant's own waiting jobs (and a tiled forest's tiles) higher goes first;
    every tenant still takes its turn (``docs/jobs.md``)."""

    _recipe = field_validator("recipe", mode="before")(recipe_value)

    @model_validator(mode="after")
    def _source(self) -> TreeRequest:
        given = [n for n in ("preset", "grammar", "recipe") if getattr(self, n) is not None]
        if self.recipe is not None and len(given) > 1:
            raise FieldValueError("recipe", "give exactly one of preset, grammar or recipe")
        formats = self._recipe_formats()
        if self.recipe is not None and self.format not in formats:
            raise FieldValueError("format", f"a recipe's stand is written as {', '.join(formats)}")
        self._stand_only()
        if self.recipe is not None and self.bark is not None:
            raise FieldValueError("bark", "a recipe's layers keep their species' bark")
        if self.tiles is not None and self.recipe is not None:
            raise FieldValueError("tiles", "a recipe's layers keep their species' bark")
        if self.tiles is not None and self.bark is not None:
            raise FieldValueError("tiles", "give bark (a shipped set) or tiles (yours), not both")
        return self

    def _recipe_formats(self) -> tuple[str, ...]:
        return ("usda", "usdc", "usdz")  # one file: flattened, or packaged with its pictures

    def _stand_only(self) -> None:
        for name in ("trees", "area"):
            if getattr(self, name) is not None and self.recipe is None:
                raise FieldValueError(name, "one tree: trees and area go with a recipe only")


class ForestRequest(TreeRequest):
    """A forest job: ``trees`` trees scattered over ``area`` (metres)."""

    after: Annotated[list[JobId], Field(max_length=16)] = []
    """Jobs to wait for (:mod:`farm.graph`): the forest runs once all have completed; if one
    fails or is canceled, so is it, saying which."""
    render: RenderSettings | None = None
    """Also a render job of this forest, made now and run once the forest has completed: the
    forest job's ``then`` names it (one request for a forest and its picture)."""

    trees: Annotated[int, Field(ge=1, le=MAX_TILED_TREES)] = 1
    """At most 200,000 in one scene; up to 10 million with ``tile_size``."""
    area: tuple[
        Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)],
        Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)],
    ] = (20.0, 20.0)
    placement: Literal["poisson", "grid"] = "poisson"
    tile_size: Annotated[float, Field(ge=1, le=1e6, allow_inf_nan=False)] | None = None
    """Metres: cut the area into square tiles, each generated by its own task; the scene is
    a root layer (usda/usdc) holding every tile (``scene_tile_<i>_<j>.usdc``) as a payload,
    or with a ``recipe`` every layer's tile (``scene_tile_<i>_<j>_<layer>.usdc``) as a
    reference. Placement is a seamless jittered grid (``placement`` is not used), or the
    recipe's, the same tile by tile as untiled."""

    def _stand_only(self) -> None:
        pass  # a forest has trees and an area, from any source

    def _recipe_formats(self) -> tuple[str, ...]:
        return ("usda", "usdc")  # a root layer beside its layers' files

    @model_validator(mode="after")
    def _tiling(self) -> ForestRequest:
        if self.tile_size is None:
            if self.trees > MAX_UNTILED_TREES:
                raise ValueError(
                    f"trees: at most {MAX_UNTILED_TREES} in one scene; give tile_size for more"
                )
            return self
        if self.format not in ("usda", "usdc"):
            raise ValueError("format: a tiled forest (tile_size) is a usda or usdc root layer")
        if self.tiles is not None:
            raise ValueError("tiles: a tiled forest's tiles keep their species' bark")
        nx, nz = tile_grid(self.area, self.tile_size)
        if nx * nz > MAX_TILES:
            raise ValueError(f"tile_size: {nx} x {nz} tiles exceed the cap of {MAX_TILES}")
        return self


class RenderSettings(FiniteModel):
    """How a render draws (``POST /v1/renders`` without the forest job it draws; a forest
    request's ``render``)."""

    width: Annotated[int, Field(ge=1, le=8192)] = 640
    height: Annotated[int, Field(ge=1, le=8192)] = 480
    tess_max: Annotated[float, Field(ge=1, le=64, allow_inf_nan=False)] = 8.0
    frame: Annotated[int, Field(ge=0, le=10_000)] = 0
    frames: Annotated[int, Field(ge=1, le=10_000)] = 1
    """Measured frames (wind samples from ``frame`` on); the preview is the first. A still
    scene (no wind frames) draws one, and the job's ``warnings`` and ``frames`` say so."""
    webhook: WebhookUrl | None = None
    """A URL called (POST, JSON, HMAC-signed) once the job has ended; its host must be one of
    the server's ``FOREST_WEBHOOK_HOSTS``."""
    view: Literal["overview", "side", "eye"] = "overview"
    """Named camera (worker.render.camera.CameraSpec): the whole forest from 35 degrees azimuth and
    18 up, the same horizontally, or eyes 1.7 m above the ground at ``distance``."""
    eye: tuple[float, float, float] | None = None
    """Camera position in metres (Y up); with ``target``, it overrides ``view``."""
    target: tuple[float, float, float] | None = None
    fov: Annotated[float, Field(ge=1, le=170, allow_inf_nan=False)] = 40.0
    """Vertical field of view, degrees."""
    distance: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    """Eye view: metres from the forest's centre (default: the least that shows it all)."""
    tree: Annotated[int, Field(ge=0, le=10_000_000)] | None = None
    """The view frames this tree of the scene alone (a close-up), not the forest."""
    pool: Literal["any", "gpu", "cpu"] = "any"
    """Which render workers may take it: ``gpu`` (an NVIDIA EGL worker), ``cpu`` (Mesa's
    llvmpipe: slower, runs anywhere) or ``any`` (whichever is free). Same pictures either way,
    within the golden-image tolerance."""
    staged: bool = True
    """Ground, sky, sun shadows, 4x MSAA and a filmic tone map; false: the bare mode (the
    paper's measurement set-up: none of these)."""
    lod_pixels: Annotated[float, Field(ge=0, le=64, allow_inf_nan=False)] | None = 0.5
    """Pieces thinner on screen than this many pixels are not drawn (a distant tree's
    twigs, under its leaves); 0 draws every piece in view, null also those out of view
    (whole instances are tested on the GPU before the draws: worker.render.instance_cull)."""
    clip: Literal["mp4", "webm", "gif"] | None = None
    """Also encode the frames as ``clip.<format>`` (an artifact with its media type); with
    ``frames`` 1 the clip is the scene's whole wind loop, which loops seamlessly."""
    orbit: bool = False
    """The camera turns once about its target over the clip (needs ``clip``)."""
    priority: Priority = 5
    """0-9, as a tree's or forest's: among the tenant's own waiting jobs, higher first."""

    @model_validator(mode="after")
    def _camera_and_clip(self) -> RenderSettings:
        if (self.eye is None) != (self.target is None):
            raise ValueError(
                f"{'eye' if self.eye is None else 'target'}: give eye and target together"
            )
        if self.eye is not None and self.eye == self.target:
            raise ValueError("target: must differ from the eye")
        if self.orbit and self.clip is None:
            raise ValueError("orbit: an orbit is a clip: give clip too")
        if self.clip in ("mp4", "webm") and (self.width % 2 or self.height % 2):
            name = "width" if self.width % 2 else "height"
            raise ValueError(f"{name}: {self.clip} needs an even width and height")
        return self


After = Annotated[list[JobId], Field(max_length=16)]
"""Jobs a job waits for (:mod:`farm.graph`): it runs once all have completed; if one fails
or is canceled, so is it, saying which."""


class RenderRequest(RenderSettings):
    """A render job of a forest job's scene (the camera frames the forest itself). A forest
    job still queued or running is waited for: the render runs once it has completed."""

    forest_job: JobId
    """Id of the forest job whose scene is rendered."""
    after: After = []
    """Other jobs to wait for (the forest job is always waited for)."""


class TileJob(ForestRequest):
    """A ``forest_tile`` job's parameters: its forest job's request, that job's id and the
    tile's grid cell ``(i, j)``."""

    parent: str
    tile: tuple[int, int]


class RenderJob(RenderRequest):
    """A render job's parameters: the request plus the scene's artifact name. An uploaded
    scene's job has no forest job (the scene is its own artifact), carries the upload's
    digest and takes only the upload form's settings (the rest keep their defaults)."""

    forest_job: Annotated[str, Field(min_length=1, max_length=64)] | None  # type: ignore[assignment]
    scene: str
    scene_sha256: str | None = None
    tiles: str | None = None
    """The forest's own tile set (its ``tiles``: a tile-set job's id), which the render draws
    its bark from; None: the shipped set its scene's material names."""


TILESET_EXAMPLES = 8
"""Bark photographs one ``POST /v1/tilesets`` takes."""


class TileSetJob(StrictModel):
    """A ``tileset`` job's parameters (``POST /v1/tilesets``, a multipart form): the names
    and SHA-256 of its photographs, which the job keeps as input files
    (``example_<k>.png`` or ``.jpg``), and the form's settings."""

    examples: list[str]
    sha256: list[str]
    per_class: int
    size: int
    seed: int
    priority: Priority = 5


class JobCost(StrictModel):
    """A job's cost, estimated before it was queued: what the tenant's quotas count while it
    is queued or running (``FOREST_TENANT_MAX_COST``, ``FOREST_TENANT_MAX_TILES``)."""

    pieces: Annotated[int, Field(ge=0)]
    """Expected pieces of the whole scene (every tile's)."""
    frames: Annotated[int, Field(ge=0)]
    tiles: Annotated[int, Field(ge=0)]
    """Tile jobs it makes (0: not tiled)."""
    scene_bytes: Annotated[int, Field(ge=0)]
    """Estimated bytes of its files (``forest.cost``)."""
    units: Annotated[int, Field(ge=0)]
    """Piece-frames: pieces x max(frames, 1)."""


class Artifact(StrictModel):
    name: str
    url: str
    size: Annotated[int, Field(ge=0)]


class JobRun(StrictModel):
    """One attempt of a job and the worker that ran it."""

    attempt: Annotated[int, Field(ge=1)]
    worker: str
    """``host:pid:tag`` (a worker's ``id`` in ``GET /v1/workers``)."""
    started_at: datetime


class JobWebhook(StrictModel):
    """A job's webhook call: made once the job has ended, tried again while it fails."""

    url: str
    pending: bool
    """To be called (or called again); false once it answered 2xx or was given up."""
    attempts: Annotated[int, Field(ge=0)]
    delivered_at: datetime | None
    error: str | None
    """What went wrong with the last call."""


class Job(StrictModel):
    """A job record: the SQL job table is the source of truth, the broker only delivers."""

    id: str
    kind: JobKind
    state: JobState
    progress: Annotated[float, Field(ge=0, le=1)]
    stage: str
    attempts: Annotated[int, Field(ge=0)]
    max_attempts: Annotated[int, Field(ge=1)]
    cancel_requested: bool
    worker: str | None
    """``host:pid:tag`` of the worker holding the job's lease while it is active."""
    error: str | None
    params: dict[str, Any]
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    heartbeat_at: datetime | None
    artifacts: list[Artifact]
    artifacts_deleted_at: datetime | None = None
    """When the job's artifacts were deleted (``DELETE /v1/jobs/{id}/artifacts``, or
    ``FOREST_ARTIFACT_TTL_S`` after the job finished); ``artifacts`` is empty from then on."""
    result: dict[str, Any] | None
    priority: Priority = 5
    cost: JobCost | None = None
    """The estimate its tenant's quotas counted (none for a tile: its forest job counts it)."""
    after: list[str] = []
    """Jobs this one waits for (it is held, stage ``waiting for N job(s)``, until all have
    completed)."""
    then: list[str] = []
    """Jobs that wait for this one (a forest request's ``render``, a render of a forest
    still running)."""
    runs: list[JobRun] = []
    """Which worker ran each attempt, oldest first (``worker`` names only the one running it
    now)."""
    webhook: JobWebhook | None = None
    """The delivery of the request's ``webhook`` (none without one)."""


LogLevel = Literal["info", "warning", "error"]


class LogLine(StrictModel):
    id: Annotated[int, Field(ge=1)]
    """Increasing within a job (and across jobs): ``after`` of the next read."""
    at: datetime
    attempt: Annotated[int, Field(ge=0)]
    level: LogLevel
    message: str


class JobLog(StrictModel):
    """A job's log lines (stage changes with the time each stage took, warnings, errors,
    the worker of each attempt, how it ended), oldest first."""

    items: list[LogLine]
    dropped: Annotated[int, Field(ge=0)]
    """Older lines dropped past the per-job cap (``FOREST_JOB_LOG_LINES``)."""
    next_after: Annotated[int, Field(ge=0)]
    """``after`` for the lines that come next (the last id here, or the one asked)."""


WorkerState = Literal["idle", "busy", "lost", "stopped"]


class Worker(StrictModel):
    """A worker process as the registry last saw it."""

    id: str
    """``host:pid:tag``: what a job's ``worker`` and ``runs`` name."""
    name: str
    """Its node name (``forest worker --name``)."""
    host: str
    pid: Annotated[int, Field(ge=0)]
    queues: list[str]
    renderer: str | None
    """GL_RENDERER of the context its render jobs get (probed at start), or why none."""
    state: WorkerState
    """``lost``: not seen for ``FOREST_WORKER_TIMEOUT_S`` (killed, or its host gone);
    ``stopped``: shut down cleanly."""
    current_job: str | None
    started_at: datetime
    last_seen: datetime


class WorkerList(StrictModel):
    items: list[Worker]
    timeout_s: float
    """A worker not seen for this long is ``lost``."""


class JobPage(StrictModel):
    items: list[Job]
    total: Annotated[int, Field(ge=0)]
    limit: Annotated[int, Field(ge=1)]
    offset: Annotated[int, Field(ge=0)]


class Preset(StrictModel):
    name: str
    description: str
    grammar: Grammar


class PresetList(StrictModel):
    items: list[Preset]


class Health(StrictModel):
    status: Literal["ok", "unavailable"]
    checks: dict[str, str] = {}
    data_free_bytes: int | None = None
    """Free bytes on the data volume (the artifacts folder's file system); ``/readyz`` only."""
