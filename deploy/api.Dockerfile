# The HTTP API: `docker build -f deploy/api.Dockerfile -t forest-api .`
FROM python:3.11-slim-bookworm
ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1
WORKDIR /app
COPY pyproject.toml README.md ./
COPY forest forest
COPY schemas schemas
COPY farm farm
COPY service service
COPY worker worker
COPY shaders shaders
COPY cli cli
COPY bench bench
RUN pip install '.[service]' && useradd --uid 10001 forest && mkdir -p /data && chown forest /data
USER forest
# every setting comes from the environment (farm/settings.py, service/settings.py):
# FOREST_DATABASE_URL, FOREST_BROKER_URL, FOREST_ARTIFACTS_DIR, FOREST_QUORUM_QUEUES, caps and lease timing
ENV FOREST_DATA_DIR=/data FOREST_ARTIFACTS_DIR=/data/artifacts
EXPOSE 8000
HEALTHCHECK --interval=10s --timeout=3s --retries=5 \
  CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=2)"
# uvicorn with header, body and keep-alive timeouts (FOREST_HEADER_TIMEOUT_S, _BODY_TIMEOUT_S,
# _KEEP_ALIVE_S): a slow client cannot hold connections open
CMD ["python", "-m", "service.server", "--host", "0.0.0.0", "--port", "8000", "--workers", "2"]
