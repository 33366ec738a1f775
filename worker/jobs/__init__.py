"""Job execution: the task kinds (``registry`` of ``forest``, ``tile``, ``render``, each a
function of a ``context``), the Celery task that claims a job and runs its kind (``tasks``),
each attempt's supervised child process (``supervise``), the uploaded-scene guard
(``scene_guard``) and the worker's entry point (``main``)."""
