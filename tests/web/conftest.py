"""The web page's tests reuse the service tests' harness (``forest serve`` in a subprocess)."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "service"))
