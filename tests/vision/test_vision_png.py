"""Reading PNG frames (vision.png.decode_png: Pillow, bounded) against files it did not write.

Oracles: SimpleITK's PNG writer (libpng; 8- and 16-bit grey, RGB), and files assembled in this
test by a pure-Python encoder written from the PNG specification (every filter type, Adam7
interlacing, palettes, 1-4 bit grey) that shares no code with the reader. Exact equality of
every sample throughout: PNG is lossless (16-bit colour is read at 8 bits a channel, documented:
the expected samples are the high bytes).
"""

from __future__ import annotations

import struct
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
    if depth == 16 and channels > 1:  # Pillow reads 16-bit colour (and grey + alpha) at 8 bits: the high byte
        img = img >> 8
        if channels == 2:  # and 16-bit grey + alpha as RGBA (the same luma, see vision.png)
            img = img[..., [0, 0, 0, 1]]
    assert decoded.dtype == (np.uint16 if depth == 16 and channels == 1 else np.uint8)
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


BOMB_PROBE = """
import resource, struct, sys, zlib
import numpy as np
from vision.png import decode_png
def chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
def png(idat):
    return (b"\\x89PNG\\r\\n\\x1a\\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 16, 16, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", idat) + chunk(b"IEND", b""))
honest = png(zlib.compress(bytes(16 * 17)))
deflate = zlib.compressobj(9)  # the bomb made by streaming: 200 MB of zeros never sit in this process
block = bytes(1 << 20)
bomb = png(b"".join([deflate.compress(block) for _ in range(int(sys.argv[1]))] + [deflate.flush()]))
assert decode_png(honest).shape == (16, 16)   # everything imported and warmed on an honest file
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
try:
    pixels = decode_png(bomb)
    print("decoded", pixels.shape, int(pixels.max()))
except Exception as exc:
    print("refused", type(exc).__name__)
print("grew_kib", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before)
"""


def test_decompression_bomb_costs_no_more_than_an_honest_file():
    """A 16 x 16 header over 200 MiB of zeros (a 200 kB IDAT): only the 16 x 17 bytes the header
    implies are inflated, so it decodes as its header says (or is refused) and the process's peak
    memory (ru_maxrss, in a fresh interpreter: Pillow's buffers are not Python objects) grows by
    far less than the 200 MiB a decoder inflating the whole stream would need. The 200 MiB bomb
    against a 2 MiB one: the growth does not scale with the bomb."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    grown = {}
    for size in (2, 200):  # MiB of zeros
        out = subprocess.run([sys.executable, "-c", BOMB_PROBE, str(size)], cwd=root, capture_output=True, text=True,
                             timeout=300)
        assert out.returncode == 0, out.stderr[-3000:]
        lines = out.stdout.split("\n")
        assert lines[0] in ("decoded (16, 16) 0", "refused VisionInputError"), out.stdout
        grown[size] = int(lines[1].split()[1])
    # 20 MiB: an order of magnitude below the bomb's 190 MiB, far above allocator noise (~1 MiB)
    assert grown[200] < 20 * 1024, grown
    assert grown[200] < grown[2] + 5 * 1024, grown


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
    (good()[:-30], "truncated"),  # into the compressed scanlines
    (good()[:40] + bytes([good()[40] ^ 1]) + good()[41:], "checksum"),  # the IDAT chunk's type: its CRC fails
    (good()[:45] + bytes([good()[45] ^ 1]) + good()[46:], "not a valid PNG"),  # its compressed data
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 2, 0, 0, 0))[:-4] + b"\0\0\0\0", "checksum"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 3, 0, 0, 0, 0)) + chunk(b"IEND", b""), "invalid header"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 2)) + chunk(b"IEND", b""), "not a valid PNG"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 0, 8, 8, 0, 0, 0, 0)) + chunk(b"IEND", b""), "invalid header"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 0)) + chunk(b"IEND", b""), "not a valid PNG"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 0)) + chunk(b"IDAT", b"junk")
     + chunk(b"IEND", b""), "broken data stream"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 0))
     + chunk(b"IDAT", zlib.compress(bytes(9 * 8 - 5))) + chunk(b"IEND", b""), "truncated"),  # less than the size
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 2, 1, 8, 0, 0, 0, 0))
     + chunk(b"IDAT", zlib.compress(b"\x07\x00\x00")) + chunk(b"IEND", b""), "not a valid PNG"),  # filter type 7
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 2, 1, 8, 3, 0, 0, 0))
     + chunk(b"IDAT", zlib.compress(b"\x00\x00\x00")) + chunk(b"IEND", b""), "palette entry 0 of 0"),  # no PLTE
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 2, 1, 8, 3, 0, 0, 0)) + chunk(b"PLTE", bytes(3))
     + chunk(b"IDAT", zlib.compress(b"\x00\x00\x05")) + chunk(b"IEND", b""), "palette entry 5 of 1"),
    (SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 0)) + chunk(b"XXXX", b"")
     + chunk(b"IEND", b""), "not a valid PNG"),
    (SIG + chunk(b"IDAT", b"") + chunk(b"IEND", b""), "invalid header"),  # no IHDR first
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
