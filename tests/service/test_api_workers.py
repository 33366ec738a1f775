"""``forest serve --api-workers N`` (issue 12.5): several API processes answer on one port, and
``/metrics`` counts the requests of all of them (prometheus_client's multiprocess mode, its
folder emptied when the server starts)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
from prometheus_client.multiprocess import MultiProcessCollector
from prometheus_client.parser import text_string_to_metric_families

from tests.service.service_harness import Server

ROUTE = "/v1/presets"


def requests_counted(files: list[Path]) -> float:
    """GET ROUTE requests counted in these metric files."""
    return sum(
        s.value
        for metric in MultiProcessCollector.merge([str(f) for f in files], accumulate=False)
        for s in metric.samples
        if s.name == "forest_http_requests_total" and s.labels.get("route") == ROUTE
    )


def per_process(folder: Path) -> dict[str, float]:
    """GET ROUTE requests counted by each process (metric files are per pid)."""
    return {f.stem: requests_counted([f]) for f in sorted(folder.glob("counter_*.db"))}


def test_two_api_processes_one_metrics(tmp_path: Path) -> None:
    data = tmp_path / "data"
    stale = data / "run" / "metrics" / "counter_1.db"  # an earlier run's: emptied at start
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"not a metrics file")
    server = Server(data, {}, workers=0, api_workers=2).start()
    try:
        folder = data / "run" / "metrics"
        assert not stale.exists()

        def get(_: int) -> int:
            # a connection per request, several at once: the kernel hands them to both
            return httpx.get(f"{server.url}{ROUTE}", timeout=30).status_code

        sent = 0
        with ThreadPoolExecutor(8) as pool:
            for _ in range(50):
                codes = list(pool.map(get, range(16)))
                assert codes == [200] * 16
                sent += 16
                if sum(n > 0 for n in per_process(folder).values()) >= 2:
                    break
        served = {pid: n for pid, n in per_process(folder).items() if n > 0}
        assert len(served) == 2, served  # both processes answered
        text = server.get("/metrics").text
        total = sum(
            s.value
            for family in text_string_to_metric_families(text)
            for s in family.samples
            if s.name == "forest_http_requests_total"
            and s.labels == {"method": "GET", "route": ROUTE, "status": "200"}
        )
        assert total == sent == sum(served.values())  # one scrape counts every process
    finally:
        server.stop()
