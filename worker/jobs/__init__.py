"""Job execution: the task kinds, their supervision, the uploaded-scene guard, the worker's
entry point."""
