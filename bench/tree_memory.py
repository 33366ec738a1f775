"""The API process's memory over many ``POST /v1/trees`` (issue 26, defect 6): ``forest serve``
on a temporary data folder (embedded SQLite, or the job store and broker given), a warm-up,
then ``--requests`` trees from ``--clients`` threads; the API's resident memory (``VmRSS``)
every tenth of the way, and its growth after the warm-up.

``python -m bench.tree_memory --requests 1000 --clients 4`` (from the repository root)."""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

import httpx

from bench.service import embedded_server, rss_mib

# a tree of one piece: the job is quick, so the run measures the API, not the workers
ONE_PIECE = {"grammar": {"axiom": "A", "rules": {"A": [{"piece": "I", "successors": [None]}]}}}


def run(requests: int, clients: int, workers: int, body: dict[str, object]) -> None:
    backends = {
        k: v
        for k, v in os.environ.items()
        if k in ("FOREST_DATABASE_URL", "FOREST_BROKER_URL", "FOREST_QUEUE_PREFIX")
    }
    with (
        tempfile.TemporaryDirectory(prefix="forest-bench-") as tmp,
        embedded_server(Path(tmp) / "api", workers, backends) as api,
    ):
        with httpx.Client(base_url=api.url, timeout=300) as c:
            for seed in range(10):  # warm-up: connections, threads, first-request caches
                c.post("/v1/trees", json=body | {"seed": 10**6 + seed}).raise_for_status()
        base = rss_mib(api.pid)
        print(f"API RSS after warm-up: {base:.0f} MiB ({workers} workers, {clients} clients)")
        print(f"{'requests':>9} {'API MiB':>8} {'growth':>7} {'s':>7}")
        codes: Counter[int] = Counter()
        done = 0
        lock = threading.Lock()
        step = max(1, requests // 10)
        start = time.perf_counter()

        def client(seeds: range) -> None:
            nonlocal done
            with httpx.Client(base_url=api.url, timeout=300) as c:
                for seed in seeds:
                    code = c.post("/v1/trees", json=body | {"seed": seed}).status_code
                    with lock:
                        codes[code] += 1
                        done += 1
                        if done % step == 0 or done == requests:
                            rss = rss_mib(api.pid)
                            t = time.perf_counter() - start
                            print(f"{done:>9} {rss:>8.0f} {rss - base:>+7.0f} {t:>7.0f}")

        threads = [
            threading.Thread(target=client, args=(range(i, requests, clients),))
            for i in range(clients)
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        print(f"answers: {dict(sorted(codes.items()))}; load average {os.getloadavg()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--requests", type=int, default=1000)
    parser.add_argument("--clients", type=int, default=4)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--preset", help="a preset's tree (default: a tree of one piece)")
    args = parser.parse_args()
    body = {"preset": args.preset} if args.preset else ONE_PIECE
    run(args.requests, args.clients, args.workers, body | {"format": "usdc"})


if __name__ == "__main__":
    main()
