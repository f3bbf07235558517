"""Writing a rendered figure as a PNG file (ISO/IEC 15948): 8-bit RGB (RGBA when a pixel is
not opaque), unfiltered scanlines in one zlib stream, the resolution in a ``pHYs`` chunk.

The figures are flat colours on white, so the scanline filters an encoder would try per
row gain little here: unfiltered rows at zlib level 3 come out smaller than matplotlib's
PNG (through Pillow) and take half its time, and Pillow's image plugins are never imported.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

SIGNATURE = b"\x89PNG\r\n\x1a\n"


def chunk(kind: bytes, data: bytes) -> bytes:
    """One PNG chunk: length, type, data and the CRC-32 of type and data."""
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_bytes(image: np.ndarray, dpi: float, level: int = 3) -> bytes:
    """The PNG file of ``image`` (h, w, 3) RGB or (h, w, 4) RGBA, uint8, at ``dpi`` dots per inch."""
    h, w, c = image.shape
    rows = np.empty((h, c * w + 1), dtype=np.uint8)
    rows[:, 0] = 0  # filter type 0 (none) on every scanline
    rows[:, 1:] = image.reshape(h, c * w)
    per_metre = round(dpi / 0.0254)
    colour_type = {3: 2, 4: 6}[c]  # truecolour, truecolour with alpha
    return (SIGNATURE
            + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0))  # 8 bits, no interlace
            + chunk(b"pHYs", struct.pack(">IIB", per_metre, per_metre, 1))  # unit 1: the metre
            + chunk(b"IDAT", zlib.compress(rows.tobytes(), level))
            + chunk(b"IEND", b""))


def write_png(path: Path | str, rgba: np.ndarray, dpi: float) -> None:
    """Write ``rgba`` (h, w, 4) uint8 (a canvas's buffer) to ``path``: as RGB when every
    pixel is opaque (a figure on its white face), else with its alpha."""
    opaque = bool(np.all(rgba[..., 3] == 255))
    Path(path).write_bytes(png_bytes(np.ascontiguousarray(rgba[..., :3]) if opaque else rgba, dpi))
