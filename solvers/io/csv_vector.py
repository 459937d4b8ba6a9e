"""The vectorised reader of purely numeric CSV data (every cell empty or a plain decimal number).

``io_csv.read_numeric_columns`` tries it first; anything it does not handle raises ``SlowPath`` and
the file goes to numpy's text parser, then to the cell-by-cell reader whose errors name the line
and field. Results are bit-identical to ``float()`` of each cell (``tests/core/test_csv_fast.py``).
"""

import numpy as np


class SlowPath(Exception):
    """The fast reader met something it does not handle; re-read with a more careful one."""


# Vectorised reader for purely numeric blocks: every cell empty or a plain decimal number
# ([+-], digits, optional '.' or decimal ',' followed by digits, optional exponent). The bytes are
# classified with one bytes.translate, the structure is checked from the positions of the
# separators, points and exponents, digit runs are turned into integers eight ASCII digits at a
# time (SWAR: one unaligned 64-bit load and three multiply-shift steps), and a number becomes
# mantissa * 10**p in one correctly rounded float operation whenever mantissa <= 2**53 and
# |p| <= 22 (Clinger's fast path; exactly what float() returns). Other numbers (more than 16
# digits, far exponents) go through float() one by one. Anything outside this grammar, CR-only
# line ends, blank or ragged rows, raise SlowPath.
_BLOCK_PAD = b"\n" * 8  # a separator before the first field and room for the 8-byte loads
_DIG, _SIGN, _POINT, _EXP, _DELIM, _EOL = 1, 2, 3, 4, 5, 6
_U64 = np.uint64
_DIGIT_MASK = np.array([0x0F0F0F0F0F0F0F0F & ~((1 << (8 * (8 - n))) - 1) for n in range(9)], dtype=np.uint64)
_POW10 = 10.0 ** np.arange(23)
_SIGNED_POW10 = np.concatenate([_POW10, -_POW10])
_POW10_INT = np.array([10 ** k for k in range(17)], dtype=np.uint64)


def _class_table(delimiter, decimal):
    table = bytearray(256)
    table[ord("0"):ord("9") + 1] = bytes([_DIG]) * 10
    table[ord("+")] = table[ord("-")] = _SIGN
    table[ord(".")] = _POINT
    if decimal == ",":
        table[ord(",")] = _POINT  # as in _to_float, both '.' and ',' are decimal points
    table[ord("e")] = table[ord("E")] = _EXP
    table[ord(delimiter)] = _DELIM
    table[ord("\n")] = _EOL
    return bytes(table)


def _eight_digits(words, ends, n):
    """Integer value of the ``n`` (<= 8) ASCII digits that end just before each of ``ends``."""
    x = words[ends - 8]
    x &= _DIGIT_MASK[n]  # ASCII -> 0..9, bytes before the run -> leading zeros
    x *= _U64(2561)
    x >>= _U64(8)
    x &= _U64(0x00FF00FF00FF00FF)
    x *= _U64(6553601)
    x >>= _U64(16)
    x &= _U64(0x0000FFFF0000FFFF)
    x *= _U64(42949672960001)
    x >>= _U64(32)
    return x


def _digit_runs(words, ends, n):
    """Integer value of runs of up to 16 ASCII digits (longer runs: garbage, caller checks)."""
    value = _eight_digits(words, ends, np.minimum(n, 8))
    long = np.flatnonzero(n > 8)
    if long.size:
        value[long] += _eight_digits(words, ends[long] - 8, np.minimum(n[long] - 8, 8)) * _U64(10 ** 8)
    return value


def _parse_block(block, width, table, pattern):
    """(rows, width) float64 of ``block`` (pad + whole lines ending in newlines), gaps NaN."""
    cls = block.translate(table)
    if b"\x00" in cls:
        raise SlowPath
    arr = np.frombuffer(cls, np.uint8)
    sp = np.flatnonzero(arr >= _POINT)  # points, exponents and separators, in order
    kind = arr[sp]
    zi = np.flatnonzero(kind >= _DELIM)
    seps = kind[zi[len(_BLOCK_PAD):]]
    rows = seps.size // width
    if seps.size > pattern.size:
        pattern = np.tile(pattern[:width], rows + 1)
    if rows * width != seps.size or not np.array_equal(seps, pattern[:seps.size]):
        raise SlowPath  # ragged or blank rows
    zi = zi[len(_BLOCK_PAD) - 1:]
    end_i = zi[1:]
    starts = sp[zi[:-1]] + 1
    ends = sp[end_i]
    k1, k2, p1 = kind[end_i - 1], kind[end_i - 2], sp[end_i - 1]
    has_exp = k1 == _EXP
    last_point = k1 == _POINT
    has_point = last_point | (has_exp & (k2 == _POINT))
    if int(np.count_nonzero(has_exp)) + int(np.count_nonzero(has_point)) != sp.size - zi.size - len(_BLOCK_PAD) + 1:
        raise SlowPath  # a second point or exponent, or a point after the exponent
    point = np.where(last_point, p1, sp[end_i - 2])
    mant_end = np.where(has_exp, p1, ends)
    int_end = np.where(has_point, point, mant_end)
    has_sign = arr[starts] == _SIGN
    n_int = int_end - starts - has_sign
    n_frac = np.where(has_point, mant_end - point - 1, 0)
    filled = starts != ends
    bad = filled & (np.where(has_point, n_frac, n_int) < 1)  # "-", "5.", ".e3", "e3"
    n_signs = int(np.count_nonzero(has_sign))
    raw = np.frombuffer(block, np.uint8)
    words = np.ndarray((len(block) - 7,), dtype="<u8", buffer=block, strides=(1,))
    power = -n_frac
    exp_rows = np.flatnonzero(has_exp)
    far = exp_rows[:0]
    if exp_rows.size:
        at = p1[exp_rows]
        exp_sign = arr[at + 1] == _SIGN
        n_signs += int(np.count_nonzero(exp_sign))
        n_exp = ends[exp_rows] - at - 1 - exp_sign
        bad[exp_rows] |= n_exp < 1
        x = _digit_runs(words, ends[exp_rows], np.minimum(n_exp, 16)).astype(np.int64)
        np.negative(x, out=x, where=raw[at + 1] == ord("-"))
        power[exp_rows] += x
        far = exp_rows[n_exp > 6]
    # Every sign was at the start of a field or of an exponent: runs hold nothing but digits.
    if n_signs != int(np.count_nonzero(arr == _SIGN)) or bad.any():
        raise SlowPath
    mant = _digit_runs(words, int_end, np.minimum(n_int, 16))
    mant *= _POW10_INT[np.minimum(n_frac, 16)]
    mant += _digit_runs(words, mant_end, np.minimum(n_frac, 16))
    exact = (n_int + n_frac <= 16) & (mant <= _U64(1 << 53)) & (power >= -22) & (power <= 22)
    exact[far] = False
    up = np.clip(power, 0, 22)
    up += (raw[starts] == ord("-")) * 23
    values = mant.astype(np.float64)
    values *= _SIGNED_POW10[up]  # exact: 10**k (k <= 22) and mant (<= 2**53) are doubles
    values /= _POW10[np.clip(-power, 0, 22)]  # ... so one rounding, as float() does
    values[~filled] = np.nan
    if not filled.reshape(rows, width).any(axis=1).all():
        raise SlowPath  # a row of empty cells: the careful reader skips it
    others = np.flatnonzero(~exact & filled)
    if others.size > max(256, starts.size // 4):
        raise SlowPath  # mostly long numbers: numpy's parser is quicker than float() per cell
    for i in others.tolist():
        values[i] = float(block[starts[i]:ends[i]].replace(b",", b"."))  # decimal comma
    if others.size and np.isinf(values[others]).any():
        raise SlowPath
    return values.reshape(rows, width)


FAST_BLOCK_BYTES = 1 << 20


def _byte_blocks(sn):
    """Yield pad + whole data lines (newline-terminated, LF only) of the file, in blocks."""
    try:
        fh = open(sn.path, "rb")
    except OSError:
        raise SlowPath from None
    with fh:
        for _ in range(sn.header_line):
            skipped = fh.readline()
            if skipped.count(b"\r") != skipped.count(b"\r\n") or b'"' in skipped:
                raise SlowPath  # CR-only line ends, or a quote the csv module reads across lines
            try:
                skipped.decode("utf-8")
            except UnicodeDecodeError:
                raise SlowPath from None
        carry = b""
        while True:
            data = fh.read(FAST_BLOCK_BYTES)
            text = carry + data
            if not data:
                text = text.rstrip(b"\r\n")
                if text:
                    yield _lf_only(_BLOCK_PAD + text + b"\n")
                return
            end = len(text.rstrip(b"\r\n"))  # blank lines stay in carry: dropped at the end, else refused
            cut = text.find(b"\n", end) + 1 or text.rfind(b"\n", 0, end) + 1
            if cut:
                yield _lf_only(b"".join((_BLOCK_PAD, memoryview(text)[:cut])))
                carry = text[cut:]
            else:
                carry = text


def _lf_only(block):
    if b"\r" in block:
        block = block.replace(b"\r\n", b"\n")
        if b"\r" in block:
            raise SlowPath
    return block


def vector_numeric(sn, columns):
    """The vectorised reader over all blocks of the file; raises SlowPath for anything unusual."""
    width = len(sn.header)
    table = _class_table(sn.delimiter, sn.decimal)
    row = np.array([_DELIM] * (width - 1) + [_EOL], np.uint8)
    pattern = np.tile(row, FAST_BLOCK_BYTES // width + 1)  # the separators of rows of at least width bytes
    parts = []
    for block in _byte_blocks(sn):
        parts.append(_parse_block(block, width, table, pattern)[:, columns])
    if not parts:
        raise SlowPath
    return np.concatenate(parts) if len(parts) != 1 else parts[0]
