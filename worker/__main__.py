"""``python -m worker -Q default,gpu``: what ``forest worker`` runs (used by ``forest serve``)."""

import sys

from forest.cli import main

if __name__ == "__main__":
    main(["worker", *sys.argv[1:]])
