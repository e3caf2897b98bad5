"""PNG encoding of rendered frames (8-bit RGB or grey), with the standard library only.

A PNG is a signature, an IHDR chunk (size, bit depth 8, colour type 2 RGB or 0 grey), IDAT
chunks holding the zlib-deflated scanlines (each prefixed by its filter type, 0 = none), and
IEND; each chunk is length, type, data, CRC-32 of type + data (PNG specification, W3C 2003).
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from .errors import VisionInputError

_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def encode_png(image: np.ndarray, level: int = 6) -> bytes:
    """PNG bytes of a uint8 image, (H, W) grey or (H, W, 3) RGB."""
    a = np.asarray(image)
    if a.dtype != np.uint8 or a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != 3):
        raise VisionInputError(f"must be uint8 (H, W) or (H, W, 3), got {a.dtype} {a.shape}", "image")
    h, w = a.shape[:2]
    colour = 2 if a.ndim == 3 else 0
    rows = np.ascontiguousarray(a).reshape(h, -1)
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rows], axis=1).tobytes()
    header = struct.pack(">IIBBBBB", w, h, 8, colour, 0, 0, 0)
    return _SIGNATURE + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(raw, level)) + _chunk(b"IEND", b"")
