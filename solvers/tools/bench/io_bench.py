"""Reader benchmark: ``python -m facecap.solvers.tools.bench.io_bench [frames] [markers] [repeats]``.

Writes a synthetic take (default 36,000 frames x 100 markers, 1 % gaps) as C3D and wide CSV in
a temporary folder, reads each back, and prints the median time over ``repeats`` reads (default 5)
and the peak traced memory (``tracemalloc``, which numpy reports its buffers to) against the size
of the (F, M, 3) float64 array the reader returns. Goal from issue 5: under 2 s each, memory under
3x the array. A last line times writing and reading a weights CSV of the same frames x 52 shapes.
"""

import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from ...io.c3d import read_c3d
from ...io.c3d_write import write_c3d
from ...io.csv import read_weights_csv, read_wide_csv, write_markers_csv, write_weights_csv
from ...markers import MarkerSet
from .bench import median_time


def synthetic(frames=36000, markers=100, seed=0):
    rng = np.random.default_rng(seed)
    pos = rng.normal(size=(frames, markers, 3)).cumsum(axis=0) * 0.05 + rng.normal(size=(1, markers, 3)) * 50
    pos[rng.random((frames, markers)) < 0.01] = np.nan
    return MarkerSet(tuple(f"m{i:03d}" for i in range(markers)), np.arange(1, frames + 1), pos, fps=120, units="mm")


def synthetic_weights(frames=36000, shapes=52, seed=0):
    """Weights in [0, 1] with exact zeros, tiny values (written with an exponent) and 1 % gaps."""
    rng = np.random.default_rng(seed)
    w = rng.random((frames, shapes))
    w[w < 0.1] = 0.0
    w[rng.random(w.shape) < 0.05] *= 1e-6
    w[rng.random(w.shape) < 0.01] = np.nan
    return w


def measure(read, path, **options):
    """(seconds, peak bytes, MarkerSet) of one read."""
    tracemalloc.start()
    start = time.perf_counter()
    result = read(path, **options)
    seconds = time.perf_counter() - start
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return seconds, peak, result


def run(frames=36000, markers=100, out=print, repeats=5):
    """Print one line per format; returns {format: (seconds, peak_bytes, array_bytes)}.

    ``seconds`` is the median over ``repeats`` reads; the peak is that of the first.
    """
    take = synthetic(frames, markers)
    array_bytes = take.positions.nbytes
    results = {}
    with tempfile.TemporaryDirectory(prefix="facecap-io-bench-") as tmp:
        for name, write, read in (("c3d", write_c3d, read_c3d), ("csv", write_markers_csv, read_wide_csv)):
            path = Path(tmp) / f"take.{name}"
            write(path, take)
            size = path.stat().st_size
            read(path, units="mm", fps=120)  # warm the page cache and imports
            _, peak, back = measure(read, path, units="mm", fps=120)
            if not np.allclose(back.positions, take.positions, equal_nan=True, atol=1e-4):
                raise AssertionError(f"{name}: read back differs from what was written")
            seconds = median_time(lambda: read(path, units="mm", fps=120), repeats)[0]
            results[name] = (seconds, peak, array_bytes)
            out(f"{name}: {frames} frames x {markers} markers ({size / 1e6:.1f} MB file): {seconds:.2f} s, "
                f"peak {peak / 1e6:.1f} MB = {peak / array_bytes:.2f}x the {array_bytes / 1e6:.1f} MB array")
        weights = synthetic_weights(frames)
        names = [f"shape{k:02d}" for k in range(weights.shape[1])]
        path = Path(tmp) / "weights.csv"
        write_s = median_time(lambda: write_weights_csv(path, take.frames, names, weights), repeats)[0]
        read_s = median_time(lambda: read_weights_csv(path), repeats)[0]
        back = read_weights_csv(path)[2]
        if not np.allclose(back, weights, equal_nan=True, rtol=1e-8, atol=0):
            raise AssertionError("weights: read back differs from what was written")
        results["weights"] = (write_s, read_s, weights.nbytes)
        out(f"weights csv: {frames} frames x {weights.shape[1]} shapes ({path.stat().st_size / 1e6:.1f} MB): "
            f"write {write_s:.2f} s, read {read_s:.2f} s")
    return results


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:4]]
    run(*args[:2], **({"repeats": args[2]} if len(args) > 2 else {}))
