"""C3D motion-capture files: a small numpy reader and writer (no third-party package).

Format (https://www.c3d.org/HTML/default.htm): 512-byte blocks. Block 1 is the header (16-bit
words: parameter block, point count, analog words per frame, first/last frame, scale, data start
block, frame rate). The parameter section (processor type in its 4th byte: 84 Intel, 85 DEC,
86 MIPS big-endian) holds groups and typed parameters (POINT:LABELS, POINT:UNITS, POINT:RATE,
POINT:SCALE, ...). Point data follow as frames of ``[x, y, z, residual]`` per point, int16
scaled by POINT:SCALE (> 0) or float32 (scale < 0), then the frame's analog samples, which are
skipped. A negative residual word marks a gap. The writer is :mod:`~facecap.solvers.io.c3d_write`.

Why not the ``c3d`` package: this reader is vectorised (one ``np.fromfile`` for the whole take,
no per-frame Python loop), checks every size against the file so a corrupt file fails with a
named field instead of an arbitrary exception or a huge allocation, and needs no bundled wheel.

Segments are stored in a ``FACECAP`` parameter group (``SEGMENTS`` labels, ``RANGES`` first/last
frame per segment) that other software ignores.
"""

import struct

import numpy as np

from ..errors import InputFileError
from .limits import check_input_file
from .timing import UNIT_ALIASES, check_markerset, finish_arrays, unique_names

BLOCK = 512
INTEL, DEC, MIPS = 84, 85, 86
_TYPES = {-1: 1, 1: 1, 2: 2, 4: 4}



def _text(data):
    """A label's bytes as text: UTF-8 (facecap's writer, ezc3d), else Latin-1 (older writers' bytes)."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")

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
            return [_text(p.data).strip()]
        width = p.dims[0]
        if width == 0:
            return []
        count = len(p.data) // width
        return [_text(p.data[i * width:(i + 1) * width]).strip().strip("\x00").strip() for i in range(count)]

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
    # Some writers count too few parameter blocks (BTK's parameterOverflow, c3d.org sample 13): the
    # section then runs on to the data, whose start block the header gives.
    data_block = int(np.frombuffer(head[16:18], dtype=endian + "u2")[0])
    end_block = param_block - 1 + n_blocks
    if data_block > param_block:
        end_block = max(end_block, data_block - 1)
    limit = size if n_blocks == 0 else min(size, end_block * BLOCK)
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

    Where the header and the parameters disagree on the frame layout (point count, analog samples
    per frame), the layout that the file's size fits is read and a note says so; a file shorter
    than its declared frames gives the frames it holds (noted). Repeated labels are kept, the
    repeats suffixed ``_2``, ``_3``, ... (noted).

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
    check_input_file(path)
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
        if size == 0:
            raise _fail(path, "empty file (0 bytes); expected a C3D file")
        c = _parse(path, fh, size)
        lay = _layout(c, size, notes)
        fh.seek(lay.data_start)
        raw = np.fromfile(fh, dtype=lay.dtype, count=lay.n_frames * lay.frame_words)
    if raw.size != lay.n_frames * lay.frame_words:
        raise _fail(path, "truncated point data", field="POINT:FRAMES")
    positions = _positions(c, lay, raw)
    del raw
    names = _labels(c, lay.n_points, notes)
    file_units = None
    unit_text = (c.strings("POINT", "UNITS") or [""])[0].lower()
    if unit_text:
        if unit_text in UNIT_ALIASES:
            file_units = UNIT_ALIASES[unit_text]
        else:
            notes.append(f"POINT:UNITS {unit_text!r} not understood")
    segments = _segments(c)
    frames = np.arange(lay.first, lay.first + lay.n_frames, dtype=np.float64)
    screen = (c.strings("POINT", "Y_SCREEN") or [None])[0]
    up_hint = None if not screen else (f"POINT:Y_SCREEN is {screen!r} (Y is up in the capture software)"
                                       if screen.upper() in ("+Y", "Y") else "")
    return check_markerset(lambda: finish_arrays(
        names, frames, positions, source=path, file_fps=lay.rate, segments=segments, units=units,
        file_units=file_units, unit_scale=unit_scale, up_axis=up_axis, fps=fps, notes=notes, up_hint=up_hint), path)


class _Layout:
    """Where the points are: first frame, frame count, points, words per frame, dtype, scale."""

    __slots__ = ("first", "n_frames", "n_points", "frame_words", "data_start", "dtype", "scale", "rate")

    def __init__(self, **kw):
        for k, v in kw.items():
            setattr(self, k, v)

    @property
    def is_float(self):
        return self.scale < 0


def _layout(c, size, notes):
    """Decide the point layout from the header, the parameters and the file's size."""
    hw = np.frombuffer(c.head[:24], dtype=c.endian + "u2")
    scale, rate = _scale_rate(c)
    data_start = _data_start(c, hw, size, notes)
    first, n_frames = _frame_range(c, hw)
    word = 4 if scale < 0 else 2
    points, analog = _count_choices(c, hw, rate, notes)
    if not points:
        raise _fail(c.path, f"no 3D points (POINT:USED 0): {_holds_instead(c)}", field="POINT:USED")
    avail = size - data_start

    def fits(choice, exact):
        need = n_frames * (4 * choice[0] + choice[1]) * word
        return need <= avail and (not exact or avail - need < BLOCK)  # files are padded to whole blocks

    choices = [(p, a) for p in points for a in analog]
    pick = choices[0]
    if not fits(pick, True):  # the usual reading leaves the size unexplained: does another explain it?
        exact = [ch for ch in choices if fits(ch, True)]
        if len(exact) == 1:
            pick = exact[0]
        elif not fits(pick, False):
            pick = next((ch for ch in choices if fits(ch, False)), pick)
    _note_choice(pick, points, analog, n_frames, notes)
    n_points, analog_words = pick
    frame_words = 4 * n_points + analog_words
    n_frames = _frames_held(c, hw, first, n_frames, avail // (frame_words * word), notes)
    dtype = c.endian + ("f4" if scale < 0 else "i2")
    if c.proc == DEC and scale < 0:
        dtype = "<u4"
    return _Layout(first=first, n_frames=n_frames, n_points=n_points, frame_words=frame_words,
                   data_start=data_start, dtype=dtype, scale=scale, rate=rate)


def _scale_rate(c):
    scale = c.number("POINT", "SCALE")
    if scale is None or not np.isfinite(scale) or scale == 0:
        scale = float(c._floats(c.head[12:16])[0])
    if not np.isfinite(scale) or scale == 0:
        raise _fail(c.path, f"invalid point scale {scale}", field="POINT:SCALE")
    rate = c.number("POINT", "RATE")
    if rate is None or not np.isfinite(rate) or rate <= 0:
        rate = float(c._floats(c.head[20:24])[0])
    if not np.isfinite(rate) or rate <= 0:
        raise _fail(c.path, f"frame rate must be positive; got {rate:g} (header and POINT:RATE)",
                    field="POINT:RATE")
    return scale, rate


def _data_start(c, hw, size, notes):
    """Byte offset of the point data: POINT:DATA_START, or the header's block when that one is not valid."""
    starts = [int(b) for b in (c.number("POINT", "DATA_START", unsigned=True), hw[8]) if b]
    valid = [b for b in starts if 2 <= b and (b - 1) * BLOCK < size]
    if not valid:
        raise _fail(c.path, f"data start block {starts[0] if starts else 0} lies outside the file ({size} bytes)",
                    field="POINT:DATA_START")
    if valid[0] != starts[0]:
        notes.append(f"POINT:DATA_START {starts[0]} is not a data block; the header's {valid[0]} is used")
    return (valid[0] - 1) * BLOCK


def _frame_range(c, hw):
    first = c.words("TRIAL", "ACTUAL_START_FIELD")
    first = int(hw[3]) if first is None else first
    last = _last_frame(c, int(hw[4]))
    if last < first:
        raise _fail(c.path, f"zero frames (first frame {first}, last frame {last})", field="POINT:FRAMES")
    return first, last - first + 1


def _frames_held(c, hw, first, n_frames, held, notes):
    """The frame count to read when the file holds ``held`` whole frames of the chosen layout."""
    header_frames = int(hw[4]) - first + 1
    if 0 < header_frames <= held < n_frames:  # the parameters overstate it; the header fits
        notes.append(f"the parameters declare {n_frames} frames, the header {header_frames}; "
                     f"the file holds {held}: read {header_frames}")
        return header_frames
    if held >= n_frames:
        return n_frames
    if held == 0:
        raise _fail(c.path, f"truncated point data: {n_frames} frames declared, the file holds none",
                    field="POINT:FRAMES")
    notes.append(f"warning: {n_frames} frames declared, the file holds {held} (truncated): read {held}")
    return held


def _count_choices(c, hw, rate, notes):
    """Candidate point counts and analog samples per frame, the usual reading first."""
    used = c.number("POINT", "USED", unsigned=True)
    points = [int(used)] if used is not None else []
    if int(hw[1]) not in points:
        points.append(int(hw[1]))
    points = [p for p in points if p > 0]
    analog = [int(hw[2])]
    a_used = c.number("ANALOG", "USED", unsigned=True) or 0
    a_rate = c.number("ANALOG", "RATE")
    if a_used and a_rate is not None:
        ratio = a_rate / rate
        if np.isfinite(ratio) and 0 < ratio < 1e6:
            per_frame = int(a_used) * max(int(round(ratio)), 1)
            if per_frame not in analog:
                analog.append(per_frame)
                if analog[0] == 0:  # the header leaves it out: the parameters' count comes first
                    analog.reverse()
        else:
            notes.append(f"ANALOG:RATE {a_rate:g} ignored (not a positive rate)")
    return points, analog


def _note_choice(pick, points, analog, n_frames, notes):
    if len(points) > 1 and pick[0] != points[0]:
        notes.append(f"warning: POINT:USED says {points[0]} points, the header {pick[0]}; the file's size fits "
                     f"{pick[0]} ({n_frames} frames): read {pick[0]}")
    if len(analog) > 1 and pick[1] != analog[0]:
        notes.append(f"warning: the header says {analog[0]} analog samples per frame, the ANALOG parameters "
                     f"{pick[1]}; the file's size fits {pick[1]}: read with {pick[1]}")


def _holds_instead(c):
    rotations = c.number("ROTATION", "USED", unsigned=True)
    channels = c.number("ANALOG", "USED", unsigned=True)
    if rotations:
        return f"the file holds {int(rotations)} rotation matrices (ROTATION group), no markers"
    if channels:
        return f"the file holds only {int(channels)} analog channels (force plates, EMG), no markers"
    return "the file holds no marker data"


def _positions(c, lay, raw):
    """(F, M, 3) float64 positions from the raw frames; NaN where the residual marks a gap."""
    raw = raw.reshape(lay.n_frames, lay.frame_words)[:, : 4 * lay.n_points].reshape(lay.n_frames, lay.n_points, 4)
    if c.proc == DEC and lay.is_float:
        u = raw.astype(np.uint32)
        raw = (((u >> 16) | (u << 16)).astype("<u4").view("<f4") / 4.0)
    with np.errstate(invalid="ignore", over="ignore"):
        if lay.is_float:
            gap = ~(raw[:, :, 3] > -0.5) | ~np.isfinite(raw[:, :, :3]).all(axis=2)
            positions = raw[:, :, :3].astype(np.float64)
        else:
            gap = raw[:, :, 3] < 0
            positions = raw[:, :, :3].astype(np.float64)
            positions *= lay.scale
    positions[gap] = np.nan
    np.nan_to_num(positions, copy=False, nan=np.nan, posinf=np.nan, neginf=np.nan)
    return positions


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
        notes.append(f"POINT:LABELS names {len(labels)} of {n_points} points: the others are named "
                     f"point{len(labels) + 1}..point{n_points}")
    names = [lab if lab else f"point{i + 1}" for i, lab in enumerate(labels)]
    names += [f"point{i + 1}" for i in range(len(names), n_points)]
    return unique_names(names, notes, where="POINT:LABELS")


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
