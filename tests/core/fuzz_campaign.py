"""A seeded fuzz campaign over every reader, for counts (not a test: ``python tests/core/fuzz_campaign.py``).

Seeds: the small files of ``test_fuzz_io`` (one per format), the reader reproducers of
``shared/bugs/reliability`` (beside the checkout, ``tests/shared_data.py``) and a few small real captures; each seed is mutated ``--cases``
times with ``test_fuzz_io.mutate`` and read with ``import_markers`` (``read_weights`` for Live Link
Face). Prints, per seed, how many cases loaded, were refused with a FacecapError, raised anything
else (by exception type), loaded frame numbers beyond 2^31 or ran longer than ``--slow`` seconds.
To count for another version, point ``PYTHONPATH`` at its checkout and ``FUZZ_HELPERS`` at its
``tests/core`` (for its ``test_fuzz_io``).
"""

import argparse
import collections
import os
import signal
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: shared_data
import shared_data  # noqa: E402

HERE = Path(os.environ.get("FUZZ_HELPERS", Path(__file__).resolve().parent))
BUGS = shared_data.BUGS / "reliability"
REAL = shared_data.REALDATA
SEEDS = [
    ("c3d", BUGS / "c3d_negative_analog_rate.c3d"),
    ("c3d", BUGS / "c3d_zero_frame_words.c3d"),
    ("json", BUGS / "json_huge_int.json"),
    ("csv", BUGS / "frames" / "take_9e18.csv"),
    ("c3d", REAL / "c3d" / "btk_MyCube.c3d"),
    ("c3d", REAL / "c3d" / "ezc3d_FP_Type3.c3d"),
    ("c3d", REAL / "c3d" / "c3dorg_16_basketball.c3d"),
    ("trc", REAL / "trc" / "opensim_InverseKinematics_arm26_elbow_flex.trc"),
]


class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang


def seeds(tmp):
    """(name, kind, bytes) of every seed; test_fuzz_io's own seeds first."""
    sys.path.insert(0, str(HERE))
    import test_fuzz_io

    out = []
    for kind in sorted(test_fuzz_io.READERS):
        out.append((f"fuzz-seed.{kind}", kind, test_fuzz_io.original(kind, tmp)))
    for kind, path in SEEDS:
        if path.is_file():
            data = path.read_bytes()
            if kind == "csv":  # the first 40 rows and the last keep the campaign quick
                rows = data.rstrip(b"\n").split(b"\n")
                data = b"\n".join(rows[:40] + rows[-1:]) + b"\n"
            out.append((path.name, kind, data))
    llf = REAL / "llf" / "llf_alex_rom_3.csv"
    if llf.is_file():
        out.append((llf.name + "[:40]", "llf", b"\n".join(llf.read_bytes().split(b"\n")[:40]) + b"\n"))
    return out


def read(kind, path):
    from facecap.solvers.io import import_markers, read_weights

    if kind == "llf":
        return read_weights(path)
    return import_markers(path)


def run(cases, slow):
    from facecap.solvers.errors import FacecapError

    sys.path.insert(0, str(HERE))
    from test_fuzz_io import mutate

    signal.signal(signal.SIGALRM, _alarm)
    totals = collections.Counter()
    other = collections.Counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name, kind, data in seeds(tmp):
            rng = np.random.default_rng(sum(map(ord, name)))
            ext = {"long": "csv", "llf": "csv"}.get(kind, kind)
            path = tmp / f"case.{ext}"
            counts = collections.Counter()
            for case in range(cases):
                path.write_bytes(mutate(data, rng) if case else data)
                start = time.perf_counter()
                signal.alarm(int(slow * 4) + 1)
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        got = read(kind, path)
                    frames = got.frames if kind == "llf" else got.markers.frames
                    if np.abs(frames).max() > 2 ** 31 - 1:
                        counts["loaded frames beyond 2^31"] += 1
                    counts["loaded"] += 1
                except FacecapError:
                    counts["refused"] += 1
                except Hang:
                    counts["hang"] += 1
                except Exception as exc:  # noqa: BLE001 - what the campaign counts
                    counts["other"] += 1
                    other[f"{kind}: {type(exc).__name__}: {str(exc)[:70]}"] += 1
                finally:
                    signal.alarm(0)
                if time.perf_counter() - start > slow:
                    counts["slow"] += 1
            totals.update(counts)
            print(f"{name:55s} {dict(counts)}", flush=True)
            for leftover in os.listdir(tmp):
                if leftover.startswith("."):
                    raise AssertionError(f"{name}: a reader left {leftover}")
    print(f"TOTAL {sum(totals[k] for k in ('loaded', 'refused', 'other', 'hang'))} files: {dict(totals)}")
    for text, n in other.most_common():
        print(f"  {n:5d}  {text}")
    return totals


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=500, help="mutations per seed (default 500)")
    parser.add_argument("--slow", type=float, default=2.0, help="seconds that count as slow (default 2)")
    args = parser.parse_args(argv)
    run(args.cases, args.slow)


if __name__ == "__main__":
    main()
