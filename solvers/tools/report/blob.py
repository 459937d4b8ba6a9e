"""The review page's bulk data: numeric arrays packed into one compressed block, and the min/max envelope.

A 36,000-frame take of 52 shapes is 1.9 million weights. As JSON text that alone would be 10 MB; the
page instead carries every array quantised to a fixed step (weights to 0.001, lengths to 1 um), as
little-endian integers, concatenated and deflated (zlib), in base64. The page inflates it with the
browser's own ``DecompressionStream`` and builds typed arrays from it, so zooming can show every frame.
Measured on a 36,000 x 52 solve: 3.7 MB of int16 weights deflate to 1.3 MB (level 1, 0.1 s).
"""

import base64
import zlib

import numpy as np

#: zlib level: 1 is 5x faster than 6 on solved weights for 9 % more bytes.
LEVEL = 1
#: Integer types by range (numpy dtype, the page's name for it); the smallest that holds the data wins.
INT_TYPES = ((np.int16, "i2"), (np.int32, "i4"))


class Blob:
    """Arrays added one by one, then ``pack``ed: (base64 text, manifest for the page).

    Each manifest entry is ``{"name", "dtype", "shape", "offset", "step", "nan"}``: the page reads
    ``shape`` values of ``dtype`` at byte ``offset`` of the inflated block and multiplies them by
    ``step``; the integer ``nan`` (the type's minimum) stands for a missing value.
    """

    def __init__(self):
        self.parts, self.entries, self.size = [], [], 0

    def add(self, name, values, step):
        """Quantise ``values`` (any shape, NaN allowed) to multiples of ``step`` and add them as ``name``."""
        values = np.asarray(values, dtype=np.float64)
        finite = np.isfinite(values)
        q = np.zeros(values.shape, dtype=np.float64)
        np.divide(values, step, out=q, where=finite)
        np.round(q, out=q)
        top = float(np.abs(q[finite]).max()) if finite.any() else 0.0
        dtype, code = next(((t, c) for t, c in INT_TYPES if top < np.iinfo(t).max), INT_TYPES[-1])
        limit = np.iinfo(dtype).max
        if top >= limit:  # beyond int32 steps: clip (a display value, the files keep the exact ones)
            np.clip(q, -limit, limit, out=q)
        out = q.astype(dtype)
        out[~finite] = np.iinfo(dtype).min
        self._append(name, out, code, step, int(np.iinfo(dtype).min))

    def add_exact(self, name, values):
        """Add float64 values unquantised (frame numbers, which may be fractional)."""
        self._append(name, np.asarray(values, dtype="<f8"), "f8", 1.0, None)

    def _append(self, name, array, code, step, nan):
        pad = (-self.size) % 8  # typed arrays need offsets aligned to their item size
        if pad:
            self.parts.append(b"\0" * pad)
            self.size += pad
        data = np.ascontiguousarray(array).astype(array.dtype.newbyteorder("<"), copy=False).tobytes()
        self.entries.append({"name": name, "dtype": code, "shape": list(array.shape), "offset": self.size,
                             "step": step, "nan": nan})
        self.parts.append(data)
        self.size += len(data)

    def pack(self):
        """(base64 text of the deflated block, manifest list)."""
        return base64.b64encode(zlib.compress(b"".join(self.parts), LEVEL)).decode("ascii"), self.entries


def unpack(text, manifest):
    """The arrays of a packed blob as {name: float64 ndarray} (NaN restored): what the page reads."""
    raw = zlib.decompress(base64.b64decode(text))
    out = {}
    for e in manifest:
        dtype = np.dtype("<" + e["dtype"])
        n = int(np.prod(e["shape"])) if e["shape"] else 1
        values = np.frombuffer(raw, dtype=dtype, count=n, offset=e["offset"]).reshape(e["shape"])
        floats = values.astype(np.float64) * e["step"]
        if e["nan"] is not None:
            floats[values == e["nan"]] = np.nan
        out[e["name"]] = floats
    return out


def envelope(x, y, buckets):
    """A curve reduced to at most ``2 * buckets`` points that keeps each bucket's minimum and maximum.

    The frames are cut into ``buckets`` equal runs; of each run the lowest and the highest sample are
    kept, in frame order, so a one-frame spike survives at any reduction (a plain every-n-th sample
    would drop it). A run with no finite sample gives one NaN point (a gap in the line). The page's
    own reduction (``review.js``, on every zoom) is the same rule.

    Parameters
    ----------
    x : (N,) increasing
    y : (N,) NaN for missing
    buckets : int

    Returns
    -------
    (x, y) : (P,) arrays, P <= 2 * buckets (N when N <= 2 * buckets)
    """
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    n = y.size
    if n <= 2 * buckets:
        return x.copy(), y.copy()
    edges = (np.arange(buckets + 1) * n) // buckets
    lo_y = np.where(np.isnan(y), np.inf, y)
    hi_y = np.where(np.isnan(y), -np.inf, y)
    lo = np.minimum.reduceat(lo_y, edges[:-1])
    hi = np.maximum.reduceat(hi_y, edges[:-1])
    bucket = np.repeat(np.arange(buckets), np.diff(edges))
    # index of the first minimum / maximum of each bucket
    i_lo = _first_where(lo_y == lo[bucket], bucket, buckets)
    i_hi = _first_where(hi_y == hi[bucket], bucket, buckets)
    empty = ~np.isfinite(lo)
    first, second = np.minimum(i_lo, i_hi), np.maximum(i_lo, i_hi)
    idx = np.stack([first, second], axis=1)
    keep = np.ones_like(idx, dtype=bool)
    keep[:, 1] = first != second
    keep[empty, 1] = False
    idx[empty, 0] = edges[:-1][empty]
    out_idx = idx[keep]
    out_y = y[out_idx]
    out_y[np.repeat(empty, keep.sum(axis=1))] = np.nan
    return x[out_idx], out_y


def _first_where(mask, bucket, buckets):
    """Per bucket, the first index where ``mask`` is true (the bucket's first index when none is)."""
    idx = np.flatnonzero(mask)
    first = np.full(buckets, -1, dtype=np.int64)
    # reversed so that the earliest index of each bucket is the one left written
    first[bucket[idx[::-1]]] = idx[::-1]
    starts = np.searchsorted(bucket, np.arange(buckets))
    return np.where(first < 0, starts, first)
