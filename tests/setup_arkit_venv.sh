#!/usr/bin/env bash
# Create .venv-arkit: usd-core 25.5, whose UsdUtils.ComplianceChecker runs `usdchecker --arkit`
# (usd-core 26 removed the checker), for tests/test_usd_textures.py and tests/test_lod.py.
# Its own venv because the project's usd-core is newer; the scenes are written by the
# project's venv and the checker only reads them. Idempotent: does nothing when the venv
# already has the pinned version with the checker importable.
#
#   bash tests/setup_arkit_venv.sh                  # usd-core 25.5
#   ARKIT_USD_VERSION=25.5 bash tests/setup_arkit_venv.sh
set -euo pipefail

VERSION="${ARKIT_USD_VERSION:-25.5}"
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv-arkit"

have_checker() {
    "$VENV/bin/python" - "$VERSION" <<'PY' >/dev/null 2>&1
import sys
from importlib.metadata import version
from pxr import UsdUtils
UsdUtils.ComplianceChecker(arkit=True)
sys.exit(version("usd-core") != sys.argv[1])
PY
}

if [ -x "$VENV/bin/python" ] && have_checker; then
    echo "setup_arkit_venv: $VENV already has usd-core $VERSION"
    exit 0
fi

PY="${PYTHON:-python3}"
echo "setup_arkit_venv: creating $VENV with usd-core==$VERSION (from $PY)"
rm -rf "$VENV"
"$PY" -m venv "$VENV"
"$VENV/bin/python" -m pip install --no-input --disable-pip-version-check -q "usd-core==$VERSION"
if ! have_checker; then
    echo "setup_arkit_venv: usd-core $VERSION installed but has no ComplianceChecker" >&2
    exit 1
fi
echo "setup_arkit_venv: done"
