"""The FastAPI application: ``create_app(settings)``; migrations run on startup."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI

from forest import __version__
from service.artifacts import ArtifactStore
from service.db import migrate
from service.deps import Services
from service.dispatch import Dispatcher
from service.errors import install_handlers
from service.limits import BodyLimitMiddleware
from service.metrics import Metrics, MetricsMiddleware
from service.reaper import Reaper
from service.routes import forests, health, jobs, presets, renders, trees, web
from service.security import Keys, RateLimit, SameSiteWrites
from service.settings import ServiceSettings, get_settings
from service.store import JobStore


def create_app(settings: ServiceSettings | None = None, reaper: bool = True) -> FastAPI:
    settings = settings or get_settings()
    store = JobStore(settings.db_url)
    metrics = Metrics(store)
    services = Services(
        settings, store, ArtifactStore(settings.artifacts), Dispatcher(settings), metrics,
        Keys(settings), RateLimit(settings),
    )

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        settings.artifacts.mkdir(parents=True, exist_ok=True)
        migrate(settings.db_url)
        thread = None
        if reaper:
            thread = Reaper(
                store, services.dispatcher, settings.reaper_interval_s, settings.requeue_after_s
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
    for module in (presets, trees, forests, renders, jobs, health):
        app.include_router(module.router)
    web.install(app)  # /docs, /redoc and the page at /: after the API, whose routes come first
    app.add_middleware(BodyLimitMiddleware, max_bytes=settings.max_body_bytes)
    allowed = frozenset(o.strip() for o in settings.allowed_origins.split(",") if o.strip())
    app.add_middleware(SameSiteWrites, allowed=allowed)
    app.add_middleware(MetricsMiddleware, metrics=metrics)
    return app


def app_from_env() -> FastAPI:
    """uvicorn factory: ``uvicorn --factory service.app:app_from_env``."""
    return create_app()
