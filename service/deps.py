"""Shared dependencies as ``Annotated`` aliases; everything hangs off ``app.state.services``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Header, Request

from farm.artifacts import ArtifactStore
from farm.dispatch import Dispatcher
from farm.store import JobStore
from service.metrics import Metrics
from service.security import AuthThrottle, Keys, RateLimit
from service.settings import ServiceSettings


@dataclass
class Services:
    settings: ServiceSettings
    store: JobStore
    artifacts: ArtifactStore
    dispatcher: Dispatcher
    metrics: Metrics
    keys: Keys
    rate_limit: RateLimit
    auth_throttle: AuthThrottle


def get_services(request: Request) -> Services:
    services: Services = request.app.state.services
    return services


ServicesDep = Annotated[Services, Depends(get_services)]
IdempotencyKey = Annotated[
    str | None,
    Header(
        alias="Idempotency-Key",
        min_length=1,
        max_length=255,
        description="Same key, same request: the same job is answered (no second job).",
    ),
]
