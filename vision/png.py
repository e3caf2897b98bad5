"""PNG files of frames, read and written by Pillow (PNG specification, W3C 2003; Pillow's PngImagePlugin).

:func:`encode_png` writes 8-bit RGB or grey frames; :func:`decode_png` reads a frame a client
sent, bounded against hostile files before anything is inflated (its doc). Nothing here parses
the format: the signature and the header's size are read through Pillow's ``Image.open``, which
reads the chunks before the image data and stops there; ``load()`` then inflates exactly the
scanlines the header implies.
"""

from __future__ import annotations

import io
import zlib

import numpy as np
from PIL import Image, PngImagePlugin

from .errors import VisionInputError

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Default bounds of :func:`decode_png`: pixels a side, and pixels in all.
MAX_DECODE_SIDE_PX, MAX_DECODE_PIXELS = 4096, 4096 * 4096
#: Pillow's modes of a decoded PNG -> the array the estimator reads: "P" (palette) goes to RGB,
#: "1" (1-bit grey) to 8-bit grey; Pillow reads 1-4 bit grey as "L" scaled to 0-255 and 16-bit
#: grey as "I;16"; 16-bit colour it reads at 8 bits a channel (the high byte), 16-bit grey + alpha as RGBA.
_CONVERT = {"P": "RGB", "PA": "RGBA", "1": "L"}
#: What Pillow raises on a file it cannot read (a truncated or corrupt stream, a bad chunk or CRC,
#: an unknown filter type).
_PILLOW_ERRORS = (OSError, SyntaxError, ValueError, EOFError, IndexError, zlib.error)


def encode_png(image: np.ndarray, level: int = 6) -> bytes:
    """PNG bytes of a uint8 image, (H, W) grey or (H, W, 3) RGB, zlib level ``level``."""
    a = np.asarray(image)
    if a.dtype != np.uint8 or a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != 3):
        raise VisionInputError(f"must be uint8 (H, W) or (H, W, 3), got {a.dtype} {a.shape}", "image")
    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(a)).save(out, format="PNG", compress_level=level)  # uint8: L or RGB
    return out.getvalue()


def decode_png(data: bytes, *, field: str = "image", max_side_px: int = MAX_DECODE_SIDE_PX,
               max_pixels: int = MAX_DECODE_PIXELS) -> np.ndarray:
    """The pixels of a PNG file: (H, W) grey, (H, W, 2) grey + alpha, (H, W, 3) RGB or (H, W, 4)
    RGBA; uint8, or uint16 for 16-bit grey (16-bit colour is read at 8 bits a channel, and 16-bit
    grey + alpha as RGBA with the grey in R, G and B: Pillow's reading, the same BT.601 luma); palette
    images expanded to RGB (an index beyond the palette is refused), grey levels of 1-4 bits
    scaled to 0-255. Every colour type, bit depth and interlacing of the specification;
    ancillary chunks are ignored.

    Safe on hostile input: the size in the header is checked against ``max_side_px`` and
    ``max_pixels`` (never more than Pillow's decompression-bomb limit, ``Image.MAX_IMAGE_PIXELS``)
    before anything is inflated, and inflation stops at the scanlines the header implies: data
    beyond them is never inflated, so a decompression bomb costs no more memory than an honest
    file of its size. Compressed text chunks are bounded by Pillow
    (``PngImagePlugin.MAX_TEXT_CHUNK`` each, ``MAX_TEXT_MEMORY`` in all). Anything that is not a
    valid PNG raises :class:`VisionInputError` naming ``field``, with Pillow's reason.
    """
    data = bytes(data)
    if not data:
        raise VisionInputError("is empty (0 bytes)", field)
    if not data.startswith(_SIGNATURE):
        raise VisionInputError("is not a PNG image (it does not start with the PNG signature)", field)
    if Image.MAX_IMAGE_PIXELS:
        max_pixels = min(max_pixels, int(Image.MAX_IMAGE_PIXELS))
    try:
        # the PNG reader itself (Image.open would hide its reason behind "cannot identify image file")
        with PngImagePlugin.PngImageFile(io.BytesIO(data)) as image:
            width, height = image.size
            if not (1 <= width <= max_side_px and 1 <= height <= max_side_px) or width * height > max_pixels:
                raise VisionInputError(f"is {width} x {height} pixels: at most {max_side_px} a side and "
                                       f"{max_pixels} pixels are accepted", field)
            image.load()
            if image.mode == "P":
                _check_palette(image, field)
            pixels = np.array(image.convert(_CONVERT[image.mode]) if image.mode in _CONVERT else image)
    except VisionInputError:
        raise
    except _PILLOW_ERRORS as exc:
        reason = str(exc) or type(exc).__name__
        if "not identified by this driver" in reason:  # Pillow's words for a header it cannot read
            reason = "an invalid header: size, bit depth, colour type or chunk order"
        raise VisionInputError(f"is not a valid PNG ({reason})", field) from None
    if pixels.dtype not in (np.uint8, np.uint16):  # 16-bit grey in a 32-bit mode ("I") on some Pillows
        pixels = pixels.astype(np.uint16)
    return pixels


def _check_palette(image: Image.Image, field: str) -> None:
    """A palette image uses only entries its palette has (Pillow pads a short palette with black)."""
    palette = image.getpalette() or []
    entries = len(palette) // 3
    used = image.getextrema()[1]
    if "transparency" not in image.info and used >= entries:
        raise VisionInputError(f"uses palette entry {used} of {entries}", field)
