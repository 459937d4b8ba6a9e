"""2D stabilisation of image tracks: a per-frame similarity, rigid or affine map of the stable points
onto a reference (the one implementation; ``stabilise.stabilise_rigid`` hands 2D takes here)."""

import warnings

import numpy as np

from ..errors import FacecapError
from .stabilise_result import StabiliseResult, frame_label, frame_rms


def stabilise_2d(markers, stable, *, reference_frames=None, mode="similarity", min_points=None, robust=True,
                 iterations=5):
    """Stabilise 2D tracks on stable points: per-frame similarity (or rigid) or affine map onto a reference.

    Parameters
    ----------
    markers : MarkerSet (2D image tracks)
    stable : sequence of str, points that move only with the head (>= 2 for similarity, >= 3 for affine)
    reference_frames : (first, last) or None; the median of that range (default: the first frame
        with every stable point) is the reference
    mode : "similarity", "rigid" or "affine"
    robust : bool
        Tukey-reweight the stable points per frame (``iterations`` refits), so a "stable" point that
        does move (a cheek in a smile, a slipping dot) loses its say; needs more points than the
        model's minimum.

    Returns
    -------
    StabiliseResult with ``rotations`` (F, 2, 2) holding the linear part (rotation x scale, or the
    affine matrix), ``translations`` (F, 2) (see ``transforms_2d``); frames with too few points are flagged.
    """
    if markers.dim != 2:
        raise FacecapError(f"stabilise 2D needs 2D markers; got D = {markers.dim}")
    if mode not in ("rigid", "similarity", "affine"):
        raise FacecapError(f"stabilise 2D: mode must be 'rigid', 'similarity' or 'affine'; got '{mode}'")
    stable = tuple(stable)
    need = 3 if mode == "affine" else 2
    min_points = need if min_points is None else max(min_points, need)
    if len(stable) < need:
        raise FacecapError(f"stabilise 2D ({mode}): need at least {need} stable points; got {len(stable)} {list(stable)}")
    idx = markers.index(stable, what="stable marker")
    pts = markers.positions[:, idx]
    vis = ~np.isnan(pts[:, :, 0])
    F = markers.n_frames
    if reference_frames is None:
        complete = np.flatnonzero(vis.all(axis=1))
        if complete.size == 0:
            raise FacecapError("stabilise 2D: no frame shows all stable points")
        reference = pts[complete[0]]
    else:
        sel = markers.frame_range_mask(*reference_frames)
        if not sel.any():
            raise FacecapError(f"stabilise 2D: reference frames {reference_frames[0]}-{reference_frames[1]} are outside the take")
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            reference = np.nanmedian(pts[sel], axis=0)
        if np.isnan(reference).any():
            raise FacecapError("stabilise 2D: a stable point is never visible in the reference frames")
    # Tukey scale floor, unit-free: a small fraction of the stable points' spread.
    floor = 1e-4 * float(np.sqrt(np.mean(np.sum((reference - reference.mean(axis=0)) ** 2, axis=1)))) or 1e-12
    A = np.tile(np.eye(2), (F, 1, 1))
    t = np.zeros((F, 2))
    flagged = vis.sum(axis=1) < min_points
    for f in np.flatnonzero(~flagged):
        x, y = pts[f, vis[f]], reference[vis[f]]
        w = np.ones(len(x))
        fit = _fit_2d(x, y, w, mode)
        for _ in range(iterations if robust and len(x) > need else 0):
            M, c = fit
            res = np.linalg.norm(x @ M.T + c - y, axis=1)
            u = res / (4.685 * max(1.4826 * np.median(res), floor))
            w = np.where(u < 1, (1 - u**2) ** 2, 0.0)
            if (w > 0).sum() < need:
                break
            fit = _fit_2d(x, y, w, mode) or fit
        if fit is None:
            flagged[f] = True
            continue
        A[f], t[f] = fit
    moved = (markers.positions @ A.transpose(0, 2, 1)) + t[:, None, :]
    moved[flagged] = np.nan
    err = np.linalg.norm(moved[:, idx] - reference[None], axis=2)
    rms = frame_rms(np.where(vis, err, np.nan))
    rms[flagged] = np.nan
    reasons = {frame_label(markers.frames[f]): f"only {int(vis[f].sum())} of {len(stable)} stable points visible "
               f"(need {min_points}) or they are degenerate" for f in np.flatnonzero(flagged)}
    return StabiliseResult(
        markers=markers._with_mapped_positions(moved), stable_names=stable, reference=reference, rotations=A,
        translations=t, rms=rms, flagged=flagged, flag_reasons=reasons, unreliable=np.zeros(F, dtype=bool),
        marker_trust={n: 1.0 for n in stable}, scales=None, mode=mode,
    )


def _fit_2d(x, y, w, mode):
    """Weighted fit ``y ~ M x + c`` (Umeyama for rigid/similarity, least squares for affine); None if degenerate."""
    wn = w / w.sum()
    cx, cy = wn @ x, wn @ y
    x0, y0 = x - cx, y - cy
    if mode == "affine":
        sw = np.sqrt(wn)[:, None]
        sol, _, rank, _ = np.linalg.lstsq(x0 * sw, y0 * sw, rcond=None)
        if rank < 2:
            return None
        M = sol.T
    else:
        U, _, Vt = np.linalg.svd((x0 * wn[:, None]).T @ y0)
        d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
        R = Vt.T @ np.diag([1.0, d]) @ U.T
        var = float(wn @ np.sum(x0**2, axis=1))
        if var <= 1e-24:
            return None
        M = R if mode == "rigid" else float(wn @ np.sum(y0 * (x0 @ R.T), axis=1)) / var * R
    return M, cy - M @ cx


def transforms_2d(result):
    """(F, 2, 3) matrices ``[A | t]`` mapping raw image points onto the reference, from a 2D StabiliseResult."""
    return np.concatenate([result.rotations, result.translations[:, :, None]], axis=2)
