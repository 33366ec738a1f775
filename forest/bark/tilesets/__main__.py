"""``python -m forest.bark.tilesets [FOLDER]``: rebuild the default tile set (into the package)."""

from __future__ import annotations

import sys
from pathlib import Path

from forest.bark.tilesets import default_dir, make_default


def main(argv: list[str]) -> int:
    folder = Path(argv[0]) if argv else default_dir()
    ts = make_default(folder)
    print(f"wrote {folder}: {len(ts.tiles)} tiles of {ts.manifest.tile_size} px")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
