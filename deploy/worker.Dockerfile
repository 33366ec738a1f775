# CPU worker (forest generation, queue `default`; renders of the `cpu` pool and of any pool,
# queues `cpu` and `render`, on Mesa's llvmpipe): `docker build -f deploy/worker.Dockerfile .`
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
# Mesa's EGL and llvmpipe: this worker renders without a GPU
RUN apt-get update && apt-get install -y --no-install-recommends libegl1 libegl-mesa0 \
        libgl1-mesa-dri libgles2 && rm -rf /var/lib/apt/lists/*
RUN pip install '.[service]' && useradd --uid 10001 forest && mkdir -p /data && chown forest /data
USER forest
ENV FOREST_DATA_DIR=/data FOREST_ARTIFACTS_DIR=/data/artifacts
# one task at a time per process (solo pool); scale with replicas
CMD ["forest", "worker", "-Q", "default,render,cpu"]
