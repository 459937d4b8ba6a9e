"""Bookkeeping of the windowed whole-take solve (``engine.temporal``): cores, windows, held frames, seams.

Why windows: the whole-take kernel holds its (F, K) iterates and, in its first pass, the banded
Cholesky factor of every frame's free variables (about 29 KB a frame on the sample character:
10 GB for 100 minutes at 60 fps). Solved window by window, the memory is that of one window per
process, whatever the length of the take.

Why the result is still the whole take's optimum (exact, not an approximation): Q couples a frame
with frames f +- 1 and f +- 2 only, so the optimality (KKT) conditions of a frame involve its own
variables and those of four neighbours.

1. The take is cut into cores of about ``length`` frames. Each core is solved inside a window that
   runs ``overlap`` frames past it on both sides, with free ends. Every frame of a core at least
   two frames from its edges then meets the whole take's conditions (its neighbours are the same
   window's, its temporal terms the take's), to the kernel's tolerance. The others are the seams.
2. Each seam is settled by solving a window around it with the two frames beyond each end held at
   their current values: the whole take's problem restricted to the window (its temporal operator
   is the take's, ``window_operator``; the held neighbours move to the right-hand side,
   ``held_coupling``). Inside it the conditions then hold. The frames just outside see their
   neighbours move by the change of the window's two edge frames; if that change could move their
   residual past the kernel's tolerance, the window doubles and is solved again (merging with a
   neighbouring seam's when they meet), until its edges stay where they were.

Every frame then meets the whole take's conditions: the unwindowed optimum, up to the tolerance of
the kernel itself. Windows only grow where the problem needs it (a long stretch without data
across a seam is bridged by the smoothing: its window grows over it).
"""

import numpy as np

#: Frames closer than this between two seam windows: merged into one (so that a solve of one never
#: moves a frame the other's edge conditions read: couplings reach two frames).
SEAM_GAP = 4


def cores(F, length):
    """Edges (n + 1,) of n >= 2 cores of about ``length`` frames covering [0, F)."""
    n = max(2, -(-F // max(int(length), 1)))
    return np.linspace(0, F, n + 1).round().astype(np.int64)


def window_operator(T, a, b):
    """The take's temporal operator ``T`` = (diag, off1, off2) restricted to the frames [a, b).

    Unlike ``temporal_operator(b - a)`` (a window with free ends), the diagonal keeps the terms of
    differences that reach outside the window: their other frames are held, not absent."""
    diag, off1, off2 = T
    return diag[a:b], off1[a : max(a, b - 1)], off2[a : max(a, b - 2)]


def held_coupling(T, w, a, b):
    """(b - a, K): the temporal operator's coupling of the frames [a, b) with the held frames a - 2,
    a - 1, b, b + 1 at their values ``w`` (F, K); subtracted from the window's right-hand side."""
    _, off1, off2 = T
    F = w.shape[0]
    out = np.zeros((b - a, w.shape[1]))
    if a >= 1:  # off1[f] couples f and f + 1, off2[f] couples f and f + 2
        out[0] += off1[a - 1] * w[a - 1]
        if b - a > 1:
            out[1] += off2[a - 1] * w[a - 1]
    if a >= 2:
        out[0] += off2[a - 2] * w[a - 2]
    if b < F:
        out[-1] += off1[b - 1] * w[b]
        if b - a > 1:
            out[-2] += off2[b - 2] * w[b]
    if b + 1 < F:
        out[-1] += off2[b - 1] * w[b + 1]
    return out


def coupling(T):
    """Largest total coupling of a frame with the two frames on one side of it (for the edge test)."""
    _, off1, off2 = T
    return float(np.abs(off1).max(initial=0.0) + np.abs(off2).max(initial=0.0))


def edge_changes(old, new, a, b, F):
    """(left, right): the largest change of the two frames at each end of the window [a, b) whose
    neighbours outside it read them (0 at an end of the take)."""
    d = np.abs(new - old)
    left = float(d[:2].max(initial=0.0)) if a > 0 else 0.0
    right = float(d[-2:].max(initial=0.0)) if b < F else 0.0
    return left, right


class Seams:
    """Seam windows: sorted, disjoint [a, b) frame ranges, each settled or not."""

    def __init__(self, edges, half, F):
        self.F = F
        self.spans = []
        for e in np.asarray(edges)[1:-1].tolist():
            self.add(max(0, e - half), min(F, e + half))

    def add(self, a, b):
        """Add [a, b) unsettled, merged with every span closer than ``SEAM_GAP`` frames."""
        keep = []
        for s in self.spans:
            if s[0] <= b + SEAM_GAP and a <= s[1] + SEAM_GAP:
                a, b = min(a, s[0]), max(b, s[1])
            else:
                keep.append(s)
        keep.append([a, b, False])
        self.spans = sorted(keep)

    def next(self):
        """The first unsettled span as (a, b), or None."""
        for a, b, done in self.spans:
            if not done:
                return a, b
        return None

    def settle(self, a, b, grow_left, grow_right):
        """Mark [a, b) settled, or replace it by a wider one (doubled on the sides that moved)."""
        self.spans = [s for s in self.spans if (s[0], s[1]) != (a, b)]
        if not (grow_left or grow_right):
            self.spans = sorted(self.spans + [[a, b, True]])
            return
        width = b - a
        self.add(max(0, a - width) if grow_left else a, min(self.F, b + width) if grow_right else b)
