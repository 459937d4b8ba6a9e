"""Seeded fuzzing of every reader: each mutated file loads or raises FacecapError, quickly, writing nothing."""

import os
import time
import warnings

import numpy as np
import pytest

from facecap.solvers import FacecapError, MarkerSet
from facecap.solvers.io.c3d import read_c3d
from facecap.solvers.io.c3d_write import write_c3d
from facecap.solvers.io.csv import read_wide_csv, write_markers_csv
from facecap.solvers.io.csv_long import read_long_csv
from facecap.solvers.io.json import read_json, write_json
from facecap.solvers.io.trc import read_trc, write_trc
from facecap.solvers.io.weights import read_weights

CASES = 2000
MAX_SECONDS = 5.0


def seed_take():
    rng = np.random.default_rng(7)
    pos = np.round(rng.normal(size=(12, 3, 3)) * 10, 3)
    pos[4, 1] = np.nan
    return MarkerSet(("brow_L", "lip", "chin"), np.arange(1, 13), pos, fps=60, units="mm",
                     segments={"posed_happy": [(3.0, 6.0)]})


def original(kind, tmp_path):
    m = seed_take()
    path = tmp_path / f"seed.{kind}"
    if kind == "csv":
        write_markers_csv(path, m, delimiter=";")
    elif kind == "c3d":
        write_c3d(path, m)
    elif kind == "trc":
        write_trc(path, m)
    elif kind == "json":
        write_json(path, m)
    elif kind == "long":
        rows = [f"{int(f)},{n},{x},{y},{z}" for f, frame in zip(m.frames, m.positions)
                for n, (x, y, z) in zip(m.names, frame)]
        path.write_text("frame,marker,x,y,z\n" + "\n".join(rows) + "\n")
    elif kind == "llf":
        head = "Timecode,BlendShapeCount,EyeBlinkLeft,JawOpen,HeadYaw,HeadPitch,HeadRoll"
        rows = [f"10:00:00:{i:02d}.000,52,0.{i},0.5,0.1,0.2,0.3" for i in range(12)]
        path.write_text(head + "\n" + "\n".join(rows) + "\n")
    return path.read_bytes()


READERS = {"csv": read_wide_csv, "c3d": read_c3d, "trc": read_trc, "json": read_json, "long": read_long_csv,
           "llf": read_weights}
TOKENS = [b"", b";", b",", b"\t", b"\n", b"\r\n", b"NA", b"nan", b"inf", b"-1e308", b"1e999", b"x", b'"',
          b"\x00", b"\xff", b"{", b"]", b"null", b"frame", b"Frame#", b"time", b"0", b"-1", b"65535", b"\x50"]


def mutate(data, rng):
    data = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        op = int(rng.integers(7))
        n = len(data)
        at = int(rng.integers(n + 1)) if n else 0
        if op == 0 and n:  # flip a byte
            data[min(at, n - 1)] = int(rng.integers(256))
        elif op == 1:  # insert a token
            data[at:at] = TOKENS[int(rng.integers(len(TOKENS)))]
        elif op == 2 and n:  # delete a range
            del data[at:at + int(rng.integers(1, 40))]
        elif op == 3:  # truncate
            del data[at:]
        elif op == 4 and n:  # duplicate a range
            chunk = data[at:at + int(rng.integers(1, 80))]
            data[at:at] = chunk
        elif op == 5 and n:  # replace a token-sized span
            data[at:at + int(rng.integers(1, 6))] = TOKENS[int(rng.integers(len(TOKENS)))]
        elif op == 6 and n >= 4:  # overwrite 2-4 bytes with random values (C3D words)
            k = int(rng.integers(2, 5))
            data[at:at + k] = rng.integers(0, 256, size=k, dtype=np.uint8).tobytes()
    return bytes(data)


@pytest.mark.parametrize("kind", sorted(READERS))
def test_fuzz_reader(kind, tmp_path):
    seed_dir = tmp_path / "seed"
    seed_dir.mkdir()
    data = original(kind, seed_dir)
    work = tmp_path / "work"
    work.mkdir()
    path = work / f"case.{kind}"
    reader = READERS[kind]
    rng = np.random.default_rng(sum(map(ord, kind)))
    loaded = refused = 0
    slowest = 0.0
    for case in range(CASES):
        case_bytes = mutate(data, rng)
        path.write_bytes(case_bytes)
        start = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                reader(path)
            loaded += 1
        except FacecapError:
            refused += 1
        except Exception as exc:  # noqa: BLE001 - the point of the test
            raise AssertionError(f"{kind} case {case}: {type(exc).__name__}: {exc}\n{case_bytes[:300]!r}") from exc
        slowest = max(slowest, time.perf_counter() - start)
        assert os.listdir(work) == [path.name], f"{kind} case {case} wrote {os.listdir(work)}"
    print(f"{kind}: {loaded} loaded, {refused} refused, slowest {slowest * 1e3:.1f} ms")
    assert loaded + refused == CASES and refused > 0 and loaded > 0
    assert slowest < MAX_SECONDS
    assert os.listdir(seed_dir) == [f"seed.{kind}"]


# --------------------------------------------------------------------------------------------
# classes found by the reliability campaign (issue 18): each generated with seeded variations


C3D_EXTREMES = [0.0, -1.0, -60.0, 1e-30, 1e30, float("nan"), float("inf"), -float("inf"), 65535.0, 32767.0, -32768.0]


def c3d_numeric_params(data):
    """(offset, etype, count) of every numeric parameter value in a facecap-written C3D file."""
    import struct

    out = []
    pos = 512 + 4
    while pos + 2 <= len(data):
        nlen, gid = struct.unpack_from("bb", data, pos)
        if nlen == 0 or gid == 0:
            break
        name_end = pos + 2 + abs(nlen)
        offset = struct.unpack_from("<h", data, name_end)[0]
        if gid > 0:
            etype, ndim = struct.unpack_from("bB", data, name_end + 2)
            dims = data[name_end + 4:name_end + 4 + ndim]
            count = int(np.prod(list(dims))) if ndim else 1
            if etype in (2, 4):
                out.append((name_end + 4 + ndim, etype, count))
        if offset <= 0:
            break
        pos = name_end + offset
    return out


def test_fuzz_c3d_parameter_values(tmp_path):
    """Any numeric parameter or header word set to an extreme (negative ANALOG:RATE, zero frame
    words, NaN scale, ...) gives a MarkerSet or a FacecapError."""
    import struct

    seed = tmp_path / "seed.c3d"
    write_c3d(seed, seed_take())
    data = seed.read_bytes()
    params = c3d_numeric_params(data)
    header_words = [(2 + 2 * i, 2, 1) for i in range(9)] + [(12, 4, 1), (20, 4, 1)]
    rng = np.random.default_rng(18)
    path = tmp_path / "case.c3d"
    loaded = refused = 0
    for case in range(600):
        case_bytes = bytearray(data)
        for _ in range(int(rng.integers(1, 4))):
            at, etype, count = (params + header_words)[int(rng.integers(len(params) + len(header_words)))]
            value = C3D_EXTREMES[int(rng.integers(len(C3D_EXTREMES)))]
            k = int(rng.integers(count))
            if etype == 4:
                struct.pack_into("<f", case_bytes, at + 4 * k, value)
            else:
                word = int(value) if np.isfinite(value) else 0
                struct.pack_into("<H", case_bytes, at + 2 * k, word & 0xFFFF)
        path.write_bytes(bytes(case_bytes))
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                got = read_c3d(path)
            loaded += 1
            assert np.abs(got.frames).max() <= 2 ** 31 - 1
        except FacecapError:
            refused += 1
        except Exception as exc:  # noqa: BLE001 - the point of the test
            raise AssertionError(f"C3D parameter case {case}: {type(exc).__name__}: {exc}") from exc
    assert loaded + refused == 600 and loaded > 0 and refused > 0


def test_c3d_negative_analog_rate_and_zero_frame_words_read_the_points(tmp_path):
    import struct

    m = seed_take()
    write_c3d(tmp_path / "t.c3d", m)
    data = bytearray((tmp_path / "t.c3d").read_bytes())
    at_rate = data.index(b"\x04\x02RATE") + 10  # ANALOG (group 2) RATE: name, offset, type, ndim, value
    struct.pack_into("<f", data, at_rate, -60.0)
    at_used = data.index(b"\x04\x02USED") + 10
    for used in (4, 80):  # the reproducers: used x (rate ratio -1) analog words per frame
        struct.pack_into("<H", data, at_used, used)
        (tmp_path / "t.c3d").write_bytes(bytes(data))
        notes = []
        got = read_c3d(tmp_path / "t.c3d", notes=notes)
        np.testing.assert_allclose(got.positions, m.positions, rtol=1e-6)
        assert "ANALOG:RATE -60 ignored (not a positive rate)" in notes


def test_fuzz_json_huge_integers(tmp_path):
    """Integers beyond Python's int-digit limit anywhere in a JSON take: loaded or refused, never ValueError."""
    import re

    seed = tmp_path / "seed.json"
    write_json(seed, seed_take())
    text = seed.read_text()
    numbers = [m.span() for m in re.finditer(r"-?\d+(\.\d+)?([eE][-+]?\d+)?", text)]
    rng = np.random.default_rng(4300)
    path = tmp_path / "case.json"
    for case in range(300):
        a, b = numbers[int(rng.integers(len(numbers)))]
        digits = int(rng.choice([20, 310, 4301, 5000, 20000]))
        huge = ("-" if rng.random() < 0.3 else "") + "9" * digits
        path.write_text(text[:a] + huge + text[b:])
        try:
            got = read_json(path)
            assert np.isfinite(got.frames).all() and np.abs(got.frames).max() <= 2 ** 31 - 1
        except FacecapError:
            pass
        except Exception as exc:  # noqa: BLE001 - the point of the test
            raise AssertionError(f"JSON case {case} ({digits} digits at {a}): {type(exc).__name__}: {exc}") from exc


HUGE_FRAMES = [2 ** 31 - 1, 2 ** 31, 2 ** 32 + 5, 2 ** 53, 9223372036854775807, 1e300, -(2 ** 31) - 5]


def frames_case(case, n):
    """Frame numbers 1..n with the last one huge, or the first one far below -2^31 (the reproducer's class)."""
    frames = [str(f) for f in range(1, n + 1)]
    huge = HUGE_FRAMES[case % len(HUGE_FRAMES)]
    text = str(huge) if isinstance(huge, int) else repr(huge)
    if huge < 0:
        frames[0] = text
    else:
        frames[-1] = text
    return frames, abs(huge) <= 2 ** 31 - 1


@pytest.mark.parametrize("kind", ["csv", "trc", "json", "long", "weights"])
def test_frame_numbers_beyond_32_bits_are_refused_with_the_file_named(kind, tmp_path):
    m = seed_take()
    path = tmp_path / f"case.{ {'long': 'csv', 'weights': 'csv'}.get(kind, kind)}"
    for case in range(len(HUGE_FRAMES)):
        big, fits = frames_case(case, m.n_frames)
        if kind == "csv":
            rows = [",".join([b] + [f"{v:.3f}" for v in p.ravel()]) for b, p in zip(big, np.nan_to_num(m.positions))]
            path.write_text("frame," + ",".join(f"{n}_{a}" for n in m.names for a in "xyz") + "\n" + "\n".join(rows))
        elif kind == "trc":
            write_trc(path, m)
            lines = path.read_text().split("\n")
            lines[6:6 + len(big)] = [b + line[line.index("\t"):] for b, line in zip(big, lines[6:6 + len(big)])]
            path.write_text("\n".join(lines))
        elif kind == "json":
            write_json(path, m)
            text = path.read_text()
            old = '"frames":[' + ",".join(str(int(f)) for f in m.frames) + "]"
            assert old in text
            path.write_text(text.replace(old, '"frames":[' + ",".join(big) + "]"))
        elif kind == "long":
            path.write_text("frame,marker,x,y,z\n" + "\n".join(f"{b},{n},1,2,3" for b in big for n in m.names))
        else:
            path.write_text("frame,jawOpen\n" + "\n".join(f"{b},0.5" for b in big))
        reader = read_weights if kind == "weights" else READERS[kind]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if fits:
                reader(path)  # 2^31 - 1 itself is accepted
                continue
            with pytest.raises(FacecapError, match=r"case\.\w+.*frame number .* is outside \+-2147483647"):
                reader(path)


def test_csv_header_longer_than_64_kib_is_read_whole(tmp_path):
    names = [f"marker_with_a_long_descriptive_name_{i:05d}" for i in range(1000)]
    header = "frame," + ",".join(f"{n}_{a}" for n in names for a in "xyz")
    assert len(header) > 2 * (1 << 16)  # twice the old 64 KiB sniffing window
    rng = np.random.default_rng(1000)
    values = np.round(rng.normal(size=(4, 3000)) * 100, 3)
    path = tmp_path / "wide.csv"
    path.write_text(header + "\n" + "\n".join(f"{f}," + ",".join(map(str, row)) for f, row in
                                               zip(range(1, 5), values)) + "\n")
    got = read_wide_csv(path, units="mm")
    assert got.names == tuple(names)
    np.testing.assert_array_equal(got.positions.reshape(4, -1), values)


def test_duplicate_column_check_is_linear(tmp_path):
    """A 600 KB header of one repeated column (200,000 columns): refused quickly, naming it once.
    The old quadratic check took 4-7 s on a quarter of this."""
    path = tmp_path / "dup.csv"
    path.write_text("frame," + ",".join(["ab"] * 200_000) + "\n1," + ",".join(["0"] * 200_000) + "\n")
    start = time.perf_counter()
    with pytest.raises(FacecapError, match=r"line 1: duplicate columns \['ab'\]"):
        read_wide_csv(path)
    assert time.perf_counter() - start < MAX_SECONDS
