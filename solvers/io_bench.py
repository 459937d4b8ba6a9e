"""Reader benchmark: ``python -m facecap.solvers.io_bench [frames] [markers]``.

Writes a synthetic take (default 36,000 frames x 100 markers, 1 % gaps) as C3D and wide CSV in
a temporary folder, reads each back, and prints the time and the peak traced memory
(``tracemalloc``, which numpy reports its buffers to) against the size of the (F, M, 3) float64
array the reader returns. Goal from issue 5: under 2 s each, memory under 3x the array.
"""

import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from .io_c3d import read_c3d, write_c3d
from .io_csv import read_wide_csv, write_markers_csv
from .markers import MarkerSet


def synthetic(frames=36000, markers=100, seed=0):
    rng = np.random.default_rng(seed)
    pos = rng.normal(size=(frames, markers, 3)).cumsum(axis=0) * 0.05 + rng.normal(size=(1, markers, 3)) * 50
    pos[rng.random((frames, markers)) < 0.01] = np.nan
    return MarkerSet(tuple(f"m{i:03d}" for i in range(markers)), np.arange(1, frames + 1), pos, fps=120, units="mm")


def measure(read, path, **options):
    """(seconds, peak bytes, MarkerSet) of one read."""
    tracemalloc.start()
    start = time.perf_counter()
    result = read(path, **options)
    seconds = time.perf_counter() - start
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return seconds, peak, result


def run(frames=36000, markers=100, out=print):
    """Print one line per format; returns {format: (seconds, peak_bytes, array_bytes)}."""
    take = synthetic(frames, markers)
    array_bytes = take.positions.nbytes
    results = {}
    with tempfile.TemporaryDirectory(prefix="facecap-io-bench-") as tmp:
        for name, write, read in (("c3d", write_c3d, read_c3d), ("csv", write_markers_csv, read_wide_csv)):
            path = Path(tmp) / f"take.{name}"
            write(path, take)
            size = path.stat().st_size
            read(path, units="mm", fps=120)  # warm the page cache and imports
            seconds, peak, back = measure(read, path, units="mm", fps=120)
            if not np.allclose(back.positions, take.positions, equal_nan=True, atol=1e-4):
                raise AssertionError(f"{name}: read back differs from what was written")
            results[name] = (seconds, peak, array_bytes)
            out(f"{name}: {frames} frames x {markers} markers ({size / 1e6:.1f} MB file): {seconds:.2f} s, "
                f"peak {peak / 1e6:.1f} MB = {peak / array_bytes:.2f}x the {array_bytes / 1e6:.1f} MB array")
    return results


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:3]]
    run(*args)
