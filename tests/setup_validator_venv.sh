#!/usr/bin/env bash
# Create .venv-validator: NVIDIA's USD validator (usd-validation-nvidia with its usd extra),
# for tests/test_usd_nvidia_validator.py. Its own venv because the extra pins an older
# usd-core (< 26.09) than the project's; the scenes are written by the project's venv and
# the validator only reads them. Idempotent: does nothing when the venv already has the
# pinned version importable.
#
#   bash tests/setup_validator_venv.sh                      # usd-validation-nvidia 1.22.0
#   NVIDIA_VALIDATOR_VERSION=1.22.0 bash tests/setup_validator_venv.sh
set -euo pipefail

VERSION="${NVIDIA_VALIDATOR_VERSION:-1.22.0}"
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv-validator"

have_validator() {
    "$VENV/bin/python" - "$VERSION" <<'PY' >/dev/null 2>&1
import sys
from importlib.metadata import version
import pxr.Usd  # noqa: F401  (the usd extra: the validator needs pxr)
import omni.asset_validator  # noqa: F401
sys.exit(version("usd-validation-nvidia") != sys.argv[1])
PY
}

if [ -x "$VENV/bin/python" ] && [ -x "$VENV/bin/nvidia_usd_validate" ] && have_validator; then
    echo "setup_validator_venv: $VENV already has usd-validation-nvidia $VERSION"
    exit 0
fi

PY="${PYTHON:-python3}"
echo "setup_validator_venv: creating $VENV with usd-validation-nvidia[usd]==$VERSION (from $PY)"
rm -rf "$VENV"
"$PY" -m venv "$VENV"
"$VENV/bin/python" -m pip install --no-input --disable-pip-version-check -q \
    "usd-validation-nvidia[usd]==$VERSION"
if ! have_validator; then
    echo "setup_validator_venv: usd-validation-nvidia $VERSION installed but does not import" >&2
    exit 1
fi
echo "setup_validator_venv: done"
