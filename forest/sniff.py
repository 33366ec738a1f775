"""What a file is, from its first bytes: so that a file of the wrong kind is answered with one
line naming it ("is glTF, not USD") before a reader that prints its own errors opens it.

The suffix is not trusted: a renamed file is named by its content, and the message says so.
"""

from __future__ import annotations

from pathlib import Path

from forest.errors import ForestError

# magic bytes -> (kind, its usual suffixes); the first match wins, so longer magics first
_MAGIC: tuple[tuple[bytes, str], ...] = (
    (b"PXR-USDC", "usdc"),
    (b"#usda", "usda"),
    (b"glTF", "glb"),
    (b"\x89PNG\r\n\x1a\n", "png"),
    (b"\xff\xd8\xff", "jpeg"),
    (b"II*\x00", "tiff"),
    (b"MM\x00*", "tiff"),
    (b"v/1\x01", "exr"),
    (b"GIF8", "gif"),
    (b"RIFF", "riff"),
    (b"\x1a\x45\xdf\xa3", "webm"),
    (b"%PDF", "pdf"),
    (b"\x1f\x8b", "gzip"),
    (b"\x7fELF", "elf"),
)
_NAMES = {
    "usdc": "a USD crate file (.usdc)",
    "usda": "a USD text file (.usda)",
    "usdz": "a USDZ package (.usdz)",
    "glb": "glTF (binary .glb)",
    "gltf": "glTF (JSON .gltf)",
    "json": "JSON",
    "png": "a PNG image",
    "jpeg": "a JPEG image",
    "tiff": "a TIFF image",
    "exr": "an OpenEXR image",
    "gif": "a GIF image",
    "riff": "a RIFF file (WebP image or WAV/AVI)",
    "webm": "a Matroska/WebM video",
    "mp4": "an MP4 video",
    "pdf": "a PDF document",
    "gzip": "a gzip archive",
    "zip": "a zip archive",
    "elf": "a program (ELF binary)",
    "text": "a text file",
    "empty": "empty",
    "binary": "a binary file of unknown kind",
    "folder": "a folder",
}
USD_KINDS = frozenset({"usda", "usdc", "usdz"})
USD_SUFFIXES = ".usd/.usda/.usdc/.usdz"
USD_READERS = {c: f"{c} reads {USD_SUFFIXES}" for c in ("render", "inspect")}
IMAGE_KINDS = frozenset({"png", "jpeg", "tiff", "exr", "gif", "riff"})
# kinds that are surely no image (OpenImageIO reads many formats this module does not name)
NOT_IMAGE_KINDS = frozenset(
    {"usdc", "usda", "usdz", "glb", "gltf", "json", "zip", "pdf", "gzip", "elf", "mp4", "webm"}
)
HEAD_BYTES = 512


def sniff_bytes(head: bytes) -> str:
    """The kind of a file whose first bytes are ``head`` (up to :data:`HEAD_BYTES`)."""
    if not head:
        return "empty"
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return kind
    if head[4:8] == b"ftyp":
        return "mp4"
    if head.startswith(b"PK\x03\x04"):
        # a usdz is a zip whose first member is a USD layer (the USDZ spec asks for it first)
        name_len = int.from_bytes(head[26:28], "little")
        first = head[30 : 30 + name_len].decode("utf-8", "replace").lower()
        return "usdz" if first.endswith((".usda", ".usdc", ".usd")) else "zip"
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if text.startswith((b"{", b"[")):
        return "gltf" if b'"asset"' in head and b'"version"' in head else "json"
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:
        # a multi-byte character cut at the end of the sample is still text
        if exc.start < len(head) - 4:
            return "binary"
    return "binary" if b"\x00" in head else "text"


def sniff(path: str | Path) -> str:
    """The kind of the file at ``path``: one of :data:`_NAMES`' keys. Raises ForestError
    naming the path when it does not exist or cannot be read."""
    p = Path(path)
    if p.is_dir():
        return "folder"
    try:
        with p.open("rb") as f:
            return sniff_bytes(f.read(HEAD_BYTES))
    except FileNotFoundError:
        raise ForestError("no such file", path=str(p)) from None
    except OSError as exc:
        raise ForestError(f"cannot read: {exc.strerror or exc}", path=str(p)) from None


def describe(kind: str) -> str:
    return _NAMES.get(kind, kind)


def require_kind(
    path: str | Path,
    allowed: frozenset[str],
    wanted: str,
    reader: str,
    error: type[ForestError] = ForestError,
) -> str:
    """The file's kind, or a ForestError of one line such as ``pine.glb: is glTF (binary .glb),
    not USD; render reads .usd/.usda/.usdc/.usdz``.

    ``wanted`` names what the reader takes ("USD"), ``reader`` the command and the suffixes
    it reads ("render reads .usd/.usda/.usdc/.usdz")."""
    kind = sniff(path)
    if kind not in allowed:
        raise error(f"is {describe(kind)}, not {wanted}; {reader}", path=str(path))
    return kind


def require_usd(path: str | Path, reader: str, error: type[ForestError] = ForestError) -> str:
    """``reader``: e.g. ``"render reads .usd/.usda/.usdc/.usdz"``."""
    return require_kind(path, USD_KINDS, "USD", reader, error)
