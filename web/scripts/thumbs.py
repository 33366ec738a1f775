"""Gallery thumbnails for the web page: docs/gallery/<species>.png (one tree each) and
recipe_<name>.png (a mixed forest from above) ->
web/src/gallery/ at a quarter of their size (120 x 160 from 480 x 640), so the wheel
carries small copies. Run by ``make web`` before the vite build; needs OpenImageIO (a
dependency of the package)."""

from __future__ import annotations

import sys
from pathlib import Path

import OpenImageIO as oiio

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "docs" / "gallery"
OUT = ROOT / "web" / "src" / "gallery"
SCALE = 4


def main() -> int:
    OUT.mkdir(parents=True, exist_ok=True)
    for path in sorted(SRC.glob("*.png")):
        if path.stem in ("contact_sheet", "closeups") or path.stem.endswith(
            ("_stand", "_leaves", "_base", "_eye")
        ):
            continue
        src = oiio.ImageBuf(str(path))
        spec = src.spec()
        roi = oiio.ROI(0, spec.width // SCALE, 0, spec.height // SCALE, 0, 1, 0, spec.nchannels)
        small = oiio.ImageBufAlgo.resize(src, roi=roi)  # filtered (blackman-harris) downsample
        small.set_write_format(oiio.UINT8)
        dst = OUT / path.name
        if not small.write(str(dst)):
            print(f"{dst}: {small.geterror()}", file=sys.stderr)
            return 1
    print(f"thumbnails in {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
