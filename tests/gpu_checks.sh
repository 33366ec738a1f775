#!/usr/bin/env bash
# The GPU checks on an NVIDIA machine (or any EGL driver): the render bench at 1 to 1,000
# trees, bare and staged, each with and without the cull pass, with the foliage bench; the
# same for 1 to 1,000 oaks; then the renderer's GL tests with GL required. Output (tables,
# plots, test log) goes to $OUT (default ./gpu-checks).
# Run from the repository root with the package importable (installed, or PYTHONPATH=.).
set -uo pipefail
OUT=${OUT:-gpu-checks}
PY=${PYTHON:-python3}
mkdir -p "$OUT"
nvidia-smi --query-gpu=name,driver_version --format=csv 2>&1 | tee "$OUT/device.txt"
timeout 300 "$PY" -m cli bench render --trees 1,10,50,100,250,500,1000 --levels 1,10 \
  --width 1920 --height 1080 --frames 10 --foliage-trees 100,1000 \
  --plot "$OUT/bench-render.png" 2>&1 | tee "$OUT/bench-render.txt"
# a mature species, where the cull pass and sub-pixel LOD matter most (rows lod, staged_lod)
timeout 240 "$PY" -m cli bench render --preset oak --trees 1,10,100,1000 --levels 1 \
  --width 1920 --height 1080 --frames 5 --no-naive --foliage-trees none \
  --plot "$OUT/bench-render-oak.png" 2>&1 | tee "$OUT/bench-render-oak.txt"
# warnings shown, not raised: a GPU image's own plugins warn, and pyproject's filter names
# sqlalchemy, which a render-only install lacks (the CI suite keeps warnings as errors)
FOREST_REQUIRE_GL=1 timeout 300 "$PY" -m pytest tests/worker -q -p no:cacheprovider \
  -n "${GL_TEST_WORKERS:-8}" --dist loadfile -o addopts=-ra -o filterwarnings=default 2>&1 | tee "$OUT/gl-tests.txt" | tail -15
