"""PNG encoding of rendered frames (8-bit RGB or grey), and a small, safe PNG decoder.

A PNG is a signature, an IHDR chunk (size, bit depth 8, colour type 2 RGB or 0 grey), IDAT
chunks holding the zlib-deflated scanlines (each prefixed by its filter type, 0 = none), and
IEND; each chunk is length, type, data, CRC-32 of type + data (PNG specification, W3C 2003).
The decoder (:func:`decode_png`) reads every PNG the specification allows, bounded against
hostile files (its doc); its scanline unfiltering is compiled (numba, in :mod:`vision.kernels`), the
rest numpy and zlib.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from .errors import VisionInputError
from .kernels import png_unfilter

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


# ----------------------------------------------------------------- decoding
#: Colour types (PNG spec 11.2.2): channels and the bit depths allowed for each.
_COLOUR_TYPES = {0: (1, (1, 2, 4, 8, 16)), 2: (3, (8, 16)), 3: (1, (1, 2, 4, 8)), 4: (2, (8, 16)), 6: (4, (8, 16))}
#: Adam7 passes (PNG spec 8.2): first row, first column, row step, column step.
_ADAM7 = ((0, 0, 8, 8), (0, 4, 8, 8), (4, 0, 8, 4), (0, 2, 4, 4), (2, 0, 4, 2), (0, 1, 2, 2), (1, 0, 2, 1))
#: Default bounds of :func:`decode_png`: pixels a side, and pixels in all.
MAX_DECODE_SIDE_PX, MAX_DECODE_PIXELS = 4096, 4096 * 4096


def _chunks(data: bytes, field: str):
    """(type, payload) of every chunk after the signature, CRCs checked (PNG spec 5.3)."""
    pos = len(_SIGNATURE)
    while pos < len(data):
        if pos + 12 > len(data):
            raise VisionInputError("is truncated (a chunk header runs past the end of the data)", field)
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind = data[pos + 4:pos + 8]
        if length > 2**31 - 1 or pos + 12 + length > len(data):
            raise VisionInputError(f"is truncated (chunk {kind!r} of {length} bytes runs past the end)", field)
        payload = data[pos + 8:pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length:pos + 12 + length])
        if zlib.crc32(kind + payload) & 0xFFFFFFFF != crc:
            raise VisionInputError(f"is corrupt (CRC mismatch in chunk {kind!r})", field)
        yield kind, payload
        pos += 12 + length


def decode_png(data: bytes, *, field: str = "image", max_side_px: int = MAX_DECODE_SIDE_PX,
               max_pixels: int = MAX_DECODE_PIXELS) -> np.ndarray:
    """The pixels of a PNG file: (H, W) grey, (H, W, 2) grey + alpha, (H, W, 3) RGB or (H, W, 4)
    RGBA; uint8, or uint16 for 16-bit files; palette images expanded to RGB, grey levels of 1-4
    bits scaled to 0-255 (PNG spec 12.5). Every colour type, bit depth and interlacing of the
    specification; ancillary chunks (gamma, transparency, text) are ignored.

    Safe on hostile input: the size in the header is checked against ``max_side_px`` and
    ``max_pixels`` before anything is inflated, and inflation stops one byte past the size the
    header implies (a decompression bomb costs no more memory than an honest file). Anything
    else that is not a valid PNG (bad signature, CRC, header, filter type, data too short or too
    long) raises :class:`VisionInputError` naming ``field``.
    """
    data = bytes(data)
    if not data:
        raise VisionInputError("is empty (0 bytes)", field)
    if not data.startswith(_SIGNATURE):
        raise VisionInputError("is not a PNG image (it does not start with the PNG signature)", field)
    header = None
    palette = None
    idat: list[bytes] = []
    ended = False
    for kind, payload in _chunks(data, field):
        if header is None and kind != b"IHDR":
            raise VisionInputError(f"is not a valid PNG (the first chunk is {kind!r}, not IHDR)", field)
        if kind == b"IHDR":
            if header is not None or len(payload) != 13:
                raise VisionInputError("is not a valid PNG (a second or malformed IHDR chunk)", field)
            header = struct.unpack(">IIBBBBB", payload)
            _check_header(header, field, max_side_px, max_pixels)
        elif kind == b"PLTE":
            if len(payload) % 3 or not 3 <= len(payload) <= 768:
                raise VisionInputError(f"has a malformed palette ({len(payload)} bytes)", field)
            palette = np.frombuffer(payload, np.uint8).reshape(-1, 3)
        elif kind == b"IDAT":
            idat.append(payload)
        elif kind == b"IEND":
            ended = True
            break
        elif not kind[:1].isalpha() or kind[:1].isupper():  # an unknown critical chunk (spec 5.4)
            raise VisionInputError(f"has an unknown critical chunk {kind!r}", field)
    if header is None or not ended:
        raise VisionInputError("is truncated (no IHDR or no IEND chunk)", field)
    if not idat:
        raise VisionInputError("holds no image data (no IDAT chunk)", field)
    width, height, depth, colour, _, _, interlace = header
    channels = _COLOUR_TYPES[colour][0]
    if colour == 3 and palette is None:
        raise VisionInputError("is a palette image without a palette (PLTE chunk)", field)
    bits = channels * depth
    passes = [(height, width, 0, 0, 1, 1)] if interlace == 0 else [
        (-(-(height - r0) // dr), -(-(width - c0) // dc), r0, c0, dr, dc) for r0, c0, dr, dc in _ADAM7]
    passes = [p for p in passes if p[0] > 0 and p[1] > 0]
    expected = sum(h * (1 + (w * bits + 7) // 8) for h, w, *_ in passes)
    inflater = zlib.decompressobj()
    try:
        raw = inflater.decompress(b"".join(idat), expected + 1)
    except zlib.error as exc:
        raise VisionInputError(f"has corrupt compressed data ({exc})", field) from None
    if len(raw) != expected or inflater.unconsumed_tail:
        raise VisionInputError(f"holds {'more' if len(raw) > expected else 'less'} image data than its "
                               f"{width} x {height} header implies", field)
    samples = np.empty((height, width, channels), np.uint16 if depth == 16 else np.uint8)
    raw_arr = np.frombuffer(raw, np.uint8)
    start = 0
    for h, w, r0, c0, dr, dc in passes:
        stride = (w * bits + 7) // 8
        rows = np.empty((h, stride), np.uint8)
        bad = png_unfilter(raw_arr[start:start + h * (stride + 1)], h, stride, max(1, bits // 8), rows)
        if bad >= 0:
            raise VisionInputError(f"has an unknown filter type on scanline {bad}", field)
        samples[r0::dr, c0::dc] = _unpack(rows, w, channels, depth)
        start += h * (stride + 1)
    if colour == 3:
        index = samples[..., 0]
        if int(index.max()) >= len(palette):
            raise VisionInputError(f"uses palette entry {int(index.max())} of {len(palette)}", field)
        return palette[index]
    if depth < 8:
        samples = samples * np.uint8(255 // (2**depth - 1))
    return samples[..., 0] if channels == 1 else samples


def _check_header(header: tuple, field: str, max_side_px: int, max_pixels: int) -> None:
    width, height, depth, colour, compression, filtering, interlace = header
    if colour not in _COLOUR_TYPES or depth not in _COLOUR_TYPES[colour][1]:
        raise VisionInputError(f"has an invalid colour type {colour} / bit depth {depth}", field)
    if compression != 0 or filtering != 0 or interlace not in (0, 1):
        raise VisionInputError(f"has an invalid header (compression {compression}, filter {filtering}, "
                               f"interlace {interlace})", field)
    if not (1 <= width <= max_side_px and 1 <= height <= max_side_px) or width * height > max_pixels:
        raise VisionInputError(f"is {width} x {height} pixels: at most {max_side_px} a side and {max_pixels} "
                               "pixels are accepted", field)


def _unpack(rows: np.ndarray, width: int, channels: int, depth: int) -> np.ndarray:
    """Samples (h, width, channels) of unfiltered scanlines (PNG spec 7.2: big-endian, packed MSB first)."""
    if depth == 8:
        return rows[:, :width * channels].reshape(len(rows), width, channels)
    if depth == 16:
        return rows[:, :2 * width * channels].view(">u2").astype(np.uint16).reshape(len(rows), width, channels)
    bits = np.unpackbits(rows, axis=1)[:, :width * depth].reshape(len(rows), width, depth)
    weights = (1 << np.arange(depth - 1, -1, -1)).astype(np.uint8)
    return (bits * weights).sum(axis=2, dtype=np.uint8)[..., None]
