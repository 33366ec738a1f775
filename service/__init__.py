"""The HTTP service: FastAPI app, job store (SQLAlchemy), artifact store, task dispatch."""
