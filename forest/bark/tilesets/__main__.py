"""``python -m forest.bark.tilesets [NAME ...]``: rebuild the shipped tile sets (all of
:data:`forest.bark.tilesets.SETS` by default) into the package."""

from __future__ import annotations

import sys

from forest.bark.tilesets import SETS, make_set, set_dir


def main(argv: list[str]) -> int:
    names = argv or list(SETS)
    unknown = [n for n in names if n not in SETS]
    if unknown:
        print(f"unknown tile set(s) {', '.join(unknown)}; shipped: {', '.join(SETS)}")
        return 2
    for name in names:
        folder = set_dir(name)
        ts = make_set(name, folder)
        print(f"wrote {folder}: {len(ts.tiles)} tiles of {ts.manifest.tile_size} px")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
