"""solvers.io.images: PNG writing (reproducible, decodable) and Blender's raw TGA renders."""

import struct
import zlib

import numpy as np
import pytest

from facecap.solvers.errors import InputFileError
from facecap.solvers.io.images import read_tga, write_png


def _decode_png(blob):
    """A plain reference decoder (every filter type, pixel by pixel) for 8-bit grey/RGB/RGBA PNGs."""
    assert blob[:8] == b"\x89PNG\r\n\x1a\n"
    pos, chunks = 8, []
    while pos < len(blob):
        (n,) = struct.unpack(">I", blob[pos:pos + 4])
        kind, data = blob[pos + 4:pos + 8], blob[pos + 8:pos + 8 + n]
        assert struct.unpack(">I", blob[pos + 8 + n:pos + 12 + n])[0] == zlib.crc32(kind + data)
        chunks.append((kind, data))
        pos += 12 + n
    assert [k for k, _ in chunks] == [b"IHDR", b"IDAT", b"IEND"]  # no metadata chunks
    w, h, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", chunks[0][1])
    assert depth == 8 and interlace == 0
    c = {0: 1, 2: 3, 6: 4}[colour]
    raw = zlib.decompress(chunks[1][1])
    stride = w * c
    out = np.zeros((h, stride), dtype=np.int64)
    for y in range(h):
        kind, row = raw[y * (stride + 1)], raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)]
        for x in range(stride):
            a = out[y, x - c] if x >= c else 0
            b = out[y - 1, x] if y > 0 else 0
            d = out[y - 1, x - c] if x >= c and y > 0 else 0
            if kind == 0:
                pred = 0
            elif kind == 1:
                pred = a
            elif kind == 2:
                pred = b
            elif kind == 3:
                pred = (a + b) // 2
            else:
                p = a + b - d
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - d)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else d)
            out[y, x] = (row[x] + pred) % 256
    return out.reshape(h, w, c).astype(np.uint8)


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_png_round_trip(tmp_path, channels):
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, size=(7, 11, channels), dtype=np.uint8)
    image[2:5, 3:9] = 200  # flat areas and edges, as in a render
    write_png(tmp_path / "a.png", image)
    assert np.array_equal(_decode_png((tmp_path / "a.png").read_bytes()), image)


def test_png_bytes_are_reproducible_and_the_write_is_atomic(tmp_path):
    image = np.full((5, 4, 3), 128, dtype=np.uint8)
    write_png(tmp_path / "a.png", image)
    write_png(tmp_path / "b.png", image)
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "b.png"]  # no temporary left behind


@pytest.mark.parametrize("image", [np.zeros((4, 4), np.uint8), np.zeros((4, 4, 3), np.float32),
                                   np.zeros((4, 4, 2), np.uint8), np.zeros((0, 4, 3), np.uint8)])
def test_png_rejects_what_it_cannot_write(tmp_path, image):
    with pytest.raises(ValueError, match="uint8 image"):
        write_png(tmp_path / "a.png", image)
    assert not (tmp_path / "a.png").exists()


def _tga(pixels_bgra, top_left):
    h, w, c = pixels_bgra.shape
    header = bytes([0, 0, 2]) + bytes(9) + struct.pack("<HH", w, h) + bytes([8 * c, 0x20 if top_left else 0])
    rows = pixels_bgra if top_left else pixels_bgra[::-1]
    return header + rows.tobytes()


@pytest.mark.parametrize("top_left", [True, False])
@pytest.mark.parametrize("channels", [3, 4])
def test_tga_reads_rgb_top_row_first(tmp_path, top_left, channels):
    rgba = np.arange(3 * 2 * channels, dtype=np.uint8).reshape(3, 2, channels)
    bgra = rgba[:, :, [2, 1, 0, 3][:channels]]
    (tmp_path / "t.tga").write_bytes(_tga(np.ascontiguousarray(bgra), top_left))
    assert np.array_equal(read_tga(tmp_path / "t.tga"), rgba)


def test_tga_errors_name_the_file(tmp_path):
    (tmp_path / "short.tga").write_bytes(b"abc")
    with pytest.raises(InputFileError, match="short.tga.*18-byte header"):
        read_tga(tmp_path / "short.tga")
    rle = bytearray(_tga(np.zeros((2, 2, 4), np.uint8), True))
    rle[2] = 10  # run-length encoded
    (tmp_path / "rle.tga").write_bytes(bytes(rle))
    with pytest.raises(InputFileError, match="uncompressed"):
        read_tga(tmp_path / "rle.tga")
    (tmp_path / "cut.tga").write_bytes(_tga(np.zeros((2, 2, 4), np.uint8), True)[:-1])
    with pytest.raises(InputFileError, match="truncated"):
        read_tga(tmp_path / "cut.tga")
