"""Wire models of the HTTP service: tree, forest and render requests, job records, presets.

Static bounds live here (they are part of the published schema); the service's configurable
caps (``service/settings.py``) are checked on top and answered with the same 422 shape.
"""

from __future__ import annotations

import math
from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from schemas.base import StrictModel
from schemas.grammar import Grammar

JobState = Literal["queued", "active", "completed", "failed", "canceled"]
JobKind = Literal["forest", "render"]
UsdFormat = Literal["usda", "usdc", "usdz"]
SceneFormat = Literal["usda", "usdc", "usdz", "glb"]
"""USD, or glTF 2.0 binary (skinned trees, wind animation, textures inside) for game engines."""

Seed = Annotated[int, Field(ge=0, le=2**63 - 1)]


def non_finite(value: Any, path: str = "") -> str | None:
    """The path (``grammar.rules.A[0].weight``) of the first NaN or infinite float in a JSON
    value, or None. JSON parsers accept ``NaN``, ``Infinity`` and ``1e400`` (inf)."""
    if isinstance(value, float):
        return None if math.isfinite(value) else path or "body"
    if isinstance(value, dict):
        for k, v in value.items():
            found = non_finite(v, f"{path}.{k}" if path else str(k))
            if found is not None:
                return found
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            found = non_finite(v, f"{path}[{i}]")
            if found is not None:
                return found
    return None


class FiniteModel(StrictModel):
    """A request: every float in it, however deep, is finite (checked before field parsing,
    so a NaN in a field without bounds cannot reach the library)."""

    @model_validator(mode="before")
    @classmethod
    def _finite(cls, data: Any) -> Any:
        found = non_finite(data)
        if found is not None:
            raise ValueError(f"{found}: must be a finite number (not NaN or infinite)")
        return data


class TreeRequest(FiniteModel):
    """One tree from a preset name or a grammar object, answered synchronously as USD or
    glTF (``format``)."""

    preset: Annotated[str, Field(min_length=1, max_length=64)] | None = None
    """Name of a shipped grammar (``GET /v1/presets``); give this or ``grammar``."""
    grammar: Grammar | None = None
    seed: Seed = 0
    format: SceneFormat = "usdc"
    frames: Annotated[int, Field(ge=0, le=10_000)] = 0
    """Wind frames to sample (0: a still, posed tree)."""
    fps: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] = 24.0
    wind_deg: Annotated[float, Field(ge=0, le=90, allow_inf_nan=False)] = 4.0
    segments: Annotated[int, Field(ge=1, le=8)] = 1
    skinned: bool = False
    """USD only: also bake each tree as a skinned mesh (a glb is always skinned)."""


class ForestRequest(TreeRequest):
    """A forest job: ``trees`` trees scattered over ``area`` (metres)."""

    trees: Annotated[int, Field(ge=1, le=200_000)] = 1
    area: tuple[
        Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)],
        Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)],
    ] = (20.0, 20.0)
    placement: Literal["poisson", "grid"] = "poisson"


class RenderRequest(FiniteModel):
    """A render job of a finished forest job's scene (the camera frames the forest itself)."""

    forest_job: Annotated[str, Field(min_length=1, max_length=64)]
    """Id of a completed forest job whose scene is rendered."""
    width: Annotated[int, Field(ge=1, le=8192)] = 640
    height: Annotated[int, Field(ge=1, le=8192)] = 480
    tess_max: Annotated[float, Field(ge=1, le=64, allow_inf_nan=False)] = 8.0
    frame: Annotated[int, Field(ge=0, le=10_000)] = 0
    frames: Annotated[int, Field(ge=1, le=10_000)] = 1
    """Measured frames (wind samples from ``frame`` on); the preview is the first."""


class Artifact(StrictModel):
    name: str
    url: str
    size: Annotated[int, Field(ge=0)]


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
    result: dict[str, Any] | None


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
