"""Neutral / T-pose normalisation: the neutral from ranges, a file or detection; master T-pose offsets.

Sony's two steps (course notes section 4.4): align the take's T-pose to the performer's *master*
T-pose on landmark markers that change little from day to day (eye and mouth corners), then add
per-marker offsets that make the take's T-pose equal the master and carry them through the take,
interpolated between a start and an end T-pose when both exist (which also cancels slow slip).
Everything here works on *stabilised* markers (the head frame), so rigid fits are small.
"""

import fnmatch
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError
from ..transforms import fit_rigid_batch, fit_similarity
from .neutral import neutral_from_frames
from .stable_markers import _moving_mean

#: default landmark patterns: eye corners and mouth corners (case-insensitive globs)
DEFAULT_LANDMARKS = ("*eye*outer*", "*eye*inner*", "*eye_corner*", "*canthus*", "*mouth_corner*", "*lip_corner*")


def neutral_from_ranges(markers, ranges):
    """Median per marker over several inclusive frame ranges ([(first, last), ...]) — start and end T-poses."""
    ranges = [tuple(r) for r in ranges]
    if not ranges:
        raise FacecapError("neutral: no frame range given")
    if len(ranges) == 1:
        return neutral_from_frames(markers, *ranges[0])
    sel = np.zeros(markers.n_frames, dtype=bool)
    for first, last in ranges:
        if last < first:
            raise FacecapError(f"neutral: frame range {first}-{last} is empty (last < first)")
        sel |= markers.frame_range_mask(first, last)
    if not sel.any():
        raise FacecapError(f"neutral: frames {ranges} are outside the take")
    block = markers.positions[sel]
    never = np.isnan(block[:, :, 0]).all(axis=0)
    if never.any():
        raise FacecapError(f"neutral: marker(s) {[markers.names[i] for i in np.flatnonzero(never)]} have no sample "
                           f"in frames {ranges}")
    return np.nanmedian(block, axis=0)


def detect_neutral_frames(markers, *, count=None, fraction=0.05, max_compare=1500):
    """The "most neutral" frames: the pose the face holds longest and returns to most.

    ``markers`` are stabilised. A relaxed face is the densest point of the take's poses (T-poses,
    and the rest the face returns to between expressions), whereas the take's median pose is an
    average expression. The densest frame (closest ``count``-th neighbour, RMS marker distance
    between poses smoothed over ~0.15 s) is the robust reference, and the ``count`` frames least
    deformed from it are returned.

    Returns
    -------
    frames : ndarray of the chosen frame numbers (sorted)
    deformation : (F,) RMS deformation per frame from the reference (metres, NaN where skipped)
    """

    # Compare poses smoothed over ~0.15 s: frame-to-frame noise would hide a held pose otherwise.
    P = _moving_mean(markers.positions, max(1, int(round(0.075 * markers.fps))))
    F = markers.n_frames
    n = max(3, int(round(fraction * F))) if count is None else int(count)
    n = min(n, F)
    vis = ~np.isnan(P[:, :, 0])
    ok = vis.sum(axis=1) >= 0.5 * markers.n_markers
    if not ok.any():
        raise FacecapError("neutral detection: no frame shows at least half of the markers")
    fill = np.where(np.isnan(P), np.nanmedian(P[ok], axis=0)[None], P).reshape(F, -1)
    rows = np.flatnonzero(ok)
    cmp = rows if rows.size <= max_compare else rows[np.linspace(0, rows.size - 1, max_compare).astype(int)]
    sq = (fill**2).sum(axis=1)
    d = np.sqrt(np.maximum(sq[:, None] + sq[None, cmp] - 2.0 * fill @ fill[cmp].T, 0.0) / markers.n_markers)
    k = min(n, cmp.size - 1)
    kth = np.partition(d[rows], k, axis=1)[:, k]
    ref = fill[rows[int(np.argmin(kth))]].reshape(P.shape[1:])  # the most often held pose
    for _ in range(2):
        dist = np.linalg.norm(P - ref[None], axis=2)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            dev = np.sqrt(np.nanmean(np.where(vis, dist, np.nan) ** 2, axis=1))
        dev[~ok] = np.nan
        order = np.argsort(np.where(np.isfinite(dev), dev, np.inf))[:n]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            new = np.nanmedian(P[order], axis=0)
        ref = np.where(np.isnan(new), ref, new)
    return np.sort(markers.frames[order]), dev


def neutral_from_file(file_markers, take_stab, *, stable_names):
    """A neutral captured separately (``[neutral] file``): its median pose, moved into the take's head frame.

    The file's stable markers are fitted (rigidly) onto the take's stabilisation reference.
    ``file_markers`` must be in the take's units (metres here). Returns (M_file, 3) and the names.
    """

    pose = np.nanmedian(file_markers.positions, axis=0)
    common = [n for n in stable_names if n in set(file_markers.names)]
    if len(common) < 3:
        raise FacecapError(f"neutral file {file_markers.source}: needs at least 3 of the stable markers "
                           f"{list(stable_names)}; has {common}")
    src = pose[file_markers.index(common)]
    tgt = take_stab.reference[[list(take_stab.stable_names).index(n) for n in common]]
    R, t, ok = fit_rigid_batch(src[None], tgt[None], np.ones((1, len(common))))
    if not ok[0]:
        raise FacecapError(f"neutral file {file_markers.source}: its stable markers are collinear")
    return pose @ R[0].T + t[0]


def match_landmarks(names, patterns):
    """Names matching any of the glob ``patterns`` (case-insensitive), in order."""
    pats = [p.lower() for p in patterns]
    return tuple(n for n in names if any(fnmatch.fnmatchcase(n.lower(), p) for p in pats))


@dataclass(frozen=True, eq=False)
class MasterNormalisation:
    """Per-marker offsets (F, M, 3) that make the take's T-pose(s) equal the master T-pose."""

    offsets: np.ndarray  # (F, M, 3), metres, in the stabilised head frame
    master: np.ndarray  # (M, 3) master T-pose in the take's head frame
    landmarks: tuple
    start_offset: np.ndarray  # (M, 3)
    end_offset: np.ndarray  # (M, 3) or None
    landmark_residual: np.ndarray  # (L,) distance of the landmarks after the alignment (metres)

    def report(self, names):
        mag = np.linalg.norm(self.start_offset, axis=1)
        out = {"landmarks": list(self.landmarks),
               "landmark_residual_mm": [round(float(v) * 1e3, 4) for v in self.landmark_residual],
               "offset_mm": {n: round(float(v) * 1e3, 4) for n, v in zip(names, mag)}}
        if self.end_offset is not None:
            slip = np.linalg.norm(self.end_offset - self.start_offset, axis=1)
            out["slip_mm"] = {n: round(float(v) * 1e3, 4) for n, v in zip(names, slip)}
        return out


def master_offsets(stab_markers, master_markers, ranges, *, landmarks=DEFAULT_LANDMARKS, scale=False):
    """Offsets that normalise a stabilised take to a performer's master T-pose.

    Parameters
    ----------
    stab_markers : MarkerSet, the stabilised take (metres)
    master_markers : MarkerSet, the master T-pose capture (metres; every frame is T-pose)
    ranges : [(first, last), ...] the take's T-pose ranges; the first is the start T-pose, a
        second one the end T-pose (offsets are interpolated linearly in time between their centres)
    landmarks : glob patterns (or names) of the landmark markers the alignment uses (>= 3)
    scale : bool, allow a uniform scale in the landmark alignment

    Returns
    -------
    MasterNormalisation
    """
    names = stab_markers.names
    missing = [n for n in names if n not in set(master_markers.names)]
    if missing:
        raise FacecapError(f"master T-pose {master_markers.source}: has no marker(s) {missing[:8]}")
    marks = match_landmarks(names, landmarks)
    if len(marks) < 3:
        raise FacecapError(f"master T-pose: landmarks {list(landmarks)} match {list(marks)}; need at least 3 markers "
                           "(eye and mouth corners; set [neutral] landmarks)")
    master_pose = np.nanmedian(master_markers.positions, axis=0)[master_markers.index(names)]
    li = np.array(stab_markers.index(marks))
    tposes = [neutral_from_frames(stab_markers, *r) for r in ranges[:2]]
    align = fit_similarity(master_pose[li], tposes[0][li], allow_scale=scale)
    master = align.apply(master_pose)
    residual = np.linalg.norm(master[li] - tposes[0][li], axis=1)
    # Both T-poses are in the same (stabilised) head frame, so the master aligned on the start
    # T-pose's landmarks serves both; what differs at the end is slip, which the ramp cancels.
    offs = [master - pose for pose in tposes]
    F = stab_markers.n_frames
    end = None if len(offs) == 1 else offs[1]
    if end is None:
        offsets = np.broadcast_to(offs[0], (F,) + offs[0].shape).copy()
    else:
        c0 = 0.5 * (ranges[0][0] + ranges[0][1])
        c1 = 0.5 * (ranges[1][0] + ranges[1][1])
        u = np.clip((stab_markers.frames - c0) / (c1 - c0 if c1 != c0 else 1.0), 0.0, 1.0)
        offsets = (1 - u)[:, None, None] * offs[0][None] + u[:, None, None] * end[None]
    return MasterNormalisation(offsets=offsets, master=master, landmarks=marks, start_offset=offs[0],
                               end_offset=end, landmark_residual=residual)
