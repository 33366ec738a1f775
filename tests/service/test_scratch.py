"""Scratch folders left by killed processes are removed, and only those: a folder whose owner
on this host is gone goes at once; one whose owner cannot be checked from here (another host,
an old name without an owner) goes only once its job is finished and the folder is old; a
folder of a queued or running job, a live owner's, or anything else in the artifact folder
stays."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterable
from pathlib import Path

from farm import scratch

JOB = "a" * 32
OTHER = "b" * 32


def made_by_killed_process(root: Path) -> Path:
    """A scratch folder whose owner was killed (SIGKILL: no clean-up ran)."""
    code = (
        "import sys, time; from pathlib import Path; from farm import scratch; "
        f"print(scratch.make(Path(sys.argv[1]), {JOB!r}), flush=True); time.sleep(60)"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(root)],
        stdout=subprocess.PIPE,
        text=True,
        env=os.environ | {"PYTHONPATH": str(Path(__file__).resolve().parents[2])},
    )
    assert proc.stdout is not None
    folder = Path(proc.stdout.readline().strip())
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    proc.stdout.close()
    return folder


def aged(path: Path, seconds: float) -> Path:
    t = time.time() - seconds
    os.utime(path, (t, t))
    return path


def test_dead_local_owner_goes_live_one_stays(tmp_path: Path) -> None:
    dead = made_by_killed_process(tmp_path)
    assert dead.is_dir() and dead.parent == tmp_path
    (dead / "scene.usdc").write_bytes(b"half a scene")
    live = scratch.make(tmp_path, JOB)
    assert str(os.getpid()) in live.name
    assert scratch.sweep(tmp_path) == [dead]
    assert not dead.exists() and live.is_dir()


def test_unknown_owners_go_only_when_their_job_is_done_and_old(tmp_path: Path) -> None:
    elsewhere = tmp_path / f".{JOB}.4242@another-pod~4026531836.k3j2h1g0"
    legacy = tmp_path / f".{OTHER}.x8f7_a2c"
    for p in (elsewhere, legacy):
        p.mkdir()
    running: set[str] = {JOB, OTHER}
    asked: list[set[str]] = []

    def unfinished(ids: Iterable[str]) -> set[str]:
        asked.append(set(ids))
        return running & set(ids)

    assert scratch.sweep(tmp_path, unfinished, grace_s=600) == []  # fresh: not even asked
    assert asked == []
    aged(elsewhere, 3600)
    aged(legacy, 3600)
    assert scratch.sweep(tmp_path, unfinished, grace_s=600) == []  # old, but jobs still run
    assert asked == [{JOB, OTHER}]
    running = {OTHER}  # JOB finished (or is gone from the job table)
    assert scratch.sweep(tmp_path, unfinished, grace_s=600) == [elsewhere]
    assert legacy.is_dir()
    # without the job store nothing of an unknown owner goes
    running = set()
    assert scratch.sweep(tmp_path, None, grace_s=600) == []
    assert scratch.sweep(tmp_path, unfinished, grace_s=600) == [legacy]


def test_nothing_else_is_touched(tmp_path: Path) -> None:
    keep = [
        tmp_path / JOB,  # a job's artifact folder
        tmp_path / f".{JOB}.notes.txt",  # a dot name that is no scratch folder
        tmp_path / ".cache",
    ]
    for p in keep:
        p.mkdir()
        aged(p, 10**6)
    target = tmp_path / "elsewhere"
    target.mkdir()
    link = tmp_path / f".{JOB}.4242@{scratch.HOST}~{scratch.PID_NS}.abcdefgh"
    link.symlink_to(target, target_is_directory=True)  # a dead owner's name, but a link
    assert scratch.sweep(tmp_path, lambda ids: set(), grace_s=0) == []
    assert all(p.is_dir() for p in keep) and target.is_dir() and link.is_symlink()


def test_the_job_store_says_which_jobs_are_unfinished(tmp_path: Path) -> None:
    from farm.db import migrate
    from farm.store import JobStore

    url = f"sqlite:///{tmp_path / 'jobs.sqlite'}"
    migrate(url)
    store = JobStore(url)
    queued, _ = store.create("forest", {"seed": 1}, max_attempts=3)
    running, _ = store.create("forest", {"seed": 2}, max_attempts=3)
    done, _ = store.create("forest", {"seed": 3}, max_attempts=3)
    assert store.claim(running.id, "w", 60) is not None
    claim = store.claim(done.id, "w", 60)
    assert claim is not None and store.finish(claim, "completed")
    ids = [queued.id, running.id, done.id, "f" * 32]
    assert store.unfinished(ids) == {queued.id, running.id}
    root = tmp_path / "artifacts"
    root.mkdir()
    folders = {}
    for job in ids:
        folders[job] = root / f".{job}.7@elsewhere~1.abcdefgh"
        folders[job].mkdir()
        aged(folders[job], 3600)
    removed = scratch.sweep(root, store.unfinished, grace_s=600)
    assert sorted(removed) == sorted([folders[done.id], folders["f" * 32]])
