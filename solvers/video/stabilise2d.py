"""2D stabilisation of image tracks: remove a per-frame similarity or affine fitted on stable points.

The 3D ``solvers.stabilise`` works on rigid 3D markers; in the image plane head motion is only
approximately a similarity (or an affine for small out-of-plane turns), fitted here per frame by
weighted least squares with optional Tukey reweighting so that a stable point that does move
(a cheek during a smile) loses its say.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError
from ..markers import MarkerSet


@dataclass(frozen=True, eq=False)
class Stabilise2DResult:
    """``markers`` in the reference frame's image coordinates; ``transforms`` (F, 2, 3) map raw -> stabilised."""

    markers: MarkerSet
    transforms: np.ndarray
    rms: np.ndarray  # (F,) residual of the stable points (px), NaN where not fitted
    flagged: np.ndarray  # (F,) bool: too few stable points


def _fit(src, dst, w, model):
    """Weighted fit dst ~ A src + t; returns (2, 3)."""
    ws = w / w.sum()
    ms, md = ws @ src, ws @ dst
    a, b = src - ms, dst - md
    if model == "similarity":
        var = ws @ np.sum(a * a, axis=1)
        c = ws @ (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]) / var
        s = ws @ (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) / var
        A = np.array([[c, -s], [s, c]])
    else:
        A = np.linalg.lstsq(a * np.sqrt(ws)[:, None], b * np.sqrt(ws)[:, None], rcond=None)[0].T
    return np.hstack([A, (md - A @ ms)[:, None]])


def stabilise_2d(markers, stable, *, model="similarity", reference_frame=None, robust=True, iterations=5):
    """Map every frame's 2D markers onto the reference frame using the ``stable`` markers.

    Parameters
    ----------
    markers : MarkerSet with D = 2
    stable : sequence of str
        Markers that move with the head only (e.g. nose bridge, temples, head-cam rig dots).
    model : "similarity" or "affine"
    reference_frame : frame number, optional
        Frame whose image coordinates are kept (default: the first frame with all stable points).
    """
    if markers.dim != 2:
        raise FacecapError(f"stabilise_2d needs 2D markers; got D = {markers.dim}")
    if model not in ("similarity", "affine"):
        raise FacecapError(f"`model` must be 'similarity' or 'affine'; got {model!r}")
    idx = markers.index(list(stable), what="stable marker")
    need = 2 if model == "similarity" else 3
    if len(idx) < need:
        raise FacecapError(f"{model} stabilisation needs at least {need} stable markers; got {len(idx)}")
    pts = markers.positions[:, idx]
    vis = ~np.isnan(pts[..., 0])
    if reference_frame is None:
        full = np.flatnonzero(vis.all(axis=1))
        if not len(full):
            raise FacecapError("no frame shows every stable marker; give `reference_frame`")
        r = full[0]
    else:
        hit = np.flatnonzero(markers.frames == reference_frame)
        if not len(hit):
            raise FacecapError(f"reference frame {reference_frame} is not in the take")
        r = hit[0]
    ref = pts[r]
    F = markers.n_frames
    T = np.full((F, 2, 3), np.nan)
    rms = np.full(F, np.nan)
    flagged = np.zeros(F, bool)
    for f in range(F):
        ok = vis[f] & vis[r]
        if ok.sum() < need:
            flagged[f] = True
            continue
        src, dst = pts[f, ok], ref[ok]
        w = np.ones(len(src))
        M = _fit(src, dst, w, model)
        for _ in range(iterations if robust and ok.sum() > need else 0):
            res = np.linalg.norm(src @ M[:, :2].T + M[:, 2] - dst, axis=1)
            scale = max(1.4826 * np.median(res), 0.05)
            u = res / (4.685 * scale)
            w = np.where(u < 1, (1 - u**2) ** 2, 0.0)
            if w.sum() < 1e-9 or (w > 0).sum() < need:
                break
            M = _fit(src, dst, w, model)
        T[f] = M
        rms[f] = np.sqrt(np.mean(np.sum((src @ M[:, :2].T + M[:, 2] - dst) ** 2, axis=1)))
    out = np.einsum("fij,fmj->fmi", T[:, :, :2], markers.positions) + T[:, None, :, 2]
    out[flagged] = np.nan
    return Stabilise2DResult(markers.with_positions(out), T, rms, flagged)
