"""C3D writer: an Intel float C3D with POINT, ANALOG (empty), TRIAL and FACECAP (segments) groups."""

import struct

import numpy as np

from ..errors import FacecapError
from .c3d import BLOCK, INTEL
from .files import atomic_path


def _param(group_id, name, etype, dims, data):
    name_b = name.encode("ascii")
    body = struct.pack("<bB", etype, len(dims)) + bytes(dims) + data + b"\x00"
    return struct.pack("<bb", len(name_b), group_id) + name_b + struct.pack("<h", len(body) + 2) + body


def _group(group_id, name):
    name_b = name.encode("ascii")
    body = b"\x00"
    return struct.pack("<bb", len(name_b), -group_id) + name_b + struct.pack("<h", len(body) + 2) + body


def _chars(strings, width):
    return b"".join(s.encode("utf-8").ljust(width) for s in strings)


def _unstorable(names, width):
    """The names a C3D text field of ``width`` bytes cannot give back as they are (UTF-8, padded with
    spaces that readers strip): too long, empty, edged with spaces, or holding control characters."""
    return [n for n in names if len(n.encode("utf-8")) > width or n != n.strip() or not n
            or any(ord(c) < 32 or ord(c) == 127 for c in n)]


def _refuse(path, what, names, width):
    shown = ", ".join(repr(n) for n in names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
    raise FacecapError(f"{path}: C3D stores {what} of at most {width} bytes (UTF-8), without control characters or "
                       f"spaces at either end; these cannot be stored as they are: {shown}; rename them, or write "
                       ".csv, .trc or .json, which keep them")


def write_c3d(path, markers):
    """Write a 3D MarkerSet as an Intel float C3D (gaps: residual -1), atomically.

    Frames must be whole numbers >= 0; missing frames between first and last are written as gaps.
    Labels are written as UTF-8 in C3D's 30-byte fields (segment labels: 255 bytes); a name that does not
    fit as it is is refused, naming it (a cut or changed name would not be read back).
    """
    if markers.dim != 3:
        raise FacecapError(f"{path}: C3D holds 3D points; got {markers.dim}D markers")
    frames = markers.frames
    if not np.all(frames == np.round(frames)) or frames[0] < 0:
        raise FacecapError(f"{path}: C3D needs whole, non-negative frame numbers")
    first, last = int(frames[0]), int(frames[-1])
    n_frames, n_points = last - first + 1, markers.n_markers
    names = list(markers.names)
    bad = _unstorable(names, 30)
    if bad:
        _refuse(path, "marker names", bad, 30)
    bad = _unstorable(list(markers.segments), 255)
    if bad:
        _refuse(path, "segment labels", bad, 255)
    if n_points > 65535:
        raise FacecapError(f"{path}: C3D holds at most 65535 points")
    if len(markers.segments) and sum(len(v) for v in markers.segments.values()) > 255:
        raise FacecapError(f"{path}: at most 255 segments can be stored in a C3D file")
    data = np.zeros((n_frames, n_points, 4), dtype="<f4")
    rows = (frames - first).astype(np.intp)
    pos = markers.positions
    gap = np.isnan(pos[:, :, 0])
    data[rows, :, :3] = np.where(gap[:, :, None], 0.0, pos)
    data[:, :, 3] = -1.0
    data[rows, :, 3] = np.where(gap, -1.0, 0.0)
    rate = float(markers.fps)
    units = markers.units if markers.units in ("m", "cm", "mm") else "m"

    def build(data_start):
        p = [_group(1, "POINT"), _group(2, "ANALOG"), _group(3, "TRIAL")]
        p.append(_param(1, "USED", 2, (), struct.pack("<H", n_points)))
        p.append(_param(1, "FRAMES", 2, (), struct.pack("<H", min(n_frames, 65535))))
        if n_frames > 65535:
            p.append(_param(1, "LONG_FRAMES", 4, (), struct.pack("<f", n_frames)))
        p.append(_param(1, "DATA_START", 2, (), struct.pack("<H", data_start)))
        p.append(_param(1, "SCALE", 4, (), struct.pack("<f", -1.0)))
        p.append(_param(1, "RATE", 4, (), struct.pack("<f", rate)))
        p.append(_param(1, "UNITS", -1, (4,), _chars([units], 4)))
        for k in range(0, max(n_points, 1), 255):
            chunk = names[k:k + 255]
            label = "LABELS" if k == 0 else f"LABELS{k // 255 + 1}"
            p.append(_param(1, label, -1, (30, len(chunk)), _chars(chunk, 30)))
        p.append(_param(2, "USED", 2, (), struct.pack("<H", 0)))
        p.append(_param(2, "RATE", 4, (), struct.pack("<f", rate)))
        p.append(_param(3, "ACTUAL_START_FIELD", 2, (2,), struct.pack("<HH", first & 0xFFFF, first >> 16)))
        p.append(_param(3, "ACTUAL_END_FIELD", 2, (2,), struct.pack("<HH", last & 0xFFFF, last >> 16)))
        spans = [(lab, a, b) for lab, v in markers.segments.items() for a, b in v]
        if spans:
            width = max(1, max(len(s[0].encode("utf-8")) for s in spans))
            p.append(_group(4, "FACECAP"))
            p.append(_param(4, "SEGMENTS", -1, (width, len(spans)), _chars([s[0] for s in spans], width)))
            p.append(_param(4, "RANGES", 4, (2, len(spans)),
                            np.array([[a, b] for _, a, b in spans], dtype="<f4").tobytes()))
        blob = bytearray(b"".join(p))
        # The last entry's offset 0 ends the section.
        return bytes(blob)

    blob = build(0)
    n_param_blocks = (4 + len(blob) + BLOCK - 1) // BLOCK
    data_start = 2 + n_param_blocks
    blob = build(data_start)
    section = bytearray(struct.pack("<BBBB", 1, 0x50, n_param_blocks, INTEL) + blob)
    section += b"\x00" * (n_param_blocks * BLOCK - len(section))
    header = bytearray(BLOCK)
    struct.pack_into("<BB", header, 0, 2, 0x50)
    struct.pack_into("<HHHHH", header, 2, n_points, 0, min(first, 65535), min(last, 65535), 0)
    struct.pack_into("<f", header, 12, -1.0)
    struct.pack_into("<HH", header, 16, data_start, 1)  # 1 analog sample per frame, 0 channels
    struct.pack_into("<f", header, 20, rate)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header)
            fh.write(section)
            data.tofile(fh)
