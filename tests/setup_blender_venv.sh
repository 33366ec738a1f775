#!/usr/bin/env bash
# Create .venv-blender: real Blender as a Python module (the bpy package on PyPI), for
# tests/test_blender.py and tests/blender_import_check.py. Idempotent: does nothing when the
# venv is already there with the pinned bpy importable.
#
#   bash tests/setup_blender_venv.sh            # bpy 4.2.23 (Blender 4.2 LTS, the oldest we support)
#   BPY_VERSION=4.5.15 bash tests/setup_blender_venv.sh
#
# bpy 4.2-5.0 wheels exist only for CPython 3.11 (manylinux_2_28 x86_64 here); the wheel is
# about 350 MB and the venv about 1 GB.
set -euo pipefail

BPY_VERSION="${BPY_VERSION:-4.2.23}"
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv-blender"

have_bpy() {
    "$VENV/bin/python" - "$BPY_VERSION" <<'EOF' >/dev/null 2>&1
import sys
from importlib.metadata import version
import bpy  # noqa: F401  (a real import: the shared libraries must load)
import numpy  # noqa: F401
sys.exit(version("bpy") != sys.argv[1])
EOF
}

if [ -x "$VENV/bin/python" ] && have_bpy; then
    echo "setup_blender_venv: $VENV already has bpy $BPY_VERSION"
    exit 0
fi

# a Python 3.11 to build the venv from
PY="${PYTHON311:-}"
if [ -z "$PY" ]; then
    for cand in python3.11 "$ROOT/.venv/bin/python" python3; do
        if command -v "$cand" >/dev/null 2>&1 &&
            "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
            PY="$cand"
            break
        fi
    done
fi
if [ -z "$PY" ]; then
    echo "setup_blender_venv: bpy $BPY_VERSION needs CPython 3.11; none found" \
        "(set PYTHON311=/path/to/python3.11)" >&2
    exit 1
fi

echo "setup_blender_venv: creating $VENV with bpy $BPY_VERSION (from $PY)"
rm -rf "$VENV"
"$PY" -m venv "$VENV"
"$VENV/bin/python" -m pip install --no-input --disable-pip-version-check -q "bpy==$BPY_VERSION"
if ! have_bpy; then
    echo "setup_blender_venv: bpy $BPY_VERSION installed but does not import" >&2
    exit 1
fi
echo "setup_blender_venv: done ($("$VENV/bin/python" -c 'import bpy; print(bpy.app.version_string)'))"
