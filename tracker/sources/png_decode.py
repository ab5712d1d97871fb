"""A PNG decoder for the recordings' own images: zlib inflate (ISA-L's when the ``isal`` package is there) and the
five PNG row filters undone by one compiled loop.

Reading a recording frame is mostly PNG decoding (OpenCV's libpng: about 5.5 ms for a 640×480 colour image and
3 ms for a 16-bit depth image on this project's machines, two thirds of it in zlib's inflate). The images a
:class:`~tracker.sources.recording.RecordingWriter` writes are plain PNGs — 8-bit RGB colour, 16-bit grey depth,
non-interlaced — and for those this module gives the same pixels (a PNG decodes to one image: the filters are exact
byte arithmetic) in about half the time: ISA-L's inflate is about twice as fast as zlib's, and the colour comes out
in RGB order without the BGR round trip.

:func:`decode_png` handles 8-bit grey, RGB and RGBA and 16-bit grey images without interlacing, palette or
transparency chunks; for anything else, or any inconsistency (a bad signature, a truncated or corrupt stream, a
data length that does not match the header), it returns None and the caller falls back to OpenCV, which also gives
the error for a corrupt file. Chunk CRCs are not checked (zlib's Adler-32 of the image data is).
"""

from __future__ import annotations

import struct

import numba as nb
import numpy as np

try:  # ISA-L's inflate: the same bytes as zlib's, about twice as fast
    from isal import isal_zlib as _zlib
except ImportError:  # pragma: no cover - the standard library's, as fast as OpenCV's
    import zlib as _zlib

SIGNATURE = b"\x89PNG\r\n\x1a\n"
"""The eight bytes every PNG file starts with."""
ZLIB_MODULE = _zlib.__name__
"""Which inflate is used (``isal.isal_zlib`` or ``zlib``)."""

_CHANNELS = {0: 1, 2: 3, 6: 4}
"""PNG colour type → channels for the types handled here (grey, RGB, RGBA)."""
_HARMLESS = frozenset((b"pHYs", b"tEXt", b"zTXt", b"iTXt", b"tIME"))
"""Ancillary chunks that do not change the decoded pixels (OpenCV's decoder ignores them); any other chunk than
these, IHDR, IDAT and IEND sends the image to OpenCV."""


def decode_png(data: bytes | bytearray | memoryview | np.ndarray) -> np.ndarray | None:
    """Pixels of a PNG file's bytes ``data``: (H, W) for grey, (H, W, 3) RGB, (H, W, 4) RGBA, uint8 or (16-bit
    grey) native uint16; None when the file is not one this decoder handles (see the module docstring) or is
    corrupt. Channel order as stored in the PNG (RGB), unlike OpenCV's BGR."""
    buf = memoryview(data).cast("B") if not isinstance(data, np.ndarray) else memoryview(data.reshape(-1))
    n = len(buf)
    if n < 8 + 25 or bytes(buf[:8]) != SIGNATURE:
        return None
    pos = 8
    header = None
    idat: list[memoryview] = []
    ended = False
    while pos + 8 <= n:
        length, kind = struct.unpack(">I4s", buf[pos:pos + 8])
        start = pos + 8
        stop = start + length
        if stop + 4 > n:
            return None
        if kind == b"IHDR":
            if header is not None or length != 13:
                return None
            header = struct.unpack(">IIBBBBB", buf[start:stop])
        elif kind == b"IDAT":
            idat.append(buf[start:stop])
        elif kind == b"IEND":
            ended = True
            break
        elif kind not in _HARMLESS:
            return None
        pos = stop + 4
    if header is None or not idat or not ended:
        return None
    width, height, depth, colour, compression, filtering, interlace = header
    channels = _CHANNELS.get(colour)
    if (channels is None or compression != 0 or filtering != 0 or interlace != 0 or width == 0 or height == 0
            or not (depth == 8 or (depth == 16 and colour == 0))):
        return None
    bpp = channels * depth // 8
    stride = width * bpp
    try:
        # one byte more than the image data: a buffer that the stream fills exactly is grown and inflated again
        raw = _zlib.decompress(idat[0] if len(idat) == 1 else b"".join(idat), 15, height * (stride + 1) + 1)
    except Exception:  # noqa: BLE001 - a corrupt stream: OpenCV reports it
        return None
    if len(raw) != height * (stride + 1):
        return None
    out = np.empty((height, stride), np.uint8)
    if not _unfilter(np.frombuffer(raw, np.uint8), height, stride, bpp, out):  # without the GIL, as OpenCV's
        return None
    if depth == 16:
        return out.view(">u2").astype(np.uint16)
    return out.reshape(height, width) if channels == 1 else out.reshape(height, width, channels)


@nb.njit(cache=True, nogil=True)
def _unfilter(raw, height, stride, bpp, out):
    """Undo the PNG row filters (ISO/IEC 15948 section 9): ``raw`` holds ``height`` rows of a filter-type byte
    and ``stride`` filtered bytes, ``bpp`` bytes per pixel (at least 1); the reconstructed rows go to ``out``
    (height, stride) uint8. False for an unknown filter type."""
    for y in range(height):
        src = y * (stride + 1)
        ftype = raw[src]
        src += 1
        if ftype == 0:
            for x in range(stride):
                out[y, x] = raw[src + x]
        elif ftype == 1:  # Sub: + the byte one pixel to the left
            if bpp == 3:  # RGB: the three running sums in registers
                r = np.uint8(0)
                g = np.uint8(0)
                b = np.uint8(0)
                for x in range(0, stride, 3):
                    r = np.uint8(r + raw[src + x])
                    g = np.uint8(g + raw[src + x + 1])
                    b = np.uint8(b + raw[src + x + 2])
                    out[y, x] = r
                    out[y, x + 1] = g
                    out[y, x + 2] = b
            else:
                for x in range(bpp):
                    out[y, x] = raw[src + x]
                for x in range(bpp, stride):
                    out[y, x] = (raw[src + x] + out[y, x - bpp]) & 255
        elif ftype == 2:  # Up: + the byte above
            if y == 0:
                for x in range(stride):
                    out[y, x] = raw[src + x]
            else:
                for x in range(stride):
                    out[y, x] = (raw[src + x] + out[y - 1, x]) & 255
        elif ftype == 3:  # Average: + floor((left + above) / 2)
            for x in range(stride):
                a = np.int32(out[y, x - bpp]) if x >= bpp else np.int32(0)
                b = np.int32(out[y - 1, x]) if y > 0 else np.int32(0)
                out[y, x] = (np.int32(raw[src + x]) + ((a + b) >> 1)) & 255
        elif ftype == 4:  # Paeth: + the one of left, above, upper left nearest to left + above − upper left
            for x in range(stride):
                a = np.int32(out[y, x - bpp]) if x >= bpp else np.int32(0)
                b = np.int32(out[y - 1, x]) if y > 0 else np.int32(0)
                c = np.int32(out[y - 1, x - bpp]) if (x >= bpp and y > 0) else np.int32(0)
                p = a + b - c
                pa = abs(p - a)
                pb = abs(p - b)
                pc = abs(p - c)
                if pa <= pb and pa <= pc:
                    pr = a
                elif pb <= pc:
                    pr = b
                else:
                    pr = c
                out[y, x] = (np.int32(raw[src + x]) + pr) & 255
        else:
            return False
    return True
