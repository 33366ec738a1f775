"""``GET /v1/presets``: the shipped grammars, public (no key needed: a page lists them before
a key is pasted)."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from forest.growth.presets import load_preset, preset_names
from schemas.jobs import Preset, PresetList
from service.security import public

router = APIRouter(prefix="/v1/presets", tags=["presets"], dependencies=[Depends(public)])


@router.get("", response_model=PresetList)
def list_presets() -> PresetList:
    items = []
    for name in preset_names():
        g = load_preset(name)
        items.append(Preset(name=name, description=g.description, grammar=g))
    return PresetList(items=items)
