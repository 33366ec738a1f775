"""``python -m worker -Q default,render,gpu,cpu``: what ``forest worker`` runs (used by
``forest serve``)."""

from worker.jobs.main import worker_command

if __name__ == "__main__":
    worker_command(prog_name="python -m worker")
