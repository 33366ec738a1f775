#!/usr/bin/env bash
# Build the images of deploy/Dockerfile and smoke-test them with Docker alone (no Compose, no
# curl or Python on the host): run from anywhere, `bash deploy/smoke.sh`.
#   - api: starts on the embedded job store and broker (SQLite on a shared volume), answers
#     /healthz and /readyz, and lists the worker below on GET /v1/workers (an admin key);
#   - worker-cpu: Mesa's llvmpipe makes an EGL context (GL_RENDERER says llvmpipe), `forest
#     worker --list` runs, and a worker on the API's volume registers: its liveness probe
#     (python -m worker.probe) passes;
#   - worker-gpu: built; its EGL context is made only with SMOKE_GPU=1 (a host with an NVIDIA
#     GPU and the container toolkit), which should name the NVIDIA renderer.
# Environment: SMOKE_TAG (image tag, default smoke), SMOKE_GPU (1: run the GPU check),
# SMOKE_BUILD_ARGS (more `docker build` options, e.g. `--build-arg PYTHON_IMAGE=...` naming a
# mirror's or a local base image where Docker Hub cannot be reached),
# SMOKE_SKIP_GPU_BUILD (1: do not build worker-gpu, a large download), SMOKE_KEEP (1: leave
# the containers and volume for a look).
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
TAG=${SMOKE_TAG:-smoke}
RUN_ID="forest-smoke-$$"
VOLUME="$RUN_ID-data"
KEY="smoke-admin-key"
WAIT_S=${SMOKE_WAIT_S:-180}

log() { printf '[smoke] %s\n' "$*" >&2; }
fail() { log "FAILED: $*"; exit 1; }

cleanup() {
  if [[ ${SMOKE_KEEP:-0} == 1 ]]; then
    log "kept: containers $RUN_ID-api $RUN_ID-worker, volume $VOLUME"
    return
  fi
  docker rm -f "$RUN_ID-api" "$RUN_ID-worker" >/dev/null 2>&1 || true
  docker volume rm -f "$VOLUME" >/dev/null 2>&1 || true
}
trap cleanup EXIT

build() {  # build TARGET
  log "building target $1 -> forest-$1:$TAG"
  # shellcheck disable=SC2086 # SMOKE_BUILD_ARGS is a list of options
  DOCKER_BUILDKIT=1 docker build -f "$ROOT/deploy/Dockerfile" --target "$1" \
    ${SMOKE_BUILD_ARGS:-} -t "forest-$1:$TAG" "$ROOT"
}

# until SECONDS CMD...: run CMD every 2 s until it succeeds or SECONDS pass
until_ok() {
  local deadline=$((SECONDS + $1))
  shift
  until "$@" >/dev/null 2>&1; do
    ((SECONDS < deadline)) || return 1
    sleep 2
  done
}

# GET a path of the API from inside its container (the image has Python, the host needs none)
api_get() {  # api_get PATH [KEY]
  docker exec "$RUN_ID-api" python -c '
import sys, urllib.request
req = urllib.request.Request("http://127.0.0.1:8000" + sys.argv[1])
if len(sys.argv) > 2:
    req.add_header("X-API-Key", sys.argv[2])
print(urllib.request.urlopen(req, timeout=5).read().decode())
' "$@"
}

gl_renderer() {  # gl_renderer IMAGE [docker run options...]
  local image=$1
  shift
  docker run --rm "$@" "$image" python -c \
    'from forest.gl.context import create_context, gl_info; print(gl_info(create_context()).renderer)'
}

command -v docker >/dev/null || fail "docker is not installed"
docker info >/dev/null 2>&1 || fail "no Docker daemon answers (docker info)"

build api
build worker-cpu
if [[ ${SMOKE_SKIP_GPU_BUILD:-0} != 1 ]]; then
  build worker-gpu
fi

log "worker-cpu: EGL on llvmpipe"
renderer=$(gl_renderer "forest-worker-cpu:$TAG")
log "GL_RENDERER: $renderer"
[[ $renderer == *llvmpipe* ]] || fail "worker-cpu renders on '$renderer', not llvmpipe"
# (read whole, then matched: `| grep -q` would close the pipe early, and pipefail fail it)
kinds=$(docker run --rm "forest-worker-cpu:$TAG" forest worker --list)
[[ $kinds == *render* ]] || fail "forest worker --list names no render job: $kinds"

log "api + worker-cpu on the embedded job store (volume $VOLUME)"
docker volume create "$VOLUME" >/dev/null
# the images' user (uid 10001) owns the fresh volume's root: Docker copies /data's owner
docker run -d --name "$RUN_ID-api" -v "$VOLUME:/data" \
  -e FOREST_API_KEYS="$KEY=ops:admin" "forest-api:$TAG" >/dev/null
until_ok "$WAIT_S" api_get /healthz || { docker logs "$RUN_ID-api" >&2; fail "api: no /healthz"; }
until_ok 60 api_get /readyz || { docker logs "$RUN_ID-api" >&2; fail "api: /readyz not ready"; }
log "api: /healthz and /readyz answer"

docker run -d --name "$RUN_ID-worker" --hostname "$RUN_ID-worker" -v "$VOLUME:/data" \
  -e FOREST_WORKER_HEARTBEAT_S=2 -e FOREST_WORKER_TIMEOUT_S=10 \
  "forest-worker-cpu:$TAG" forest worker -Q default,render,cpu >/dev/null
until_ok "$WAIT_S" docker exec "$RUN_ID-worker" python -m worker.probe \
  || { docker logs "$RUN_ID-worker" >&2; fail "worker: its liveness probe never passed"; }
log "worker: $(docker exec "$RUN_ID-worker" python -m worker.probe)"
workers=$(api_get /v1/workers "$KEY")
[[ $workers == *"$RUN_ID-worker"* ]] || fail "GET /v1/workers does not list the worker: $workers"
log "api: GET /v1/workers lists the worker"

# a forest and its render through the API, run by the worker container: both complete, and
# the render's preview is a PNG (a script in the API's image: the host needs no Python)
log "api: a forest job and its render on the worker"
docker exec "$RUN_ID-api" python -c '
import json, sys, time, urllib.request
key, url = sys.argv[1], "http://127.0.0.1:8000"
def call(path, body=None):
    req = urllib.request.Request(url + path, headers={"X-API-Key": key})
    if body is not None:
        req.data = json.dumps(body).encode()
        req.add_header("Content-Type", "application/json")
    with urllib.request.urlopen(req, timeout=30) as r:
        return r.read()
body = {"preset": "alternating", "trees": 2, "seed": 1, "render": {"width": 64, "height": 48}}
forest = json.loads(call("/v1/forests", body))
jobs = [forest["id"], *forest["then"]]
deadline = time.monotonic() + 300
for job_id in jobs:
    while True:
        job = json.loads(call(f"/v1/jobs/{job_id}"))
        state, kind, error = job["state"], job["kind"], job.get("error")
        if state in ("completed", "failed", "canceled"):
            break
        if time.monotonic() > deadline:
            sys.exit(f"job {job_id} still {state} after 300 s")
        time.sleep(1)
    if state != "completed":
        sys.exit(f"{kind} job {state}: {error}")
preview = next(a["url"] for a in job["artifacts"] if a["name"] == "preview.png")
png = call(preview)
assert png[:8] == b"\x89PNG\r\n\x1a\n", png[:16]
print(f"forest {jobs[0]} and render {jobs[1]} completed; preview {len(png)} bytes")
' "$KEY" >&2 || { docker logs "$RUN_ID-worker" 2>&1 | tail -40 >&2; fail "the forest and its render"; }

# stopped (its row marked so) or, were the stop not clean, its row older than the timeout:
# the probe, run again under the same hostname as a restarted container would, must fail
probe_fails() {
  ! docker run --rm --hostname "$RUN_ID-worker" -v "$VOLUME:/data" \
    -e FOREST_WORKER_HEARTBEAT_S=2 -e FOREST_WORKER_TIMEOUT_S=10 \
    "forest-worker-cpu:$TAG" python -m worker.probe
}
docker stop -t 60 "$RUN_ID-worker" >/dev/null
until_ok 60 probe_fails || fail "the probe still passes for a stopped worker"
log "worker: stopped, its probe fails as it should"

if [[ ${SMOKE_GPU:-0} == 1 ]]; then
  log "worker-gpu: EGL on the NVIDIA driver"
  renderer=$(gl_renderer "forest-worker-gpu:$TAG" --gpus all)
  log "GL_RENDERER: $renderer"
  [[ $renderer != *llvmpipe* && $renderer == *NVIDIA* ]] \
    || fail "worker-gpu renders on '$renderer', not the NVIDIA driver"
fi

log "all checks passed"
