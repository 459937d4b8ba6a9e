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
