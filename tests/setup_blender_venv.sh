#!/usr/bin/env bash
# Create .venv-blender: real Blender as a Python module (the bpy package on PyPI), for
# tests/test_blender.py and tests/blender_import_check.py. Idempotent: does nothing when the
# venv is already there with the pinned bpy importable.
#
#   bash tests/setup_blender_venv.sh            # bpy 4.2.23 (Blender 4.2 LTS, the oldest we support)
#   bash tests/setup_blender_venv.sh 5.2        # bpy 5.2.3 (Blender 5.2 LTS) in .venv-blender52
#   BPY_VERSION=4.5.15 bash tests/setup_blender_venv.sh
#
# bpy 4.2-5.0 wheels exist only for CPython 3.11, 5.1 and later only for 3.13 (manylinux_2_28
# x86_64 here; this machine's pyenv has both); the wheel is about 350 MB and the venv about 1 GB.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ "${1:-}" = "5.2" ]; then
    BPY_VERSION="${BPY_VERSION:-5.2.3}"
    VENV="$ROOT/.venv-blender52"
    WANT_PY="3.13"
else
    BPY_VERSION="${BPY_VERSION:-4.2.23}"
    VENV="$ROOT/.venv-blender"
    WANT_PY="3.11"
fi

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

# a Python of the version the wheel is for, to build the venv from
PY="${BLENDER_PYTHON:-}"
if [ -z "$PY" ]; then
    for cand in "python$WANT_PY" "$ROOT/.venv/bin/python" python3 \
        "$HOME"/.pyenv/versions/"$WANT_PY".*/bin/python"$WANT_PY"; do
        if command -v "$cand" >/dev/null 2>&1 &&
            "$cand" -c "import sys; sys.exit(sys.version_info[:2] != tuple(map(int, '$WANT_PY'.split('.'))))" 2>/dev/null; then
            PY="$cand"
            break
        fi
    done
fi
if [ -z "$PY" ]; then
    echo "setup_blender_venv: bpy $BPY_VERSION needs CPython $WANT_PY; none found" \
        "(set BLENDER_PYTHON=/path/to/python$WANT_PY)" >&2
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
