"""The vectorised CSV reader and the block writer give exactly what the careful code gives.

``read_numeric_columns`` tries a vectorised reader (numbers and empty cells only), then numpy's
text parser, then the cell-by-cell reader whose errors name line and field. Arrays are compared
bit for bit (``view(np.uint64)``: -0.0, NaN and the last ulp all count).
"""

import numpy as np
import pytest

from facecap.solvers.io import csv as io_csv, csv_vector as io_csv_vector, csv_write as io_csv_write
from facecap.solvers.errors import InputFileError
from facecap.solvers.io.csv import read_numeric_columns, read_weights_csv, sniff, write_weights_csv


def bits(a):
    return np.ascontiguousarray(a, dtype=np.float64).view(np.uint64)


def outcome(reader, path):
    """("ok", shape, bits) or ("error", message) of one reader over every column of ``path``."""
    sn = sniff(path)
    try:
        values = reader(sn, list(range(len(sn.header))))
    except InputFileError as exc:
        return "error", str(exc)
    values = values[1] if isinstance(values, tuple) else values
    return "ok", values.shape, bits(values).tobytes()


def careful(path):
    return outcome(io_csv._slow_numeric, path)


def vector(path):
    return outcome(io_csv_vector.vector_numeric, path)


def write(tmp_path, data, name="t.csv"):
    path = tmp_path / name
    path.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
    return path


FAST = {
    "gaps": "frame,a_x,a_y\n1,,2\n2,3,\n3,,\n4,5,6\n",
    "negative and signed zeros": "frame,a_x,a_y\n1,-1.5,-0\n2,-0.0,+2\n3,-.5,+.25\n",
    "exponents": "frame,v,w\n1,1e-05,-2.5E+12\n2,1.23456789e-300,6.02e23\n3,1e22,1e-22\n4,7e0,0e99\n",
    "long and hard numbers": "frame,v,w\n1,0.30000000000000004,123456789012345678\n2,9007199254740993,"
                             "2.2250738585072014e-308\n3,0.1000000000000000055511151231257827,1e23\n",
    "CRLF": "frame,a_x,a_y\r\n1,0.25,-3\r\n2,,7.125\r\n",
    "no trailing newline": "frame,a_x,a_y\n1,0.25,-3\n2,1,2",
    "trailing blank lines": "frame,a_x,a_y\n1,0.25,-3\n\n\r\n",
    "semicolon": "Frame;A_x;A_y\n1;0.25;-3.5\n2;;1e-3\n",
    "semicolon and decimal comma": "Frame;A_x;A_y\n1;0,25;-3,5\n2;;1,5e-3\n3;12,125;0\n",
    "tab": "frame\ta_x\ta_y\n1\t.5\t-.25\n",
    "BOM and leading blank lines": "\ufeff\n\nframe,a_x,a_y\n1,2,3\n",
    "leading zeros": "frame,a_x,a_y\n001,007.50,-0000.0\n",
}
FALLBACK = {
    "gap words": "frame,a_x,a_y\n1,NA,nan\n2,null,3\n",
    "text column": "frame,a_x,label\n1,2,happy\n2,3,\n",
    "quotes": 'frame,a_x,a_y\n1,"2",3\n',
    "quote in the header": 'frame,a_x,"a_y\n1,2,3\n2,4,5\n',
    "blank line inside": "frame,a_x,a_y\n1,2,3\n\n2,4,5\n",
    "row of empty cells": "frame,a_x,a_y\n1,2,3\n,,\n2,4,5\n",
    "ragged": "frame,a_x,a_y\n1,2,3\n2,4\n",
    "spaces": "frame,a_x,a_y\n1, 2,3\n",
    "trailing point": "frame,a_x,a_y\n1,5.,3\n",
    "CR line ends": "frame,a_x,a_y\r1,2,3\r2,4,5\r",
    "bad number": "frame,a_x,a_y\n1,1-2,3\n",
    "two points": "frame,a_x,a_y\n1,1.2.3,3\n",
    "infinite": "frame,a_x,a_y\n1,1e999,3\n",
    "underscore (float() takes it)": "frame,a_x,a_y\n1,1_0,3\n",
    "non-ASCII digit (float() takes it)": "frame,a_x,a_y\n1,\u0661,3\n",
}


@pytest.mark.parametrize("text", FAST.values(), ids=FAST.keys())
def test_vectorised_reader_is_bit_identical_to_the_careful_one(tmp_path, text):
    path = write(tmp_path, text)
    expected = careful(path)
    assert expected[0] == "ok"
    assert vector(path) == expected
    assert outcome(read_numeric_columns, path) == expected


@pytest.mark.parametrize("text", FALLBACK.values(), ids=FALLBACK.keys())
def test_unusual_files_fall_back_with_the_same_result_or_error(tmp_path, text):
    path = write(tmp_path, text)
    with pytest.raises(io_csv_vector.SlowPath):
        io_csv_vector.vector_numeric(sniff(path), [0, 1])
    assert outcome(read_numeric_columns, path) == careful(path)


def test_errors_still_name_line_and_field(tmp_path):
    path = write(tmp_path, "frame,a_x,a_y,a_z\n1,0,0,0\n2,0,1-2,0\n", "take.csv")
    with pytest.raises(InputFileError, match=r"take\.csv, line 3, field 'a_y': expected a number, got '1-2'"):
        io_csv.read_markers_csv(path)


def random_cell(rng):
    v = rng.normal() * 10.0 ** int(rng.integers(-30, 30))
    spellings = [
        "", repr(v), f"{v:.9g}", f"{v:.3e}", f"{v:.6f}", f"{v:.17g}", f"{v:g}", f"{v:.12G}",
        str(int(rng.integers(-10 ** 6, 10 ** 6))), f"{rng.random():.16f}",
        f"{int(rng.integers(10 ** 9))}.{int(rng.integers(10 ** 9)):09d}",
        str(rng.choice(["-0", "+0", "-0.0", ".5", "-.25", "+1.5e3", "1E-05", "007", "1e-22", "1e22", "1e23",
                        "9007199254740993", "123456789012345678", "0.000001234", "4.9e-324", "1e-400"])),
    ]
    return spellings[int(rng.integers(len(spellings)))]


@pytest.mark.parametrize("seed", range(4))
def test_random_numeric_files_match_bit_for_bit(tmp_path, monkeypatch, seed):
    rng = np.random.default_rng(seed)
    fast = 0
    for case in range(60):
        delimiter, decimal = [(",", "."), (";", "."), (";", ","), ("\t", "."), ("|", ".")][case % 5]
        n_cols = int(rng.integers(1, 6))
        lines = [delimiter.join(["frame"] + [f"m{i}_x" for i in range(n_cols)])]
        for row in range(int(rng.integers(1, 40))):
            cells = [str(row + 1)] + [random_cell(rng) for _ in range(n_cols)]
            if decimal == ",":
                cells = [c.replace(".", ",") for c in cells]
            lines.append(delimiter.join(cells))
        eol = "\r\n" if case % 3 == 0 else "\n"
        path = write(tmp_path, eol.join(lines) + (eol if case % 4 else ""))
        # Tiny blocks put block boundaries everywhere (lines longer than a block, CRLF across reads).
        monkeypatch.setattr(io_csv_vector, "FAST_BLOCK_BYTES", int(rng.integers(1, 64)) if case % 2 else 1 << 20)
        expected = careful(path)
        assert expected[0] == "ok", (case, expected)
        assert outcome(read_numeric_columns, path) == expected, case
        try:
            got = vector(path)
        except io_csv_vector.SlowPath:  # mostly numbers of more than 16 digits: numpy's parser reads them
            continue
        assert got == expected, case
        fast += 1
    assert fast > 40


def mutate(data, rng):
    data = bytearray(data)
    tokens = [b"", b",", b";", b"\n", b"\r\n", b".", b"-", b"+", b"e", b"E", b"0", b"9", b"1e5", b" ", b"x", b'"']
    for _ in range(int(rng.integers(1, 4))):
        at = int(rng.integers(len(data) + 1))
        op = int(rng.integers(3))
        if op == 0:
            data[at:at] = tokens[int(rng.integers(len(tokens)))]
        elif op == 1:
            del data[at:at + int(rng.integers(1, 4))]
        else:
            data[at:at + 1] = tokens[int(rng.integers(len(tokens)))]
    return bytes(data)


def test_mutated_numeric_files_give_the_careful_result_or_error(tmp_path, monkeypatch):
    rng = np.random.default_rng(11)
    values = np.round(rng.normal(size=(10, 6)) * 10, 4)
    values[3, 2] = np.nan
    values[5, 0] = -0.0
    seed = "frame,a_x,a_y,a_z,b_x,b_y,b_z\n" + "".join(
        f"{i + 1}," + ",".join("" if np.isnan(v) else f"{v:.9g}" for v in row) + "\n" for i, row in enumerate(values))
    seeds = [seed, seed.replace("\n", "\r\n"), seed.replace(",", ";").replace(".", ","), seed.replace("4,", "4e-3,")]
    agreed = fast = 0
    for case in range(1500):
        path = write(tmp_path, mutate(seeds[case % len(seeds)].encode(), rng))
        monkeypatch.setattr(io_csv_vector, "FAST_BLOCK_BYTES", 48 if case % 2 else 1 << 20)
        try:
            expected = careful(path)
        except InputFileError:
            continue  # sniff refused the header
        assert outcome(read_numeric_columns, path) == expected, (case, path.read_bytes())
        try:
            got = vector(path)
        except io_csv_vector.SlowPath:
            got = None
        if got is not None:
            assert got == expected, (case, path.read_bytes())
            fast += 1
        agreed += 1
    assert agreed > 1000 and fast > 200


def test_only_the_requested_columns_in_their_order(tmp_path):
    path = write(tmp_path, "frame,a,b,c\n1,2,3,4\n2,5,,7\n")
    sn = sniff(path)
    expected = io_csv._slow_numeric(sn, [3, 0])[1]
    assert np.array_equal(bits(io_csv_vector.vector_numeric(sn, [3, 0])), bits(expected))


def legacy_lines(frames, values, delimiter, labels=None):
    """The data lines as the per-cell writer wrote them before the block writer."""
    out = []
    for i, (f, row) in enumerate(zip(io_csv_write._format_frames(np.asarray(frames, dtype=np.float64)), values)):
        cells = ["" if np.isnan(v) else f"{v:.9g}" for v in row]
        if labels is not None:
            cells.append(labels[i])
        out.append(f + delimiter + delimiter.join(cells) + "\n")
    return "".join(out)


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.float16, np.int64, np.uint8])
def test_block_writer_writes_the_same_text_as_the_per_cell_writer(tmp_path, monkeypatch, dtype):
    rng = np.random.default_rng(3)
    for case in range(40):
        n, k = int(rng.integers(0, 30)), int(rng.integers(0, 5))
        v = rng.normal(size=(n, k)) * 10.0 ** rng.integers(-12, 12, size=(n, k))
        if np.dtype(dtype).kind == "f":
            v[rng.random((n, k)) < 0.2] = np.nan
            v[rng.random((n, k)) < 0.05] = np.inf
            v[rng.random((n, k)) < 0.05] = -0.0
            with np.errstate(over="ignore"):
                v = v.astype(dtype)
        else:
            v = np.round(v).clip(np.iinfo(dtype).min, np.iinfo(dtype).max).astype(dtype)
        frames = np.arange(1, n + 1) if case % 3 else np.arange(n) * 0.5
        labels = [str(rng.choice(["", "posed_happy", "nan", "a nan"])) for _ in range(n)] if case % 4 == 0 else None
        delimiter = [",", ";", "\t"][case % 3]
        monkeypatch.setattr(io_csv_write, "WRITE_BLOCK_CELLS", int(rng.integers(1, 40)) if case % 2 else 1 << 18)
        header = ["frame"] + [f"s{i}" for i in range(k)]
        io_csv_write._write_table(tmp_path / "w.csv", header, frames, v, delimiter, labels=labels)
        head = delimiter.join(header + (["segment"] if labels is not None else [])) + "\n"
        expected = head + legacy_lines(frames, v, delimiter, labels)
        assert (tmp_path / "w.csv").read_bytes() == expected.encode(), case


def test_weights_round_trip_exactly_as_before(tmp_path):
    rng = np.random.default_rng(5)
    w = rng.random((500, 52))
    w[w < 0.1] = 0.0
    w[rng.random(w.shape) < 0.05] *= 1e-7
    w[rng.random(w.shape) < 0.01] = np.nan
    w[0, 0] = -0.0
    write_weights_csv(tmp_path / "w.csv", np.arange(1, 501), [f"s{k}" for k in range(52)], w)
    frames, names, back = read_weights_csv(tmp_path / "w.csv")
    # What the writer's 9 significant digits parse back to, cell by cell, NaN for gaps.
    expected = np.array([[np.nan if np.isnan(v) else float(f"{v:.9g}") for v in row] for row in w])
    assert np.array_equal(bits(back), bits(expected))
    assert np.array_equal(frames, np.arange(1, 501)) and len(names) == 52
    assert np.abs(back - w)[~np.isnan(w)].max() <= 5e-10
