"""Head stabilisation: remove rigid head motion using markers that do not deform with expression."""

import warnings

import numpy as np

from ..errors import FacecapError
from ..transforms import best_rotation, fit_rigid_batch, fit_rigid_masked, gap_mask, zero_rows
from .smoothing import local_polynomial
from .stabilise_2d import stabilise_2d, transforms_2d  # noqa: F401  (transforms_2d re-exported)
from .stabilise_result import StabiliseResult, frame_label, frame_rms


class _MovedMarkers:
    """Stabilised markers not computed yet: the pipeline refits or smooths a head pose before
    anyone reads its markers, so they are applied on first access (an (F, M, 3) product each).
    Read by ``StabiliseResult.markers`` (``stabilise_result.LazyMarkers``)."""

    def __init__(self, markers, R, t, scales, flagged):
        # The pose as of now (small copies), should a caller edit the result's arrays in place.
        self.args = markers, R.copy(), t.copy(), None if scales is None else scales.copy(), flagged.copy()

    def compute(self):
        markers, R, t, scales, flagged = self.args
        moved = _apply(R, t, scales, markers.positions)
        moved[flagged] = np.nan
        return markers._with_mapped_positions(moved)


MODES = ("rigid", "similarity")

#: Frames per block of the head refit: its temporaries are a few (block, M, 3) arrays (13 MB for
#: 68 markers) that the allocator reuses, not (F, M, 3) ones (587 MB each on 100 minutes at 60 fps).
REFIT_BLOCK = 8192


def _apply(R, t, scales, X):
    """s_f * R_f @ x + t_f for every point of every frame."""
    out = X @ _transposed(R)
    if scales is not None:
        out *= scales[:, None, None]
    out += t[:, None, :]
    return out


def _transposed(R):
    """R_f^T laid out contiguously: the batched product with a transposed view is ~2x slower
    (same result, bit for bit)."""
    return np.ascontiguousarray(R.transpose(0, 2, 1))


def _norm3(x):
    """``np.linalg.norm(x, axis=-1)`` for (..., 3), bit for bit (same summation order), ~4x faster:
    the reduction over a length-3 axis is slow."""
    sq = x * x
    total = sq[..., 0] + sq[..., 1]
    total += sq[..., 2]
    return np.sqrt(total, out=total)


def _columns(positions, idx):
    """``positions[:, idx]`` laid out frame-major: fancy indexing there returns a marker-major
    array, which makes every later pass over it ~2x slower."""
    return np.take(positions, idx, axis=1)


def _frame_scales(R, pts, reference, weights):
    """Per-frame least-squares scale (Umeyama) for fixed rotations, and the matching translation."""
    w = np.where(np.isnan(pts[:, :, 0]), 0.0, weights)
    safe = np.maximum(w.sum(axis=1), 1e-300)
    src = np.nan_to_num(pts)
    cs = np.einsum("fn,fnd->fd", w, src) / safe[:, None]
    ct = np.einsum("fn,nd->fd", w, reference) / safe[:, None]
    s0 = np.einsum("fij,fnj->fni", R, src - cs[:, None])
    t0 = reference[None] - ct[:, None]
    num = np.einsum("fn,fnd,fnd->f", w, t0, s0)
    den = np.einsum("fn,fnd,fnd->f", w, s0, s0)
    s = np.where(den > 0, num / np.maximum(den, 1e-300), 1.0)
    return s, ct - s[:, None] * np.einsum("fij,fj->fi", R, cs)


def stabilise_rigid(markers, stable, *, reference_frames=None, min_points=3, robust=True, iterations=6,
                    mode="rigid"):
    """Remove rigid head motion with a closed-form fit of ``stable`` markers per frame.

    Parameters
    ----------
    markers : MarkerSet (3D)
    stable : sequence of str
        Markers that move only with the head (forehead, temples, nose bridge); >= 3, spread out.
    reference_frames : (first, last) or None
        Inclusive frame range whose robust average defines the reference head pose
        (normally the neutral / T-pose). Default: the first frame where all stable markers
        are visible.
    min_points : int
        Frames with fewer usable stable markers are flagged.
    robust : bool
        Iteratively re-weighted fit (Tukey biweight on each marker's distance from the reference,
        scaled by the take's median residual), so a stable marker that slides or was placed on
        skin that moves is down-weighted in the frames where it moves. Frames where fewer than
        ``min_points`` markers keep a weight above one half are reported as ``unreliable``.
    iterations : int
        Re-weighting passes of the robust fit.
    mode : "rigid" or "similarity"
        "similarity" also fits a uniform scale per frame (captures from different days, a camera
        rig whose distance changes); the robust weights come from the rigid fit.

    Returns
    -------
    StabiliseResult
    """
    if markers.dim == 2:
        return stabilise_2d(markers, stable, reference_frames=reference_frames, mode=mode, min_points=min_points)
    if mode not in MODES:
        raise FacecapError(f"stabilise: mode must be one of {MODES} for 3D markers; got '{mode}'")
    if markers.dim != 3:
        raise FacecapError(f"{markers.source}: rigid stabilisation needs 3D markers; got {markers.dim}D")
    stable = tuple(stable)
    if len(stable) < 3:
        raise FacecapError(f"stabilise: need at least 3 stable markers; got {len(stable)} {list(stable)}")
    idx = markers.index(stable, what="stable marker")
    pts = _columns(markers.positions, idx)  # (F, S, 3)
    vis = ~np.isnan(pts[:, :, 0])

    reference = _reference_pose(markers, pts, vis, stable, reference_frames)
    weights = vis.astype(np.float64)
    R, t, rank_ok = fit_rigid_batch(pts, reference, weights)
    if robust and len(stable) >= 4:
        # Start the re-weighting from a least-median fit over triples of stable markers, so
        # that up to ~40% moving markers cannot drag the starting pose.
        R, t = _least_median_start(pts, reference, vis, R, t)
    keep = np.ones(len(stable), dtype=bool)
    filled = np.nan_to_num(pts)
    dist = _distances(R, t, filled, reference)
    for _ in range(iterations if robust else 0):
        weights = vis * keep * _tukey_weights(dist, vis)
        R, t, rank_ok = fit_rigid_batch(pts, reference, weights)
        dist = _distances(R, t, filled, reference)
        # A marker that moves in many frames is not rigid at all: drop it for the whole take
        # (a per-frame M-estimator only catches it once it has moved far).
        keep = _rigid_markers(dist, vis, keep)
    count = vis.sum(axis=1)
    flagged = (count < min_points) | ~rank_ok
    reasons = {}
    for f in np.flatnonzero(flagged):
        frame = frame_label(markers.frames[f])
        if count[f] < min_points:
            reasons[frame] = f"only {int(count[f])} of {len(stable)} stable markers visible (need {min_points})"
        else:
            reasons[frame] = "stable markers are (nearly) collinear"

    unreliable = ~flagged & ((weights > 0.5).sum(axis=1) < min_points)
    for f in np.flatnonzero(unreliable):
        reasons[frame_label(markers.frames[f])] = "fit unreliable: too few stable markers agree with the reference"
    with np.errstate(invalid="ignore"):
        trust = np.where(vis, weights, np.nan)
        trust = {n: float(np.nanmean(trust[:, i])) for i, n in enumerate(stable) if vis[:, i].any()}

    scales = None
    if mode == "similarity":
        scales, t = _frame_scales(R, pts, reference, weights)
    fitted = _apply(R, t, scales, pts)
    fitted -= reference
    err = _norm3(fitted)
    rms = frame_rms(np.where(vis, err, np.nan))
    rms[flagged] = np.nan
    return StabiliseResult(
        markers=_MovedMarkers(markers, R, t, scales, flagged),
        stable_names=stable,
        reference=reference,
        rotations=R,
        translations=t,
        rms=rms,
        flagged=flagged,
        flag_reasons=reasons,
        unreliable=unreliable,
        marker_trust=trust,
        scales=scales,
        mode=mode,
    )


def _least_median_start(pts, reference, vis, R0, t0, n_triples=40, seed=0):
    """Per frame, the rigid fit of the triple of stable markers whose fit has the least median residual."""
    S = reference.shape[0]
    combos = np.array([(a, b, c) for a in range(S) for b in range(a + 1, S) for c in range(b + 1, S)])
    # Keep well-spread triples only (a thin triangle gives a poor rotation).
    tri = reference[combos]
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    combos = combos[area > 0.25 * np.median(area)]
    if len(combos) > n_triples:
        combos = combos[np.random.default_rng(seed).choice(len(combos), n_triples, replace=False)]
    R, t = R0.copy(), t0.copy()
    # Only frames the plain fit leaves with an outlying stable marker need the search.
    filled = np.nan_to_num(pts)
    r0 = np.where(vis, np.linalg.norm(filled @ R0.transpose(0, 2, 1) + t0[:, None] - reference[None], axis=2), 0.0)
    sigma = 1.4826 * np.median(r0[vis]) if vis.any() else 0.0
    todo = np.flatnonzero(r0.max(axis=1) > 4.0 * max(sigma, 1e-12))
    if todo.size == 0:
        return R, t
    pts, vis, filled = pts[todo], vis[todo], filled[todo]
    F = todo.size
    best = np.full(F, np.inf)
    Rs, ts = R[todo], t[todo]
    for triple in combos:
        w = np.zeros((F, S))
        w[:, triple] = vis[:, triple]
        Rc, tc, ok = fit_rigid_batch(pts, reference, w)
        ok &= vis[:, triple].all(axis=1)
        r = np.linalg.norm((filled @ Rc.transpose(0, 2, 1)) + tc[:, None] - reference[None], axis=2)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # frames with no stable marker at all
            med = np.nanmedian(np.where(vis, r, np.nan), axis=1)
        better = ok & (med < best)
        best[better] = med[better]
        Rs[better], ts[better] = Rc[better], tc[better]
    R[todo], t[todo] = Rs, ts
    return R, t


def _distances(R, t, filled, reference):
    """(F, S) distance of each (gap-filled) stable marker from the reference after the fit."""
    fitted = filled @ _transposed(R)
    fitted += t[:, None, :]
    fitted -= reference
    return _norm3(fitted)


def _rigid_markers(dist, vis, keep, factor=3.0):
    """Stable markers whose 90th-percentile residual stays within ``factor`` x the typical one."""
    r = np.where(vis, dist, np.nan)
    with np.errstate(invalid="ignore"):
        p90 = np.nanpercentile(r, 90, axis=0)
    typical = np.nanmedian(p90[keep])
    ok = ~(p90 > factor * typical)
    if ok.sum() < 3:  # never drop below what a fit needs; keep the three most rigid
        ok = np.zeros_like(ok)
        ok[np.argsort(np.nan_to_num(p90, nan=np.inf))[:3]] = True
    return ok


def _tukey_weights(r, vis, c=4.685):
    """Tukey biweight of each stable marker's distance ``r`` (F, S) from the reference after the current fit."""
    sigma = 1.4826 * np.median(r[vis]) if vis.any() else 0.0
    sigma = max(sigma, 1e-12)
    u = r / (c * sigma)
    return np.where(u < 1.0, (1.0 - u**2) ** 2, 0.0)


def _reference_pose(markers, pts, vis, stable, reference_frames):
    """Robust reference: frames of the range aligned to their first complete frame, then the median."""
    if reference_frames is None:
        candidates = np.arange(markers.n_frames)
    else:
        first, last = reference_frames
        candidates = np.flatnonzero(markers.frame_range_mask(first, last))
        if candidates.size == 0:
            raise FacecapError(
                f"stabilise: reference frames {first}-{last} are outside the take "
                f"({frame_label(markers.frames[0])}-{frame_label(markers.frames[-1])})"
            )
    complete = candidates[vis[candidates].all(axis=1)]
    if complete.size == 0:
        missing = [stable[i] for i in np.flatnonzero(~vis[candidates].any(axis=0))]
        detail = f"; never visible there: {missing}" if missing else ""
        raise FacecapError(
            "stabilise: no frame in the reference range shows all stable markers" + detail
        )
    anchor = pts[complete[0]]
    sel = candidates if reference_frames is not None else complete[:1]
    w = vis[sel].astype(np.float64)
    reference = anchor
    # Generalised Procrustes: the shape is the median of the aligned frames; its pose is then
    # moved to the average head pose of the range (aligning to a template keeps the template's
    # pose, which would carry the noise of whichever frame came first).
    for _ in range(2):
        R, t, ok = fit_rigid_batch(pts[sel], reference, w)
        aligned = (pts[sel] @ R.transpose(0, 2, 1)) + t[:, None, :]
        aligned[~ok] = np.nan
        shape = np.nanmedian(aligned, axis=0)
        back = np.einsum("fji,fsj->fsi", R[ok], shape[None] - t[ok, None, :])  # shape in each frame's pose
        reference = back.mean(axis=0)
    return reference


def refine_rigid(markers, stab, names, predicted, *, weights):
    """Fine stage of hierarchical stabilisation (Sony): refit every frame's head pose on many markers.

    The gross fit uses only the stable markers; here each frame is refitted on ``names`` against
    where the current solve says those markers should be in the head frame (``predicted``), so
    markers that deform still contribute, explained by the solve instead of treated as rigid.

    Parameters
    ----------
    markers : MarkerSet, the raw (unstabilised) take
    stab : StabiliseResult of the gross fit (its reference and flags are kept)
    names : sequence of str, markers used in the refit
    predicted : ndarray (F, len(names), 3), positions in the stabilised head frame, NaN = unknown
    weights : ndarray (len(names),), relative trust per marker (stable markers higher)

    Returns
    -------
    StabiliseResult
    """
    idx = markers.index(names)
    predicted = np.asarray(predicted, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    F = markers.n_frames
    R, t, rank_ok = np.empty((F, 3, 3)), np.empty((F, 3)), np.empty(F, dtype=bool)
    for a in range(0, F, REFIT_BLOCK):  # frames are fitted independently (to rounding: best_rotation's
        # Newton steps run until the block's last frame settles)
        s = slice(a, a + REFIT_BLOCK)
        scales = None if stab.scales is None else stab.scales[s]
        R[s], t[s], rank_ok[s] = _refit(markers.positions[s], idx, predicted[s], weights, scales)
    flagged = stab.flagged | ~rank_ok
    R = np.where(flagged[:, None, None], stab.rotations, R)
    t = np.where(flagged[:, None], stab.translations, t)
    rms = _stable_rms(markers, stab, R, t, stab.scales, flagged)
    reasons = dict(stab.flag_reasons)
    for f in np.flatnonzero(flagged & ~stab.flagged):
        reasons[frame_label(markers.frames[f])] = "fine refit: markers not determined"
    return StabiliseResult(
        markers=_MovedMarkers(markers, R, t, stab.scales, flagged),
        stable_names=stab.stable_names,
        reference=stab.reference,
        rotations=R,
        translations=t,
        rms=rms,
        flagged=flagged,
        flag_reasons=reasons,
        unreliable=stab.unreliable,
        marker_trust=stab.marker_trust,
        scales=stab.scales,
        mode=stab.mode,
    )


def _refit(positions, idx, predicted, weights, scales):
    """refine_rigid's fit of the frames of ``positions`` (the raw take's) against ``predicted``."""
    raw = _columns(positions, idx)  # a copy of our own: the fit's cleaning is done here in place
    gap_raw, gap_pred = gap_mask(raw), gap_mask(predicted)
    w = np.where(gap_raw | gap_pred, 0.0, weights[None])
    raw[gap_raw] = 0.0
    predicted = zero_rows(predicted, gap_pred)
    # keep the gross fit's scale; refit rotation/translation on scaled points (then only the
    # unscaled fit's rank test is used)
    scaled = None if scales is None else raw * scales[:, None, None]
    R, t, rank_ok = fit_rigid_masked(raw, predicted, w, overwrite=True)
    if scaled is not None:
        R, t, _ = fit_rigid_masked(scaled, predicted, w, overwrite=True)
    return R, t, rank_ok


def _stable_rms(markers, stab, R, t, scales, flagged):
    """Per-frame RMS distance of ``stab``'s stable markers, moved by the pose (R, t, scales), from
    its reference; NaN on ``flagged`` frames. Computed on the stable markers only (the same numbers
    as those rows of the full product, bit for bit) and in blocks of frames: no (F, M, 3) temporaries."""
    idx = markers.index(stab.stable_names)
    rms = np.empty(markers.n_frames)
    for a in range(0, markers.n_frames, REFIT_BLOCK):
        s = slice(a, a + REFIT_BLOCK)
        fitted = _apply(R[s], t[s], None if scales is None else scales[s], _columns(markers.positions[s], idx))
        fitted[flagged[s]] = np.nan
        fitted -= stab.reference
        rms[s] = frame_rms(_norm3(fitted))
    return rms


def smooth_head_motion(markers, stab, *, half_window, order=3):
    """Zero-phase smoothing of the per-frame head pose (head motion is slower than marker noise).

    Rotation matrices and translations are smoothed element-wise by a local cubic fit (a chordal
    average, exact for the small changes within a window) and projected back onto rotations.
    Flagged frames do not contribute and stay flagged.
    """
    if half_window <= 0 or markers.dim != 3:
        return stab
    ok = (~stab.flagged).astype(np.float64)
    pose = np.concatenate([stab.rotations.reshape(-1, 9), stab.translations, stab.scale_array()[:, None]], axis=1)
    smooth = local_polynomial(pose, half_window=half_window, order=order, weights=ok)
    lost = np.isnan(smooth).any(axis=1) & ~stab.flagged
    smooth[stab.flagged | lost] = pose[stab.flagged | lost]
    R = best_rotation(smooth[:, :9].reshape(-1, 3, 3).transpose(0, 2, 1))  # the rotation nearest each average
    t = smooth[:, 9:12]
    scales = None if stab.scales is None else smooth[:, 12]
    rms = _stable_rms(markers, stab, R, t, scales, stab.flagged)  # all markers are moved when first read
    return StabiliseResult(
        markers=_MovedMarkers(markers, R, t, scales, stab.flagged),
        stable_names=stab.stable_names,
        reference=stab.reference,
        rotations=R,
        translations=t,
        rms=rms,
        flagged=stab.flagged,
        flag_reasons=stab.flag_reasons,
        unreliable=stab.unreliable,
        marker_trust=stab.marker_trust,
        scales=scales,
        mode=stab.mode,
    )
