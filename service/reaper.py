"""The reaper: expired leases (a worker died) and queued jobs whose message went missing are
sent to the broker again. Runs as a thread in the API process and in every worker process."""

from __future__ import annotations

import logging
import threading

from service.dispatch import Dispatcher
from service.store import JobStore

log = logging.getLogger(__name__)


def reap_once(store: JobStore, dispatcher: Dispatcher, requeue_after_s: float) -> int:
    resend, failed = store.reap(requeue_after_s)
    for row in resend:
        dispatcher.send(row.id, row.kind)
        log.info("re-enqueued job %s (%s)", row.id, row.stage)
    for row in failed:
        log.warning("job %s failed: lease expired after %d attempt(s)", row.id, row.attempts)
    return len(resend)


class Reaper(threading.Thread):
    def __init__(
        self, store: JobStore, dispatcher: Dispatcher, interval_s: float, requeue_after_s: float
    ) -> None:
        super().__init__(name="forest-reaper", daemon=True)
        self.store, self.dispatcher = store, dispatcher
        self.interval_s, self.requeue_after_s = interval_s, requeue_after_s
        self.stopped = threading.Event()

    def run(self) -> None:
        while not self.stopped.wait(self.interval_s):
            try:
                reap_once(self.store, self.dispatcher, self.requeue_after_s)
            except Exception:  # a database or broker hiccup: try again next round
                log.exception("reaper round failed")

    def stop(self) -> None:
        self.stopped.set()
