"""The job machinery below the HTTP API and the workers: job store, dispatch, artifacts, reaper."""
