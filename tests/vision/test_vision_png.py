"""The PNG decoder (vision.png.decode_png) against files it did not write.

Oracles: SimpleITK's PNG writer (libpng; 8- and 16-bit grey, RGB), and files assembled in this
test by a pure-Python encoder written from the PNG specification (every filter type, Adam7
interlacing, palettes, 1-4 bit grey) that shares no code with the decoder. Exact equality of
every sample throughout: PNG is lossless.
"""

from __future__ import annotations

import struct
import tracemalloc
import zlib

import numpy as np
import pytest
import SimpleITK as sitk

from vision.errors import VisionInputError
from vision.png import decode_png, encode_png

SIG = b"\x89PNG\r\n\x1a\n"


def chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def paeth(a: int, b: int, c: int) -> int:
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else (b if pb <= pc else c)


def filter_rows(rows: list[bytes], bpp: int, kinds: list[int]) -> bytes:
    """Forward PNG filtering (spec 9.2), byte by byte, filter ``kinds[y % len(kinds)]`` on row y."""
    out = bytearray()
    prev = bytes(len(rows[0])) if rows else b""
    for y, row in enumerate(rows):
        kind = kinds[y % len(kinds)]
        out.append(kind)
        for x, v in enumerate(row):
            a = row[x - bpp] if x >= bpp else 0
            b = prev[x]
            c = prev[x - bpp] if x >= bpp else 0
            pred = [0, a, b, (a + b) // 2, paeth(a, b, c)][kind]
            out.append((v - pred) % 256)
        prev = row
    return bytes(out)


def scanlines(img: np.ndarray, depth: int) -> list[bytes]:
    """Rows of samples (H, W, C) packed as PNG stores them (big-endian, MSB first)."""
    h, w, c = img.shape
    rows = []
    for y in range(h):
        if depth == 16:
            rows.append(b"".join(struct.pack(">H", int(v)) for v in img[y].ravel()))
        elif depth == 8:
            rows.append(bytes(int(v) for v in img[y].ravel()))
        else:
            bits = "".join(format(int(v), f"0{depth}b") for v in img[y].ravel())
            bits += "0" * (-len(bits) % 8)
            rows.append(bytes(int(bits[i:i + 8], 2) for i in range(0, len(bits), 8)))
    return rows


def make_png(img: np.ndarray, colour: int, depth: int, *, interlace: bool = False, kinds=(0, 1, 2, 3, 4),
             palette: bytes | None = None, split_idat: int = 1, extra: list[tuple[bytes, bytes]] = ()) -> bytes:
    img = img if img.ndim == 3 else img[..., None]
    h, w, c = img.shape
    bpp = max(1, c * depth // 8)
    if interlace:
        passes = ((0, 0, 8, 8), (0, 4, 8, 8), (4, 0, 8, 4), (0, 2, 4, 4), (2, 0, 4, 2), (0, 1, 2, 2), (1, 0, 2, 1))
        raw = b"".join(filter_rows(scanlines(img[r::dr, c0::dc], depth), bpp, list(kinds))
                       for r, c0, dr, dc in passes if img[r::dr, c0::dc].size)
    else:
        raw = filter_rows(scanlines(img, depth), bpp, list(kinds))
    z = zlib.compress(raw)
    parts = [z[i * len(z) // split_idat:(i + 1) * len(z) // split_idat] for i in range(split_idat)]
    out = SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, int(interlace)))
    for kind, data in extra:
        out += chunk(kind, data)
    if palette is not None:
        out += chunk(b"PLTE", palette)
    out += b"".join(chunk(b"IDAT", p) for p in parts) + chunk(b"IEND", b"")
    return out


RNG = np.random.default_rng(7)


@pytest.mark.parametrize("colour, depth, channels", [(0, 8, 1), (0, 16, 1), (2, 8, 3), (2, 16, 3), (4, 8, 2),
                                                     (4, 16, 2), (6, 8, 4), (6, 16, 4)])
@pytest.mark.parametrize("interlace", [False, True])
def test_every_colour_type_filter_and_interlacing(colour, depth, channels, interlace):
    img = RNG.integers(0, 2**depth, size=(13, 11, channels))  # odd sizes: Adam7's partial passes
    decoded = decode_png(make_png(img, colour, depth, interlace=interlace, split_idat=3))
    assert decoded.dtype == (np.uint16 if depth == 16 else np.uint8)
    assert np.array_equal(decoded, img[..., 0] if channels == 1 else img)


@pytest.mark.parametrize("depth", [1, 2, 4])
@pytest.mark.parametrize("interlace", [False, True])
def test_low_bit_grey_scaled_to_full_range(depth, interlace):
    img = RNG.integers(0, 2**depth, size=(9, 14, 1))
    decoded = decode_png(make_png(img, 0, depth, interlace=interlace))
    assert np.array_equal(decoded, img[..., 0] * (255 // (2**depth - 1)))


@pytest.mark.parametrize("depth", [1, 2, 4, 8])
def test_palette_expands_to_rgb(depth):
    n = 2**depth
    pal = RNG.integers(0, 256, size=(n, 3)).astype(np.uint8)
    index = RNG.integers(0, n, size=(10, 7, 1))
    decoded = decode_png(make_png(index, 3, depth, palette=pal.tobytes(),
                                  extra=[(b"gAMA", struct.pack(">I", 45455)), (b"tEXt", b"k\x00v")]))
    assert np.array_equal(decoded, pal[index[..., 0]])


@pytest.mark.parametrize("pixel, dtype, shape", [(sitk.sitkUInt8, np.uint8, (20, 30)),
                                                 (sitk.sitkUInt16, np.uint16, (20, 30)),
                                                 (sitk.sitkVectorUInt8, np.uint8, (20, 30, 3))])
def test_files_written_by_libpng_through_simpleitk(tmp_path, pixel, dtype, shape):
    img = RNG.integers(0, np.iinfo(dtype).max + 1, size=shape).astype(dtype)
    path = tmp_path / "frame.png"
    sitk.WriteImage(sitk.GetImageFromArray(img, isVector=len(shape) == 3), str(path))
    assert np.array_equal(decode_png(path.read_bytes()), img)


def test_round_trip_of_our_encoder():
    img = RNG.integers(0, 256, size=(17, 19, 3)).astype(np.uint8)
    assert np.array_equal(decode_png(encode_png(img)), img)
    assert np.array_equal(decode_png(encode_png(img[..., 0])), img[..., 0])


def test_decompression_bomb_costs_no_more_than_an_honest_file():
    """A 16 x 16 header over 200 MB of zeros (a 200 kB IDAT): refused after inflating 16 x 17 + 1
    bytes, with no large allocation (tracemalloc peak < 1 MB) and at once."""
    bomb = SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 16, 16, 8, 0, 0, 0, 0))
    bomb += chunk(b"IDAT", zlib.compress(bytes(200_000_000), 9)) + chunk(b"IEND", b"")
    tracemalloc.start()
    with pytest.raises(VisionInputError, match="more image data"):
        decode_png(bomb)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 1_000_000


@pytest.mark.parametrize("width, height", [(5000, 10), (3000, 3000)])
def test_size_refused_before_inflating(width, height):
    data = SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)) + chunk(b"IEND", b"")
    with pytest.raises(VisionInputError, match="pixels are accepted") as info:
        decode_png(data, field="reference", max_side_px=4096, max_pixels=2048 * 2048)
    assert info.value.field == "reference"


def good() -> bytes:
    return make_png(RNG.integers(0, 256, size=(8, 8, 1)), 0, 8)


@pytest.mark.parametrize("data, reason", [
    (b"", "empty"),
    (b"GIF89a" + bytes(20), "not a PNG"),
    (b"\xff\xd8\xff\xe0" + bytes(20), "not a PNG"),  # a JPEG
    (good()[:-20], "truncated"),
    (good()[:40] + bytes([good()[40] ^ 1]) + good()[41:], "CRC"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 2, 0, 0, 0))[:-4] + b"\0\0\0\0", "CRC"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 3, 0, 0, 0, 0)) + chunk(b"IEND", b""), "bit depth"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 2)) + chunk(b"IEND", b""), "interlace"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 0, 8, 8, 0, 0, 0, 0)) + chunk(b"IEND", b""), "pixels"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 0)) + chunk(b"IEND", b""), "no IDAT"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 0)) + chunk(b"IDAT", b"junk")
     + chunk(b"IEND", b""), "corrupt compressed"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 0))
     + chunk(b"IDAT", zlib.compress(bytes(9 * 8 - 5))) + chunk(b"IEND", b""), "less image data"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 2, 1, 8, 0, 0, 0, 0))
     + chunk(b"IDAT", zlib.compress(b"\x07\x00\x00")) + chunk(b"IEND", b""), "filter type"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 2, 1, 8, 3, 0, 0, 0))
     + chunk(b"IDAT", zlib.compress(b"\x00\x00\x00")) + chunk(b"IEND", b""), "without a palette"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 2, 1, 8, 3, 0, 0, 0)) + chunk(b"PLTE", bytes(3))
     + chunk(b"IDAT", zlib.compress(b"\x00\x00\x05")) + chunk(b"IEND", b""), "palette entry"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 0)) + chunk(b"XXXX", b"")
     + chunk(b"IEND", b""), "critical chunk"),
    (SIG + chunk(b"IDAT", b"") + chunk(b"IEND", b""), "first chunk"),
])
def test_not_a_valid_png_is_refused_naming_the_field(data, reason):
    with pytest.raises(VisionInputError, match=reason) as info:
        decode_png(data, field="moving")
    assert info.value.field == "moving"


def test_random_bytes_after_the_signature_never_escape_as_another_error():
    rng = np.random.default_rng(3)
    base = good()
    for _ in range(300):
        data = bytearray(base)
        for k in rng.integers(8, len(data), size=3):
            data[k] = rng.integers(0, 256)
        try:
            decode_png(bytes(data))
        except VisionInputError:
            pass
