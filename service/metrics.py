"""Prometheus metrics: requests and latency per route (middleware), and, read from the job
table at scrape time, job counts per state (queue depth), job durations and render frame
times (so every API replica reports the same numbers, whichever process ran the jobs).

Several API processes of one server (``forest serve --api-workers N``, ``python -m
service.server --workers N``) share their request counts through prometheus_client's
multiprocess mode: with ``PROMETHEUS_MULTIPROC_DIR`` set before the process starts, each
process writes its samples to files there and ``/metrics`` sums every process's files.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable
from typing import Any, get_args

from prometheus_client import CollectorRegistry, Counter, Histogram, multiprocess
from prometheus_client.core import GaugeMetricFamily, HistogramMetricFamily, Metric
from prometheus_client.registry import Collector
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from farm.store import JobStore
from schemas.jobs import JobKind, JobState

JOB_BUCKETS = (0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 300, 1800, float("inf"))
FRAME_BUCKETS = (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 5000, float("inf"))
# the method label takes a fixed set of values: a client's made-up methods must not each add
# a series (the registry would grow with every new word sent)
METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})


def _histogram(values: Iterable[float], buckets: tuple[float, ...]) -> tuple[list[Any], float]:
    vals = list(values)
    cum = [[str(b) if b != float("inf") else "+Inf", sum(v <= b for v in vals)] for b in buckets]
    return cum, float(sum(vals))


class JobCollector(Collector):
    def __init__(self, store: JobStore) -> None:
        self.store = store

    def collect(self) -> Iterable[Metric]:
        counts = self.store.counts()
        jobs = GaugeMetricFamily("forest_jobs", "Jobs per kind and state", labels=["kind", "state"])
        depth = GaugeMetricFamily("forest_queue_depth", "Queued jobs per kind", labels=["kind"])
        for kind in get_args(JobKind):
            for state in JobState:
                jobs.add_metric([kind, state.value], counts.get((kind, state), 0))
            depth.add_metric([kind], counts.get((kind, JobState.QUEUED), 0))
        yield jobs
        yield depth
        rows = self.store.recent_finished()
        dur = HistogramMetricFamily(
            "forest_job_duration_seconds",
            "Run time of recently completed jobs (last 1000)",
            labels=["kind"],
        )
        frames = HistogramMetricFamily(
            "forest_render_frame_ms", "CPU frame times of recently completed renders"
        )
        for kind in get_args(JobKind):
            secs = [
                (r.finished_at - r.started_at).total_seconds()
                for r in rows
                if r.kind == kind and r.finished_at and r.started_at
            ]
            buckets, total = _histogram(secs, JOB_BUCKETS)
            dur.add_metric([kind], buckets, total)
        frame_ms = [
            float(ms)
            for r in rows
            if r.kind == "render" and r.result
            for ms in r.result.get("frame_cpu_ms", [])
        ]
        buckets, total = _histogram(frame_ms, FRAME_BUCKETS)
        frames.add_metric([], buckets, total)
        yield dur
        yield frames


MULTIPROC_ENV = "PROMETHEUS_MULTIPROC_DIR"


class Metrics:
    """The scrape registry: this process's request metrics, or with :data:`MULTIPROC_ENV`
    set, those of every process writing to that folder; and the job table's."""

    def __init__(self, store: JobStore) -> None:
        self.registry = CollectorRegistry()
        shared = bool(os.environ.get(MULTIPROC_ENV))
        # shared: the samples go to this process's files and the scrape reads all files;
        # registering the metrics themselves as well would count this process twice
        own = None if shared else self.registry
        self.requests = Counter(
            "forest_http_requests",
            "HTTP requests",
            ["method", "route", "status"],
            registry=own,
        )
        self.latency = Histogram(
            "forest_http_request_seconds",
            "HTTP request latency",
            ["method", "route"],
            registry=own,
        )
        if shared:
            multiprocess.MultiProcessCollector(self.registry)
        self.registry.register(JobCollector(store))


class MetricsMiddleware:
    """Counts every request by its route template (not its raw path: ids stay out) and its
    method (one of :data:`METHODS`, else ``other``), so the series stay bounded."""

    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app, self.metrics = app, metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        status = 500

        async def send_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_status)
        finally:
            route = scope.get("route")
            name = getattr(route, "path", "unmatched")
            method = scope.get("method", "")
            method = method if method in METHODS else "other"
            self.metrics.requests.labels(method, name, str(status)).inc()
            self.metrics.latency.labels(method, name).observe(time.perf_counter() - start)
