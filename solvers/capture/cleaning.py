"""Marker cleaning: label swaps, spikes, gap filling and low-pass filtering, every change reported.

:func:`clean` runs the steps selected in a :class:`CleanSettings` in a fixed order:

1. ``fix_swaps``: two neighbouring markers that exchange labels for a while are swapped back
   (a frame where the exchanged assignment is much more continuous than the kept one toggles it).
2. ``spike_speed`` / ``spike_mad``: samples moving faster than a physical bound (units/s; a
   blink is the fastest facial motion, ~0.5 m/s), or whose second difference is an outlier by a
   robust median-absolute-deviation test, are removed (become gaps).
3. ``fill_spline``: interior gaps up to this many frames are filled by a cubic smoothing spline
   through the visible samples around them.
4. ``fill_model``: interior gaps up to this many frames are reconstructed from the other markers:
   a low-rank (PCA) regression learnt on the frames where the marker is visible, with the offset
   at the gap edges blended across the gap. Longer gaps stay gaps (the solve masks them).
5. ``lowpass_hz`` (zero-phase Butterworth, ``scipy.signal.filtfilt``) or ``one_euro``.
   ``CleanResult.removed`` holds what the filter took away (raw - filtered), so real fast
   expressions mistaken for noise can be seen.

Nothing is extrapolated past the first or last visible sample of a marker.
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import FacecapError, needs
from ..markers import MarkerSet
from ..options import default
from .smoothing import penalised_fit


@dataclass(frozen=True)
class CleanSettings:
    """Which cleaning steps to run (all off by default) and their parameters.

    Attributes
    ----------
    fix_swaps : bool
    swap_ratio : float
        A label swap is detected when the swapped assignment costs < ``swap_ratio`` x the kept one.
    spike_speed : float or None
        Maximum speed in the markers' units per second.
    spike_mad : float or None
        Threshold in robust standard deviations (1.4826 MAD) of the second difference.
    fill_spline : int
        Longest gap (frames) filled by spline; 0 = off.
    fill_model : int
        Longest gap (frames) reconstructed from the other markers; 0 = off.
    model_rank : int or None
        PCA components of the model; None keeps 99.5 % of the variance (at most 12).
    lowpass_hz : float or None
        Butterworth cutoff in Hz (must be below fps / 2).
    lowpass_order : int
    one_euro : tuple (min_cutoff_hz, beta, d_cutoff_hz) or None
    """

    fix_swaps: bool = default("clean.fix_swaps")
    swap_ratio: float = default("clean.swap_ratio")
    spike_speed: float = None
    spike_mad: float = None
    fill_spline: int = default("clean.fill_spline")
    fill_model: int = default("clean.fill_model")
    model_rank: int = None
    lowpass_hz: float = None
    lowpass_order: int = default("clean.lowpass_order")
    one_euro: tuple = None

    def __post_init__(self):
        for name in ("spike_speed", "spike_mad", "lowpass_hz"):
            value = getattr(self, name)
            if value is not None and not (np.isfinite(value) and value > 0):
                raise FacecapError(f"`{name}` must be positive or None; got {value!r}")
        for name in ("fill_spline", "fill_model", "lowpass_order"):
            value = getattr(self, name)
            if int(value) != value or value < 0:
                raise FacecapError(f"`{name}` must be a non-negative integer; got {value!r}")
        if not 0 < self.swap_ratio < 1:
            raise FacecapError(f"`swap_ratio` must be in (0, 1); got {self.swap_ratio!r}")
        if self.model_rank is not None and (int(self.model_rank) != self.model_rank or self.model_rank < 1):
            raise FacecapError(f"`model_rank` must be a positive integer or None; got {self.model_rank!r}")
        if self.lowpass_hz is not None and self.one_euro is not None:
            raise FacecapError("choose one filter: `lowpass_hz` or `one_euro`")
        if self.one_euro is not None:
            if len(self.one_euro) != 3 or not all(np.isfinite(v) and v >= 0 for v in self.one_euro) \
                    or self.one_euro[0] <= 0 or self.one_euro[2] <= 0:
                raise FacecapError(f"`one_euro` must be (min_cutoff > 0, beta >= 0, d_cutoff > 0); got {self.one_euro!r}")


@dataclass(frozen=True)
class StepReport:
    """One step: ``counts`` samples changed per marker (filled, removed, swapped or filtered)."""

    step: str
    counts: dict
    message: str = ""

    @property
    def total(self):
        return int(sum(self.counts.values()))


@dataclass(frozen=True)
class CleanReport:
    steps: tuple = ()

    def summary(self):
        """One line per step: name, total, the markers most affected."""
        lines = []
        for s in self.steps:
            top = sorted(((c, n) for n, c in s.counts.items() if c), reverse=True)[:5]
            detail = ", ".join(f"{n} {c}" for c, n in top)
            lines.append(f"{s.step}: {s.total} sample(s)" + (f" ({detail})" if detail else "")
                         + (f"; {s.message}" if s.message else ""))
        return "\n".join(lines)


@dataclass(frozen=True, eq=False)
class CleanResult:
    """The cleaned MarkerSet, what was done, and what the filter removed (F, M, D) or None."""

    markers: MarkerSet
    report: CleanReport
    removed: np.ndarray = None
    settings: CleanSettings = field(default_factory=CleanSettings)


def clean(markers, settings=None):
    """Run the steps selected in ``settings`` (a CleanSettings) on ``markers``; returns CleanResult."""
    if not isinstance(markers, MarkerSet):
        raise FacecapError("`markers` must be a MarkerSet")
    settings = CleanSettings() if settings is None else settings
    steps, removed = [], None
    m = markers
    if settings.fix_swaps:
        m, rep = fix_swaps(m, ratio=settings.swap_ratio)
        steps.append(rep)
    if settings.spike_speed is not None or settings.spike_mad is not None:
        m, rep = remove_spikes(m, max_speed=settings.spike_speed, mad=settings.spike_mad)
        steps.append(rep)
    if settings.fill_spline:
        m, rep = fill_gaps_spline(m, max_gap=settings.fill_spline)
        steps.append(rep)
    if settings.fill_model:
        m, rep = fill_gaps_model(m, max_gap=settings.fill_model, rank=settings.model_rank)
        steps.append(rep)
    if settings.lowpass_hz is not None:
        m, removed, rep = lowpass(m, cutoff_hz=settings.lowpass_hz, order=settings.lowpass_order)
        steps.append(rep)
    elif settings.one_euro is not None:
        m, removed, rep = one_euro(m, *settings.one_euro)
        steps.append(rep)
    return CleanResult(markers=m, report=CleanReport(tuple(steps)), removed=removed, settings=settings)


def gap_runs(visible):
    """Interior and edge gap runs of a (F,) visibility mask: list of (start, stop, interior)."""
    v = np.concatenate([[True], visible, [True]])
    d = np.diff(v.astype(np.int8))
    starts, stops = np.flatnonzero(d == -1), np.flatnonzero(d == 1)
    n = visible.size
    return [(int(a), int(b), a > 0 and b < n) for a, b in zip(starts, stops)]


def _counts(markers, per_marker):
    return {n: int(c) for n, c in zip(markers.names, per_marker)}


# ---------------------------------------------------------------------------------------------
# label swaps and spikes


def fix_swaps(markers, *, ratio=0.5):
    """Undo label swaps between each marker and its nearest neighbour. Returns (markers, StepReport)."""
    pos = markers.positions.copy()
    F, M, _ = pos.shape
    swapped = np.zeros(M, dtype=np.int64)
    if M < 2 or F < 3:
        return markers, StepReport("fix_swaps", _counts(markers, swapped))
    with np.errstate(invalid="ignore"):
        centre = np.nanmedian(pos, axis=0)
    dist = np.linalg.norm(centre[:, None] - centre[None], axis=2)
    np.fill_diagonal(dist, np.inf)
    dist[np.isnan(dist)] = np.inf
    pairs = {tuple(sorted((a, int(np.argmin(dist[a]))))) for a in range(M) if np.isfinite(dist[a]).any()}
    for a, b in sorted(pairs):
        pa, pb = pos[:, a], pos[:, b]
        keep = np.linalg.norm(pa[1:] - pa[:-1], axis=1) + np.linalg.norm(pb[1:] - pb[:-1], axis=1)
        swap = np.linalg.norm(pa[1:] - pb[:-1], axis=1) + np.linalg.norm(pb[1:] - pa[:-1], axis=1)
        ok = np.isfinite(keep) & np.isfinite(swap)
        if ok.sum() < 3:
            continue
        typical = np.median(keep[ok])
        separation = np.median(np.linalg.norm(pa - pb, axis=1)[np.isfinite(pa[:, 0] + pb[:, 0])])
        events = np.flatnonzero(ok & (swap < ratio * keep) & (keep > max(3 * typical, 0.5 * separation))) + 1
        if events.size == 0:
            continue
        state = np.zeros(F, dtype=bool)
        for f in events:
            state[f:] = ~state[f:]
        if state.any():
            pos[state, a], pos[state, b] = pb[state].copy(), pa[state].copy()
            swapped[[a, b]] += int(state.sum())
    return markers.with_positions(pos), StepReport("fix_swaps", _counts(markers, swapped),
                                                   "samples whose labels were exchanged back")


def remove_spikes(markers, *, max_speed=None, mad=None):
    """Remove spikes; removed samples become gaps. Returns (markers, StepReport).

    ``max_speed`` (units/s): a sample reached and left faster than this. ``mad``: a sample whose
    second difference is a local peak more than ``mad`` robust SDs (1.4826 MAD) above the median.
    """
    pos = markers.positions.copy()
    F, M, _ = pos.shape
    bad = np.zeros((F, M), dtype=bool)
    if max_speed is not None and F >= 2:
        step = np.linalg.norm(np.diff(pos, axis=0), axis=2) * markers.fps / np.diff(markers.frames)[:, None]
        fast = np.nan_to_num(step, nan=0.0) > max_speed
        into = np.vstack([np.zeros((1, M), bool), fast])
        out = np.vstack([fast, np.zeros((1, M), bool)])
        bad |= into & out
    if mad is not None and F >= 7:
        # Second difference: a one-frame excursion stands out against smooth (even fast) motion.
        acc = np.full((F, M), np.nan)
        acc[1:-1] = np.linalg.norm(pos[:-2] - 2 * pos[1:-1] + pos[2:], axis=2)
        for m in range(M):
            ok = np.isfinite(acc[:, m])
            if ok.sum() < 7:
                continue
            centre = np.median(acc[ok, m])
            scale = 1.4826 * np.median(np.abs(acc[ok, m] - centre))
            if scale <= 0:
                continue
            a = np.nan_to_num(acc[:, m], nan=0.0)
            peak = (a >= np.roll(a, 1)) & (a >= np.roll(a, -1))
            bad[:, m] |= peak & (a > centre + mad * scale)
    bad &= markers.visible
    pos[bad] = np.nan
    return markers.with_positions(pos), StepReport("remove_spikes", _counts(markers, bad.sum(axis=0)),
                                                   "samples removed as spikes (now gaps)")


# ---------------------------------------------------------------------------------------------
# gaps


def fill_gaps_spline(markers, *, max_gap):
    """Fill interior gaps of at most ``max_gap`` frames with a cubic smoothing spline.

    One discrete cubic smoothing spline per marker through all its visible samples, on the take's
    frames (``smoothing.penalised_fit``: one banded solve, so the work grows with the take's length
    however many gaps the spike removal cut), gives the values of its gaps; its smoothing weight is
    chosen once per marker by hiding 5-frame blocks of the marker's visible samples and keeping the
    weight that predicts them best. Visible samples and longer gaps are left as they are.
    """
    with needs("scipy", "Spline gap filling (Clean Markers)"):
        import scipy.linalg  # noqa: F401 - scipy: checked here, used by penalised_fit

    pos = markers.positions.copy()
    t = markers.frames
    filled = np.zeros(markers.n_markers, dtype=np.int64)
    for m in range(markers.n_markers):
        vis = ~np.isnan(pos[:, m, 0])
        runs = [(a, b) for a, b, interior in gap_runs(vis) if interior and b - a <= max_gap]
        if not runs or vis.sum() < 5:
            continue
        lam = _choose_smoothing(t, pos[:, m], vis)
        visible = np.flatnonzero(vis)
        first, last = visible[0], visible[-1] + 1
        fit = penalised_fit(t[first:last], pos[first:last, m], vis[first:last], lam)
        rows = np.concatenate([np.arange(a, b) for a, b in runs])
        pos[rows, m] = fit[rows - first]
        filled[m] += rows.size
    return markers.with_positions(pos), StepReport("fill_spline", _counts(markers, filled),
                                                   f"gaps of up to {max_gap} frames filled by spline")


_LAMBDAS = 10.0 ** np.arange(-1.0, 3.01, 0.5)
#: The smoothing weight of a marker with too few visible samples to choose one (the grid's middle)
_DEFAULT_LAMBDA = 10.0


def _choose_smoothing(t, track, vis, block=5, period=20, longest=240):
    """Smoothing weight for ``penalised_fit`` by hold-out: in the marker's longest visible run (or, with
    no run of ``4 * period`` frames, its first ``longest`` visible samples), blocks of ``block`` samples
    every ``period`` are hidden and predicted from the rest; the weight predicting them best wins."""
    runs = _visible_runs(vis)
    a, b = max(runs, key=lambda r: r[1] - r[0])
    if b - a >= 4 * period:
        chosen = np.arange(a, min(b, a + longest))
    else:
        chosen = np.flatnonzero(vis)[:longest]
        if chosen.size < 4 * period:
            return _DEFAULT_LAMBDA
    k = np.arange(chosen.size)
    hide = (k % period >= period // 2) & (k % period < period // 2 + block)
    hide[:period] = hide[-period:] = False
    first, last = chosen[0], chosen[-1] + 1
    weights = vis[first:last].astype(np.float64)
    weights[chosen[hide] - first] = 0.0
    test = chosen[hide]
    errors = [np.mean((penalised_fit(t[first:last], track[first:last], weights, lam)[test - first] - track[test]) ** 2)
              for lam in _LAMBDAS]
    return float(_LAMBDAS[int(np.argmin(errors))])


def fill_gaps_model(markers, *, max_gap, rank=None, min_train=30):
    """Reconstruct interior gaps of at most ``max_gap`` frames from the other markers.

    For each gap, the markers visible throughout it predict the missing one through a PCA
    regression learnt on the frames where all of them are visible; the prediction's error at the
    gap edges (mean of up to 3 frames each side) is blended linearly across the gap.
    """
    pos = markers.positions.copy()
    vis_all = markers.visible
    F, M, D = pos.shape
    filled = np.zeros(M, dtype=np.int64)
    skipped = 0
    for m in range(M):
        vis = ~np.isnan(pos[:, m, 0])
        for a, b, interior in gap_runs(vis):
            if not interior or b - a > max_gap:
                continue
            others = [k for k in range(M) if k != m and vis_all[a:b, k].all()]
            train = vis & vis_all[:, others].all(axis=1) if others else np.zeros(F, bool)
            if not others or train.sum() < min_train:
                skipped += 1
                continue
            X = pos[train][:, others].reshape(int(train.sum()), -1)
            Y = pos[train, m]
            mx, my = X.mean(axis=0), Y.mean(axis=0)
            U, s, Vt = np.linalg.svd(X - mx, full_matrices=False)
            if rank is None:
                energy = np.cumsum(s ** 2) / max(np.sum(s ** 2), 1e-300)
                r = int(min(np.searchsorted(energy, 0.995) + 1, 12, len(s)))
            else:
                r = int(min(rank, len(s)))
            scores = U[:, :r] * s[:r]
            coef, *_ = np.linalg.lstsq(scores, Y - my, rcond=None)

            def predict(rows):
                Z = pos[rows][:, others].reshape(len(rows), -1) - mx
                return (Z @ Vt[:r].T) @ coef + my

            gap_rows = np.arange(a, b)
            guess = predict(gap_rows)
            edges = []
            for rows in (np.flatnonzero(vis[:a] & vis_all[:a, others].all(axis=1))[-3:],
                         b + np.flatnonzero(vis[b:] & vis_all[b:, others].all(axis=1))[:3]):
                edges.append((pos[rows, m] - predict(rows)).mean(axis=0) if rows.size else None)
            lo = edges[0] if edges[0] is not None else edges[1]
            hi = edges[1] if edges[1] is not None else edges[0]
            if lo is not None:
                w = ((gap_rows - a + 1) / (b - a + 1))[:, None]
                guess = guess + (1 - w) * lo + w * hi
            pos[a:b, m] = guess
            filled[m] += b - a
    message = f"gaps of up to {max_gap} frames reconstructed from the other markers"
    if skipped:
        message += f"; {skipped} gap(s) without enough training frames left"
    return markers.with_positions(pos), StepReport("fill_model", _counts(markers, filled), message)


# ---------------------------------------------------------------------------------------------
# filters


def _visible_runs(visible):
    v = np.concatenate([[False], visible, [False]])
    d = np.diff(v.astype(np.int8))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def lowpass(markers, *, cutoff_hz, order=4):
    """Zero-phase Butterworth low-pass (forward-backward) on each visible run.

    Returns (markers, removed (F, M, D) = raw - filtered, StepReport). Runs too short for the
    filter's padding are left unfiltered and counted in the message.
    """
    with needs("scipy", "Low-pass filtering (Clean Markers)"):
        from scipy.signal import butter, filtfilt  # scipy: loaded on first use

    nyquist = markers.fps / 2.0
    if not 0 < cutoff_hz < nyquist:
        raise FacecapError(f"`cutoff_hz` must be between 0 and fps/2 = {nyquist:g}; got {cutoff_hz!r}")
    b, a = butter(int(order), cutoff_hz / nyquist)
    padlen = 3 * max(len(a), len(b))
    pos = markers.positions.copy()
    changed = np.zeros(markers.n_markers, dtype=np.int64)
    short = 0
    for m in range(markers.n_markers):
        for s, e in _visible_runs(~np.isnan(pos[:, m, 0])):
            if e - s <= padlen:
                short += 1
                continue
            pos[s:e, m] = filtfilt(b, a, pos[s:e, m], axis=0)
            changed[m] += e - s
    removed = markers.positions - pos
    msg = f"Butterworth order {order}, cutoff {cutoff_hz:g} Hz"
    if short:
        msg += f"; {short} run(s) shorter than {padlen + 1} frames left unfiltered"
    return markers.with_positions(pos), removed, StepReport("lowpass", _counts(markers, changed), msg)


def one_euro(markers, min_cutoff=1.0, beta=0.0, d_cutoff=1.0):
    """One-Euro filter (Casiez et al. 2012) per coordinate; state restarts after each gap.

    Returns (markers, removed (F, M, D), StepReport).
    """
    pos = markers.positions
    F = pos.shape[0]
    dt = np.diff(markers.frames, prepend=markers.frames[0] - 1.0) / markers.fps
    out = np.full_like(pos, np.nan)
    x_prev = np.full(pos.shape[1:], np.nan)
    dx_prev = np.zeros(pos.shape[1:])

    def alpha(cutoff, step):
        tau = 1.0 / (2 * np.pi * cutoff)
        return 1.0 / (1.0 + tau / step)

    for f in range(F):
        x = pos[f]
        fresh = np.isnan(x_prev)
        dx = np.where(fresh, 0.0, (x - x_prev) / dt[f])
        dx_hat = alpha(d_cutoff, dt[f]) * dx + (1 - alpha(d_cutoff, dt[f])) * dx_prev
        a = alpha(min_cutoff + beta * np.abs(dx_hat), dt[f])
        x_hat = np.where(fresh, x, a * x + (1 - a) * x_prev)
        out[f] = x_hat
        x_prev = x_hat  # NaN where x is a gap: the next sample starts fresh
        dx_prev = np.where(np.isnan(x_hat), 0.0, dx_hat)
    removed = pos - out
    counts = markers.visible.sum(axis=0)
    return (markers.with_positions(out), removed,
            StepReport("one_euro", _counts(markers, counts),
                       f"One-Euro min_cutoff {min_cutoff:g} Hz, beta {beta:g}, d_cutoff {d_cutoff:g} Hz"))


__all__ = ["CleanReport", "CleanResult", "CleanSettings", "StepReport", "clean", "fill_gaps_model",
           "fill_gaps_spline", "fix_swaps", "gap_runs", "lowpass", "one_euro", "remove_spikes"]
