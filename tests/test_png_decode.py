"""The recordings' PNG decoder (tracker/sources/png_decode.py) against OpenCV's, the decoder it replaces."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
from PIL import Image

from tracker.geometry.camera import Intrinsics
from tracker.sources.png_decode import decode_png
from tracker.sources.recording import DEPTH_PNG_PARAMS, decode_color, decode_depth

FILTERS = {
    "none": cv2.IMWRITE_PNG_FILTER_NONE, "sub": cv2.IMWRITE_PNG_FILTER_SUB, "up": cv2.IMWRITE_PNG_FILTER_UP,
    "avg": cv2.IMWRITE_PNG_FILTER_AVG, "paeth": cv2.IMWRITE_PNG_FILTER_PAETH, "all": cv2.IMWRITE_PNG_ALL_FILTERS,
}


def _image(shape: tuple, dtype, seed: int) -> np.ndarray:
    """Random pixels with smooth and flat stretches (so that every filter type wins somewhere)."""
    rng = np.random.default_rng(seed)
    top = 256 if dtype == np.uint8 else 65536
    img = rng.integers(0, top, shape).astype(dtype)
    ramp = (np.arange(shape[1]) * (top // shape[1])).astype(dtype)
    img[shape[0] // 3: 2 * shape[0] // 3] = ramp[None, :, None] if img.ndim == 3 else ramp[None, :]
    img[-4:] = img[-5]
    return img


def _opencv(buf: np.ndarray) -> np.ndarray:
    """OpenCV's decoding with the channels put in the PNG's own order (RGB, RGBA)."""
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB if img.shape[2] == 3 else cv2.COLOR_BGRA2RGBA)
    return img


@pytest.mark.parametrize("kind", ["grey", "rgb", "rgba", "grey16"])
@pytest.mark.parametrize("filt", list(FILTERS))
def test_every_filter_type_decodes_as_opencv_does(kind, filt):
    shape, dtype = {"grey": ((23, 41), np.uint8), "rgb": ((23, 41, 3), np.uint8), "rgba": ((23, 41, 4), np.uint8),
                    "grey16": ((23, 41), np.uint16)}[kind]
    img = _image(shape, dtype, seed=len(kind) + 7 * len(filt))
    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_FILTER, FILTERS[filt]])
    assert ok
    got = decode_png(buf)
    assert got is not None
    ref = _opencv(buf)
    assert got.dtype == ref.dtype and got.shape == ref.shape
    assert np.array_equal(got, ref)


@pytest.mark.parametrize("mode", ["RGB", "L", "I;16"])
def test_pillow_encoded_images_with_adaptive_filters_and_split_data(mode):
    """Pillow picks a filter per row and splits the data over several IDAT chunks (small ``compress_level``
    buffers); the pixels are OpenCV's."""
    shape = (61, 77, 3) if mode == "RGB" else (61, 77)
    img = _image(shape, np.uint16 if mode == "I;16" else np.uint8, seed=3)
    out = io.BytesIO()
    Image.fromarray(img, mode=mode if mode != "I;16" else None).save(out, format="PNG", optimize=True)
    buf = np.frombuffer(out.getvalue(), np.uint8)
    got = decode_png(buf)
    assert got is not None
    assert np.array_equal(got, _opencv(buf))
    assert np.array_equal(got, img)


def test_images_it_does_not_handle_are_left_to_opencv():
    rgb = _image((20, 30, 3), np.uint8, seed=1)
    ok, good = cv2.imencode(".png", rgb)
    data = good.tobytes()
    assert decode_png(data) is not None
    assert decode_png(data[: len(data) // 2]) is None  # truncated
    assert decode_png(b"not a png at all") is None
    corrupt = bytearray(data)
    idat = data.index(b"IDAT")
    corrupt[idat + 30: idat + 60] = bytes(30)  # a damaged deflate stream (or its checksum)
    assert decode_png(bytes(corrupt)) is None
    ok, rgb16 = cv2.imencode(".png", rgb.astype(np.uint16) * 200)  # 16-bit colour
    assert decode_png(rgb16) is None
    pal = io.BytesIO()
    Image.fromarray(rgb).convert("P").save(pal, format="PNG")  # palette
    assert decode_png(pal.getvalue()) is None
    trns = io.BytesIO()
    Image.fromarray(rgb).save(trns, format="PNG", transparency=(1, 2, 3))  # a chunk that changes the pixels
    assert b"tRNS" in trns.getvalue()
    assert decode_png(trns.getvalue()) is None
    ok, jpg = cv2.imencode(".jpg", rgb)
    assert decode_png(jpg) is None


def test_recording_images_read_as_before(tmp_path):
    """decode_color / decode_depth give what they gave with OpenCV's decoder (the code replaced: imdecode, then
    BGR → RGB for colour and the units → metres table for depth) for PNGs as the writer encodes them."""
    intr = Intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:480, 0:640]
    rgb = np.stack([(xx // 3) % 256, (yy // 2) % 256, (xx + yy) % 256], axis=-1).astype(np.uint8)
    rgb[100:200, 200:400] = rng.integers(0, 256, (100, 200, 3), dtype=np.uint8)
    units = (600 + (xx + 2 * yy) % 900).astype(np.uint16)
    units[rng.random(units.shape) < 0.05] = 0
    cv2.imwrite(str(tmp_path / "c.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(tmp_path / "d.png"), units, DEPTH_PNG_PARAMS)
    colour = decode_color(tmp_path / "c.png", 0, intr)
    ref_colour = cv2.cvtColor(cv2.imread(str(tmp_path / "c.png"), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGR2RGB)
    assert colour.flags.c_contiguous and np.array_equal(colour, ref_colour) and np.array_equal(colour, rgb)
    depth = decode_depth(tmp_path / "d.png", 0, intr, 0.001)
    raw = cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED)
    ref_depth = (raw.astype(np.float64) * 0.001).astype(np.float32)
    ref_depth[raw == 0] = np.nan
    assert depth.dtype == np.float32
    assert np.array_equal(depth, ref_depth, equal_nan=True)
