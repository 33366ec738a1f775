"""Commands of the service: ``serve``, ``worker`` (the worker's own command), ``bench service``."""

from __future__ import annotations

from pathlib import Path

import click

from cli.app import bench, data_option, input_errors, main, needs, parse_counts
from forest.extras import install_line, installed
from worker.jobs.main import worker_command

# what the API and its job store and queue import first (the rest of the extra loads with them)
SERVICE_MODULES = ("fastapi", "uvicorn", "sqlalchemy", "alembic", "celery")


@main.command()
@data_option("Folder of the embedded job store, broker and artifacts.")
@click.option("--host", default="127.0.0.1", show_default=True)
@click.option("--port", type=click.IntRange(0, 65535), default=8000, show_default=True)
@click.option(
    "--workers",
    type=click.IntRange(0, 64),
    default=2,
    show_default=True,
    help="Job worker processes (forest and render jobs).",
)
@click.option(
    "--api-workers",
    type=click.IntRange(1, 64),
    default=1,
    show_default=True,
    help="API processes sharing the port: requests are answered side by side (trees are "
    "made by the job workers); /metrics sums all of them.",
)
@input_errors
def serve(data_dir: Path, host: str, port: int, workers: int, api_workers: int) -> None:
    """The HTTP API plus local worker processes. With no FOREST_DATABASE_URL /
    FOREST_BROKER_URL / FOREST_ARTIFACTS_DIR set, everything lives in --data (SQLite)."""
    needs("service", *SERVICE_MODULES)
    import os

    from service.embedded import serve as run_serve
    from service.settings import ServiceSettings

    os.environ["FOREST_DATA_DIR"] = str(data_dir.resolve())
    s = ServiceSettings()
    click.echo(
        f"forest serve: http://{host}:{port} (docs at /docs), {api_workers} API process(es), "
        f"{workers} worker(s)"
    )
    click.echo(f"  jobs {s.db_url.split('@')[-1]}, broker {s.broker.split('@')[-1]}")
    if workers and not installed("moderngl"):
        click.echo(f"  render jobs fail without the render extra: {install_line('render')}")
    if not s.api_keys:
        from farm.db import migrate
        from farm.keys import KeyStore

        migrate(s.db_url)
        if not KeyStore(s.db_url).has_keys():
            click.echo(
                "  no API keys (none in the job store, FOREST_API_KEYS unset): the API is open "
                "to loopback clients only (others get 403); `forest keys create --tenant T` "
                "makes one"
            )
    run_serve(s, host, port, workers, api_workers)


main.add_command(worker_command, "worker")


@bench.command("service")
@click.option("--preset", default="almond", show_default=True)
@click.option("--concurrency", default="1,8,32", show_default=True, help="Client counts.")
@click.option("--requests", type=click.IntRange(1, 100_000), default=200, show_default=True)
@click.option("--workers", default="1,2", show_default=True, help="Worker counts for jobs.")
@click.option("--jobs", type=click.IntRange(1, 10_000), default=16, show_default=True)
@click.option("--trees", type=click.IntRange(1, 10_000), default=200, show_default=True)
@click.option(
    "--database",
    "database_url",
    default=None,
    help="Job store URL for the job runs (default: the embedded SQLite file), e.g. "
    "postgresql+psycopg://postgres@127.0.0.1/forest_bench.",
)
@click.option(
    "--broker",
    "broker_url",
    default=None,
    help="Broker URL for the job runs (default: the embedded SQLite broker), e.g. "
    "amqp://guest:guest@127.0.0.1:5672// or redis://127.0.0.1:6379/0.",
)
@click.option(
    "--render-frames",
    type=click.IntRange(0, 10_000),
    default=0,
    show_default=True,
    help="Instead of the tree and forest runs: the wall time of one clip of this many frames "
    "(in frame chunks of FOREST_RENDER_CHUNK_FRAMES) with each worker count, and the ratio.",
)
@click.option("--render-size", default="320x240", show_default=True, help="The clip's WxH.")
@input_errors
def bench_service(
    preset: str,
    concurrency: str,
    requests: int,
    workers: str,
    jobs: int,
    trees: int,
    database_url: str | None,
    broker_url: str | None,
    render_frames: int,
    render_size: str,
) -> None:
    """Latency (p50, p99) and req/s of POST /v1/trees at several client counts, and
    forest-job throughput (trees/s) with 1 and 2 workers, on the embedded server or on the
    job store and broker given; with --render-frames, a clip's wall time per worker count."""
    needs("service", *SERVICE_MODULES, "httpx")
    from bench.service import run_clip_bench, run_service_bench

    if render_frames:
        w, _, h = render_size.partition("x")
        if not (w.isdigit() and h.isdigit()):
            raise click.BadParameter("WxH, e.g. 320x240", param_hint="--render-size")
        run_clip_bench(
            preset,
            render_frames,
            (int(w), int(h)),
            parse_counts(workers, "workers"),
            echo=click.echo,
            database_url=database_url,
            broker_url=broker_url,
        )
        return
    run_service_bench(
        preset,
        parse_counts(concurrency, "concurrency"),
        requests,
        parse_counts(workers, "workers"),
        jobs,
        trees,
        echo=click.echo,
        database_url=database_url,
        broker_url=broker_url,
    )
