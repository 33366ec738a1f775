# GPU render worker (queue `gpu`): EGL on the NVIDIA driver through libglvnd.
# `docker build -f deploy/gpu-worker.Dockerfile -t forest-gpu-worker .`; run with the NVIDIA
# container toolkit (`--gpus all`, or compose/Kubernetes device requests).
FROM nvidia/cuda:12.6.3-runtime-ubuntu24.04
ENV DEBIAN_FRONTEND=noninteractive PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1
# "graphics" makes the toolkit mount the driver's EGL/GL libraries into the container
ENV NVIDIA_VISIBLE_DEVICES=all NVIDIA_DRIVER_CAPABILITIES=graphics,compute,utility
RUN apt-get update && apt-get install -y --no-install-recommends \
      python3 python3-venv libglvnd0 libegl1 libgl1 libgles2 libgomp1 ca-certificates \
    && rm -rf /var/lib/apt/lists/* \
    && mkdir -p /usr/share/glvnd/egl_vendor.d \
    && printf '{"file_format_version":"1.0.0","ICD":{"library_path":"libEGL_nvidia.so.0"}}\n' \
       > /usr/share/glvnd/egl_vendor.d/10_nvidia.json
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
RUN python3 -m venv /opt/venv && /opt/venv/bin/pip install '.[worker]' \
    && useradd --uid 10001 forest && mkdir -p /data && chown forest /data
ENV PATH=/opt/venv/bin:$PATH FOREST_DATA_DIR=/data FOREST_ARTIFACTS_DIR=/data/artifacts
USER forest
CMD ["forest", "worker", "-Q", "gpu,render"]
