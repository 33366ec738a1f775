"""``usdchecker --arkit`` on a .usdz: ``python usdz_arkit_check.py FILE`` prints one JSON
object ``{"failed": [...], "errors": [...], "skipped": [...]}`` from
``UsdUtils.ComplianceChecker(arkit=True)``. Run it with a USD build that still has the
checker (usd-core 25.x; 26.x removed it), see tests/test_usd_textures.py.

pip's usd-core 25.5 ships no ``usdShaders`` plugin (no UsdPreviewSurface definitions), so
``ShaderPropertyTypeConformanceChecker`` finds every shader an "invalid shader node" there;
those findings are listed under ``skipped`` (with the reason), only where the build lacks
the definitions, and every other finding counts.
"""

from __future__ import annotations

import json
import sys

from pxr import Sdr, UsdUtils


def main(path: str) -> None:
    try:  # the first Sdr discovery raises once where usdHydra's shader files are missing
        known = Sdr.Registry().GetShaderNodeByIdentifier("UsdPreviewSurface") is not None
    except Exception:
        known = False
    checker = UsdUtils.ComplianceChecker(arkit=True)
    checker.CheckCompliance(path)
    failed, skipped = [], []
    for message in checker.GetFailedChecks():
        lacks_definitions = not known and "has invalid shader node" in message
        (skipped if lacks_definitions else failed).append(message)
    print(json.dumps({"failed": failed, "errors": list(checker.GetErrors()), "skipped": skipped}))


if __name__ == "__main__":
    main(sys.argv[1])
