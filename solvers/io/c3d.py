"""C3D motion-capture files: a small numpy reader and writer (no third-party package).

Format (https://www.c3d.org/HTML/default.htm): 512-byte blocks. Block 1 is the header (16-bit
words: parameter block, point count, analog words per frame, first/last frame, scale, data start
block, frame rate). The parameter section (processor type in its 4th byte: 84 Intel, 85 DEC,
86 MIPS big-endian) holds groups and typed parameters (POINT:LABELS, POINT:UNITS, POINT:RATE,
POINT:SCALE, ...). Point data follow as frames of ``[x, y, z, residual]`` per point, int16
scaled by POINT:SCALE (> 0) or float32 (scale < 0), then the frame's analog samples, which are
skipped. A negative residual word marks a gap.

Why not the ``c3d`` package: this reader is vectorised (one ``np.fromfile`` for the whole take,
no per-frame Python loop), checks every size against the file so a corrupt file fails with a
named field instead of an arbitrary exception or a huge allocation, and needs no bundled wheel.

Segments are stored in a ``FACECAP`` parameter group (``SEGMENTS`` labels, ``RANGES`` first/last
frame per segment) that other software ignores.
"""

import struct

import numpy as np

from ..errors import FacecapError, InputFileError
from .files import atomic_path
from .timing import UNIT_ALIASES, check_markerset, finish_arrays

BLOCK = 512
INTEL, DEC, MIPS = 84, 85, 86
_TYPES = {-1: 1, 1: 1, 2: 2, 4: 4}


class _Param:
    __slots__ = ("etype", "dims", "data")

    def __init__(self, etype, dims, data):
        self.etype, self.dims, self.data = etype, dims, data


class _C3D:
    """Parsed header and parameters, with typed accessors that name what is wrong."""

    def __init__(self, path, head, params, endian, proc):
        self.path, self.head, self.params, self.endian, self.proc = path, head, params, endian, proc

    def get(self, group, name):
        return self.params.get((group, name))

    def _floats(self, raw):
        if self.proc == DEC:
            u = np.frombuffer(raw, dtype="<u4")
            u = ((u >> 16) | (u << 16)).astype("<u4")
            return u.view("<f4").astype(np.float64) / 4.0
        return np.frombuffer(raw, dtype=self.endian + "f4").astype(np.float64)

    def number(self, group, name, *, unsigned=False):
        """First value of a numeric parameter as float, or None when absent/empty/non-numeric."""
        p = self.get(group, name)
        if p is None or len(p.data) < abs(p.etype) or p.etype == -1:
            return None
        if p.etype == 4:
            return float(self._floats(p.data[:4])[0])
        if p.etype == 2:
            return float(np.frombuffer(p.data[:2], dtype=self.endian + ("u2" if unsigned else "i2"))[0])
        return float(p.data[0])

    def words(self, group, name):
        p = self.get(group, name)
        if p is None or p.etype != 2 or len(p.data) < 4:
            return None
        w = np.frombuffer(p.data[:4], dtype=self.endian + "u2")
        return int(w[0]) + 65536 * int(w[1])

    def strings(self, group, name):
        p = self.get(group, name)
        if p is None or p.etype != -1:
            return None
        if len(p.dims) == 0:
            return [p.data.decode("latin-1").strip()]
        width = p.dims[0]
        if width == 0:
            return []
        count = len(p.data) // width
        return [p.data[i * width:(i + 1) * width].decode("latin-1").strip().strip("\x00").strip()
                for i in range(count)]

    def floats(self, group, name):
        p = self.get(group, name)
        if p is None or p.etype != 4:
            return None
        return self._floats(p.data[: len(p.data) // 4 * 4])


def _fail(path, message, field=None):
    return InputFileError(path, message, field=field)


def _parse(path, fh, size):
    head = fh.read(BLOCK)
    if len(head) < BLOCK:
        raise _fail(path, f"truncated C3D header: {len(head)} of 512 bytes")
    if head[1] != 0x50:
        raise _fail(path, f"not a C3D file: header byte 2 is {head[1]}, expected 80 (0x50)")
    param_block = head[0]
    if param_block < 2 or (param_block - 1) * BLOCK + 4 > size:
        raise _fail(path, f"parameter section at block {param_block} lies outside the file")
    fh.seek((param_block - 1) * BLOCK)
    first4 = fh.read(4)
    proc = first4[3]
    if proc not in (INTEL, DEC, MIPS):
        raise _fail(path, f"unknown processor type {proc}; expected 84 (Intel), 85 (DEC) or 86 (MIPS)")
    endian = ">" if proc == MIPS else "<"
    n_blocks = first4[2]
    limit = size if n_blocks == 0 else min(size, (param_block - 1 + n_blocks) * BLOCK)
    fh.seek((param_block - 1) * BLOCK)
    buf = fh.read(limit - (param_block - 1) * BLOCK)
    params, groups = {}, {}
    raw_params = []
    pos = 4
    while pos + 2 <= len(buf):
        nlen = abs(struct.unpack_from("b", buf, pos)[0])
        gid = struct.unpack_from("b", buf, pos + 1)[0]
        if nlen == 0 or gid == 0:
            break
        name_end = pos + 2 + nlen
        if name_end + 2 > len(buf):
            raise _fail(path, f"truncated parameter section at byte {(param_block - 1) * BLOCK + pos}")
        name = buf[pos + 2:name_end].decode("latin-1").strip().upper()
        offset = struct.unpack_from(endian + "h", buf, name_end)[0]
        body = name_end + 2
        if gid < 0:
            groups[-gid] = name
        else:
            if body + 2 > len(buf):
                raise _fail(path, f"truncated parameter {name!r}")
            etype = struct.unpack_from("b", buf, body)[0]
            ndim = buf[body + 1]
            dims = tuple(buf[body + 2:body + 2 + ndim])
            if len(dims) != ndim:
                raise _fail(path, f"truncated parameter {name!r}")
            if etype in _TYPES:
                count = int(np.prod(dims)) if ndim else 1
                start = body + 2 + ndim
                nbytes = _TYPES[etype] * count
                if start + nbytes > len(buf):
                    raise _fail(path, f"parameter {name!r} runs past the parameter section")
                raw_params.append((gid, name, _Param(etype, dims, bytes(buf[start:start + nbytes]))))
        if offset <= 0:
            break
        pos = name_end + offset
    for gid, name, p in raw_params:
        group = groups.get(gid)
        if group is not None:
            params[(group, name)] = p
    return _C3D(path, head, params, endian, proc)


def read_c3d(path, *, units=None, fps=None, unit_scale=None, up_axis=None, notes=None):
    """Read the 3D points of a C3D file as a MarkerSet; analog channels are ignored.

    Parameters
    ----------
    path : path-like
    units : str or None
        Override ``POINT:UNITS`` (which is used when present).
    fps : float or None
        Override ``POINT:RATE`` / the header rate.
    unit_scale, up_axis, notes
        As for :func:`facecap.solvers.io.timing.finish`.

    Returns
    -------
    MarkerSet
        ``frames`` start at the file's first frame; samples with a negative residual are gaps.
    """
    notes = [] if notes is None else notes
    path = str(path)
    try:
        fh = open(path, "rb")
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except IsADirectoryError:
        raise InputFileError(path, "is a directory, expected a file") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot read: {exc.strerror}") from None
    with fh:
        fh.seek(0, 2)
        size = fh.tell()
        fh.seek(0)
        c = _parse(path, fh, size)
        hw = np.frombuffer(c.head[:24], dtype=c.endian + "u2")
        n_points = c.number("POINT", "USED", unsigned=True)
        n_points = int(hw[1]) if n_points is None else int(n_points)
        scale = c.number("POINT", "SCALE")
        if scale is None or not np.isfinite(scale):
            scale = float(c._floats(c.head[12:16])[0])
        rate = c.number("POINT", "RATE")
        if rate is None or not np.isfinite(rate) or rate <= 0:
            rate = float(c._floats(c.head[20:24])[0])
        start_block = c.number("POINT", "DATA_START", unsigned=True)
        start_block = int(hw[8]) if not start_block else int(start_block)
        first = c.words("TRIAL", "ACTUAL_START_FIELD")
        first = int(hw[3]) if first is None else first
        last = _last_frame(c, int(hw[4]))
        n_frames = last - first + 1
        if n_points <= 0:
            raise _fail(path, f"no 3D points (POINT:USED = {n_points})", field="POINT:USED")
        if n_frames <= 0:
            raise _fail(path, f"zero frames (first frame {first}, last frame {last})", field="POINT:FRAMES")
        if not np.isfinite(scale) or scale == 0:
            raise _fail(path, f"invalid point scale {scale}", field="POINT:SCALE")
        is_float = scale < 0
        word = 4 if is_float else 2
        analog_words = int(hw[2])
        if analog_words == 0:
            used = c.number("ANALOG", "USED", unsigned=True) or 0
            arate = c.number("ANALOG", "RATE") or 0
            if used and arate and np.isfinite(arate):
                analog_words = int(used * round(arate / rate))
        frame_words = 4 * n_points + analog_words
        data_start = (start_block - 1) * BLOCK
        if start_block < 2 or data_start >= size:
            raise _fail(path, f"data start block {start_block} lies outside the file ({size} bytes)",
                        field="POINT:DATA_START")
        available = (size - data_start) // (frame_words * word)
        if available < n_frames:
            raise _fail(path, f"truncated point data: {n_frames} frames declared, the file holds {available}",
                        field="POINT:FRAMES")
        fh.seek(data_start)
        dtype = c.endian + ("f4" if is_float else "i2")
        if c.proc == DEC and is_float:
            dtype = "<u4"
        raw = np.fromfile(fh, dtype=dtype, count=n_frames * frame_words)
    if raw.size != n_frames * frame_words:
        raise _fail(path, "truncated point data", field="POINT:FRAMES")
    raw = raw.reshape(n_frames, frame_words)[:, : 4 * n_points].reshape(n_frames, n_points, 4)
    if c.proc == DEC and is_float:
        u = raw.astype(np.uint32)
        raw = (((u >> 16) | (u << 16)).astype("<u4").view("<f4") / 4.0)
    with np.errstate(invalid="ignore"):
        if is_float:
            resid = raw[:, :, 3]
            gap = ~(resid > -0.5) | ~np.isfinite(raw[:, :, :3]).all(axis=2)
            positions = raw[:, :, :3].astype(np.float64)
        else:
            gap = raw[:, :, 3] < 0
            positions = raw[:, :, :3].astype(np.float64)
            positions *= scale
    del raw
    positions[gap] = np.nan
    np.nan_to_num(positions, copy=False, nan=np.nan, posinf=np.nan, neginf=np.nan)
    names = _labels(c, n_points, notes)
    file_units = None
    unit_text = (c.strings("POINT", "UNITS") or [""])[0].lower()
    if unit_text:
        if unit_text in UNIT_ALIASES:
            file_units = UNIT_ALIASES[unit_text]
        else:
            notes.append(f"POINT:UNITS {unit_text!r} not understood")
    segments = _segments(c)
    frames = np.arange(first, first + n_frames, dtype=np.float64)
    return check_markerset(lambda: finish_arrays(
        names, frames, positions, source=path, file_fps=rate, segments=segments, units=units,
        file_units=file_units, unit_scale=unit_scale, up_axis=up_axis, fps=fps, notes=notes), path)


def _last_frame(c, header_last):
    end = c.words("TRIAL", "ACTUAL_END_FIELD")
    if end is not None and end >= header_last:
        return end
    for name in ("LONG_FRAMES", "FRAMES"):
        value = c.number("POINT", name, unsigned=True)
        if value is not None and np.isfinite(value) and value >= header_last:
            first = c.words("TRIAL", "ACTUAL_START_FIELD")
            first = int(np.frombuffer(c.head[6:8], dtype=c.endian + "u2")[0]) if first is None else first
            return first + int(value) - 1
    return header_last


def _labels(c, n_points, notes):
    labels = []
    for name in ["LABELS"] + [f"LABELS{i}" for i in range(2, 100)]:
        more = c.strings("POINT", name)
        if more is None:
            break
        labels.extend(more)
    labels = labels[:n_points]
    if len(labels) < n_points:
        notes.append(f"{n_points - len(labels)} point(s) without a label named by number")
    names = [lab if lab else f"point{i + 1}" for i, lab in enumerate(labels)]
    names += [f"point{i + 1}" for i in range(len(names), n_points)]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputFileError(c.path, f"duplicate marker names {dup}", field="POINT:LABELS")
    return tuple(names)


def _segments(c):
    labels = c.strings("FACECAP", "SEGMENTS")
    ranges = c.floats("FACECAP", "RANGES")
    if not labels or ranges is None or ranges.size < 2 * len(labels):
        return {}
    out = {}
    for label, (a, b) in zip(labels, ranges[: 2 * len(labels)].reshape(-1, 2)):
        if np.isfinite(a) and np.isfinite(b) and a <= b:
            out.setdefault(label, []).append((float(a), float(b)))
    return out


# ---------------------------------------------------------------------------------------------
# writer


def _param(group_id, name, etype, dims, data):
    name_b = name.encode("ascii")
    body = struct.pack("<bB", etype, len(dims)) + bytes(dims) + data + b"\x00"
    return struct.pack("<bb", len(name_b), group_id) + name_b + struct.pack("<h", len(body) + 2) + body


def _group(group_id, name):
    name_b = name.encode("ascii")
    body = b"\x00"
    return struct.pack("<bb", len(name_b), -group_id) + name_b + struct.pack("<h", len(body) + 2) + body


def _chars(strings, width):
    return b"".join(s.encode("latin-1", "replace")[:width].ljust(width) for s in strings)


def write_c3d(path, markers):
    """Write a 3D MarkerSet as an Intel float C3D (gaps: residual -1), atomically.

    Frames must be whole numbers >= 0; missing frames between first and last are written as gaps.
    Labels are cut to 30 characters, which must keep them unique.
    """
    if markers.dim != 3:
        raise FacecapError(f"{path}: C3D holds 3D points; got {markers.dim}D markers")
    frames = markers.frames
    if not np.all(frames == np.round(frames)) or frames[0] < 0:
        raise FacecapError(f"{path}: C3D needs whole, non-negative frame numbers")
    first, last = int(frames[0]), int(frames[-1])
    n_frames, n_points = last - first + 1, markers.n_markers
    names = [n[:30] for n in markers.names]
    if len(set(names)) != len(names):
        raise FacecapError(f"{path}: marker names are not unique in their first 30 characters")
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
            width = max(1, min(255, max(len(s[0].encode("latin-1", "replace")) for s in spans)))
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
