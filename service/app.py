"""The FastAPI application: ``create_app(settings)``; migrations run on startup."""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI

from farm.artifacts import ArtifactStore
from farm.db import migrate
from farm.dispatch import Dispatcher
from farm.keys import KeyStore
from farm.reaper import Reaper
from farm.store import JobStore
from forest import __version__
from service.deps import Services
from service.errors import install_handlers
from service.hosts import AllowedHosts
from service.limits import BodyLimitMiddleware
from service.methods import AllowedMethods
from service.metrics import Metrics, MetricsMiddleware
from service.openapi import document_shared_responses
from service.routes import (
    events,
    forests,
    health,
    jobs,
    presets,
    recipes,
    renders,
    tilesets,
    trees,
    web,
    workers,
)
from service.security import AuthThrottle, KeyFirst, Keys, RateLimit, SameSiteWrites
from service.settings import ServiceSettings

log = logging.getLogger(__name__)


def create_app(settings: ServiceSettings | None = None, reaper: bool = True) -> FastAPI:
    settings = settings or ServiceSettings()
    store = JobStore(settings.db_url)
    metrics = Metrics(store)
    services = Services(
        settings,
        store,
        ArtifactStore(settings.artifacts),
        Dispatcher(settings),
        metrics,
        Keys(settings, KeyStore(settings.db_url)),
        RateLimit(settings),
        AuthThrottle(settings),
    )

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        settings.artifacts.mkdir(parents=True, exist_ok=True)
        migrate(settings.db_url)
        if services.keys.open():
            log.warning(
                "no API keys (FOREST_API_KEYS unset, none made by `forest keys create`): "
                "the API is open to loopback clients only"
            )
        thread = None
        if reaper:
            thread = Reaper(
                store,
                services.dispatcher,
                settings.reaper_interval_s,
                settings.requeue_after_s,
                artifacts=services.artifacts,
                housekeeping_s=settings.housekeeping_s,
                artifact_ttl_s=settings.artifact_ttl_s,
                settings=settings,
            )
            thread.start()
        try:
            yield
        finally:
            if thread is not None:
                thread.stop()
            services.dispatcher.close()

    app = FastAPI(
        title="interlocking-forest",
        version=__version__,
        description="Procedural forests from interlocking quad-mesh pieces, as USD scenes; "
        "forest and render jobs.",
        lifespan=lifespan,
        docs_url=None,  # served by service.routes.web from the package's own files
        redoc_url=None,
    )
    app.state.services = services
    install_handlers(app)
    for module in (
        presets, recipes, trees, forests, renders, tilesets, jobs, events, workers, health,
    ):  # fmt: skip
        app.include_router(module.router)
    web.install(app)  # /docs, /redoc and the page at /: after the API, whose routes come first
    document_shared_responses(app)
    # the last added runs first: the cheap refusals (host, origin, method, key) come before
    # any body is read
    app.add_middleware(
        BodyLimitMiddleware,
        max_bytes=settings.max_body_bytes,
        timeout_s=settings.body_timeout_s,
        max_json_bytes=settings.max_json_body_bytes,
    )
    app.add_middleware(KeyFirst, services=services)
    app.add_middleware(AllowedMethods, routes=app.router.routes)
    allowed = frozenset(o.strip() for o in settings.allowed_origins.split(",") if o.strip())
    app.add_middleware(SameSiteWrites, allowed=allowed)
    app.add_middleware(AllowedHosts, allowed=settings.allowed_hosts, is_open=services.keys.open)
    app.add_middleware(MetricsMiddleware, metrics=metrics)
    return app


def app_from_env() -> FastAPI:
    """uvicorn factory: ``uvicorn --factory service.app:app_from_env``."""
    return create_app()
