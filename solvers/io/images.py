"""PNG and TGA images as numpy arrays, without an imaging library (numpy and zlib only).

``write_png`` writes 8-bit grey, RGB or RGBA images byte-for-byte reproducibly (no time stamp or other
metadata), atomically. ``read_tga`` reads the uncompressed TGA files Blender renders to
(``TARGA_RAW``), which need no decoder.
"""

import struct
import zlib

import numpy as np

from ..errors import InputFileError
from .files import atomic_path

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_COLOUR_TYPE = {1: 0, 3: 2, 4: 6}  # channels -> PNG colour type (greyscale, truecolour, truecolour with alpha)


def _chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def paeth_filter(image):
    """Rows of ``image`` filtered with PNG's Paeth predictor (filter type 4).

    Parameters
    ----------
    image : (H, W, C) uint8

    Returns
    -------
    (H, W * C + 1) uint8, each row led by its filter type byte.
    """
    h, w, c = image.shape
    raw = image.reshape(h, w * c).astype(np.int16)
    left = np.zeros_like(raw)
    left[:, c:] = raw[:, :-c]
    up = np.zeros_like(raw)
    up[1:] = raw[:-1]
    up_left = np.zeros_like(raw)
    up_left[1:, c:] = raw[:-1, :-c]
    # The predictor works on the unfiltered bytes, so the whole image filters at once.
    p = left + up - up_left
    pa, pb, pc = np.abs(p - left), np.abs(p - up), np.abs(p - up_left)
    pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, up_left))
    out = np.empty((h, w * c + 1), dtype=np.uint8)
    out[:, 0] = 4
    out[:, 1:] = ((raw - pred) % 256).astype(np.uint8)
    return out


def write_png(path, image):
    """Write an 8-bit grey, RGB or RGBA image as a PNG file (atomically; identical bytes for identical pixels).

    Parameters
    ----------
    path : str or Path
    image : (H, W, 1), (H, W, 3) or (H, W, 4) uint8, top row first (grey: a third of RGB's bytes)
    """
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] not in _COLOUR_TYPE or 0 in image.shape:
        raise ValueError(f"write_png needs an (H, W, 1|3|4) uint8 image, got {image.dtype} {image.shape}")
    data = encode_png(image)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def encode_png(image, level=9):
    """The PNG file bytes of an 8-bit (H, W, 1|3|4) grey, RGB or RGBA image, top row first."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] not in _COLOUR_TYPE or 0 in image.shape:
        raise ValueError(f"encode_png needs an (H, W, 1|3|4) uint8 image, got {image.dtype} {image.shape}")
    h, w, c = image.shape
    header = struct.pack(">IIBBBBB", w, h, 8, _COLOUR_TYPE[c], 0, 0, 0)
    data = zlib.compress(paeth_filter(image).tobytes(), level)
    return _SIGNATURE + _chunk(b"IHDR", header) + _chunk(b"IDAT", data) + _chunk(b"IEND", b"")


def read_tga(path):
    """Read an uncompressed 8-bit TGA (Blender's ``TARGA_RAW`` output).

    Returns
    -------
    (H, W, 3) or (H, W, 4) uint8, RGB(A), top row first.
    """
    blob = open(path, "rb").read()
    if len(blob) < 18:
        raise InputFileError(path, "not a TGA file (shorter than its 18-byte header)")
    id_length, colour_map, kind = blob[0], blob[1], blob[2]
    w, h = struct.unpack("<HH", blob[12:16])
    bits, descriptor = blob[16], blob[17]
    if colour_map != 0 or kind != 2 or bits not in (24, 32):
        raise InputFileError(path, f"expected an uncompressed 24/32-bit true-colour TGA, got type {kind}, {bits} bits")
    c = bits // 8
    start = 18 + id_length
    if len(blob) < start + w * h * c:
        raise InputFileError(path, f"truncated: {w}x{h}x{c} pixels need {w * h * c} bytes")
    pixels = np.frombuffer(blob, dtype=np.uint8, count=w * h * c, offset=start).reshape(h, w, c)
    pixels = pixels[:, :, [2, 1, 0, 3][:c]]  # stored BGR(A)
    if not descriptor & 0x20:  # bottom row first unless the top-left origin bit is set
        pixels = pixels[::-1]
    if descriptor & 0x10:  # right-to-left
        pixels = pixels[:, ::-1]
    return np.ascontiguousarray(pixels)
