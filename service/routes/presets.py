"""``GET /v1/presets``: the shipped grammars."""

from __future__ import annotations

from fastapi import APIRouter

from forest.growth.presets import load_preset, preset_names
from schemas.jobs import Preset, PresetList
from service.security import Tenant

router = APIRouter(prefix="/v1/presets", tags=["presets"])


@router.get("", response_model=PresetList)
def list_presets(tenant: Tenant) -> PresetList:
    items = []
    for name in preset_names():
        g = load_preset(name)
        items.append(Preset(name=name, description=g.description, grammar=g))
    return PresetList(items=items)
