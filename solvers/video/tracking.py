"""Sparse 2D tracking: pyramidal Lucas-Kanade with forward-backward checks, drift control and
lighting-robust re-registration (see :class:`LKTracker`).

Per frame and point there are two estimates (the thesis' Alg. 4.3, applied to points):

* **continuous** - LK from the previous frame, starting at the previous position;
* **direct** - LK from the neutral *reference* frame's patch straight to this frame, started at
  the continuous estimate (or, for a lost point, at a prediction from the points still held).

Each passes a forward-backward check; the direct estimate is used unless it fails or matches the
reference patch clearly worse than the continuous one, so errors do not accumulate (drift stays
bounded) while large expressions, which the reference patch matches badly, lean on the continuous
estimate. Loss thresholds are relative to each point's own measured noise. A point that fails both
is a gap (NaN) until the direct registration re-acquires it (``reseed``); losses and recoveries are
reported by name.
"""

import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import FacecapError, InputFileError
from ..io.files import read_text_input
from ..markers import MarkerSet
from .reading import Footage, Job, opencv


@dataclass(frozen=True, eq=False)
class TrackResult:
    """Tracked 2D markers (source pixels, origin top-left) plus per-sample confidence.

    ``confidence`` (F, M) is in [0, 1] (0 at gaps); ``lost`` maps a marker name to the frame
    numbers where it was lost, ``reseeded`` to those where it was re-acquired.
    """

    markers: MarkerSet
    confidence: np.ndarray
    reference: int
    method: str
    lost: dict = field(default_factory=dict)
    reseeded: dict = field(default_factory=dict)

    def summary(self):
        vis = self.markers.visible
        return (f"tracked {self.markers.n_markers} points over {self.markers.n_frames} frames with "
                f"{self.method}: {100 * vis.mean():.1f}% visible, mean confidence "
                f"{self.confidence[vis].mean() if vis.any() else 0:.2f}, "
                f"{sum(len(v) for v in self.lost.values())} losses, "
                f"{sum(len(v) for v in self.reseeded.values())} re-acquisitions")


def read_seed_points(path):
    """Named 2D seed positions from a ``name,x,y`` text file (header optional): ``(names, (M, 2))``."""
    names, xy = [], []
    text = read_text_input(path).splitlines()
    first = True
    for line_no, line in enumerate(text, 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        cells = [c.strip() for c in line.replace(";", ",").replace("\t", ",").split(",")]
        header, first = first, False
        if len(cells) < 3:
            raise InputFileError(path, f"expected name,x,y; got {line!r}", line=line_no)
        try:
            x, y = float(cells[1]), float(cells[2])
        except ValueError:
            if header:
                continue  # e.g. "name,x,y"
            raise InputFileError(path, f"x, y must be numbers; got {cells[1]!r}, {cells[2]!r}", line=line_no) from None
        if not (np.isfinite(x) and np.isfinite(y)):
            raise InputFileError(path, "x, y must be finite", line=line_no)
        if cells[0] in names:
            raise InputFileError(path, f"duplicate point name {cells[0]!r}", line=line_no)
        names.append(cells[0])
        xy.append((x, y))
    if not names:
        raise InputFileError(path, "no points")
    return tuple(names), np.asarray(xy, dtype=np.float64)


def auto_seeds(image, region, *, max_points=100, quality=0.01, min_distance=None, prefix="p"):
    """Corner features (Shi-Tomasi) inside ``region`` = [x, y, w, h] of a grayscale image: ``(names, (M, 2))``."""
    cv2 = opencv()
    x, y, w, h = (int(round(v)) for v in check_region(region, image.shape))
    mask = np.zeros(image.shape[:2], np.uint8)
    mask[y: y + h, x: x + w] = 255
    if min_distance is None:
        min_distance = max(3.0, 0.5 * np.sqrt(w * h / max(max_points, 1)))
    pts = cv2.goodFeaturesToTrack(image, int(max_points), float(quality), float(min_distance), mask=mask,
                                  blockSize=7)
    if pts is None or len(pts) == 0:
        raise FacecapError(f"no trackable features in region {list(region)}: too little texture")
    pts = pts.reshape(-1, 2).astype(np.float64)
    pts = pts[np.lexsort((pts[:, 0], pts[:, 1]))]  # stable order: top to bottom, left to right
    names = tuple(f"{prefix}{i:03d}" for i in range(len(pts)))
    return names, pts


def check_region(region, shape):
    try:
        x, y, w, h = (float(v) for v in region)
    except (TypeError, ValueError):
        raise FacecapError(f"`region` must be [x, y, w, h]; got {region!r}") from None
    H, W = shape[:2]
    if w <= 0 or h <= 0 or x < 0 or y < 0 or x + w > W or y + h > H:
        raise FacecapError(f"`region` {list(region)} must be a non-empty box inside the {W}x{H} frame")
    return x, y, w, h


def fit_similarity_2d(src, dst, weights=None):
    """Least-squares 2D similarity ``dst ~ s R src + t``; returns a (2, 3) matrix."""
    w = np.ones(len(src)) if weights is None else np.asarray(weights, float)
    w = w / w.sum()
    ms, md = w @ src, w @ dst
    a, b = src - ms, dst - md
    var = w @ np.sum(a * a, axis=1)
    c = w @ (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]) / var
    s = w @ (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) / var
    A = np.array([[c, -s], [s, c]])
    return np.hstack([A, (md - A @ ms)[:, None]])


class LKTracker:
    """Frame-by-frame LK tracker of reference points (working-resolution pixels).

    Per frame and point: a *continuous* estimate (LK from the previous frame) and a *direct* one
    (LK from the reference patch, started at the continuous estimate or, for a lost point, at a
    similarity prediction from the held points), each checked forward-backward (the backward pass
    starts where the point came from, so large head motion does not fail the check). The direct
    estimate is used unless it fails or matches the reference patch clearly worse than the
    continuous one (a large expression), so errors do not accumulate.

    Losses are judged against each point's own measured noise, not fixed thresholds: a sample is
    rejected when its forward-backward error exceeds ``fb_threshold`` *and* ``fb_factor`` times the
    point's recent typical one, or its patch error exceeds ``appearance_factor`` times its recent
    typical one (an occluder) - or it leaves the frame.

    ``photometric``: the direct registration is also run on detail images (shading and lighting
    removed) and the two are combined per point by their measured noise (:meth:`_combined`; lighting
    drift, and footage nobody tuned for: docs/accuracy.md).
    """

    HISTORY = 30  # frames of per-point statistics

    def __init__(self, ref_image, ref_points, *, win_size=21, levels=3, fb_threshold=1.0, reregister=True,
                 reseed=True, patch_radius=6, fb_factor=5.0, appearance_factor=3.0, photometric=True,
                 fallback_min_eig=1e-5):
        self.cv2 = cv2 = opencv()
        self.win = (int(win_size), int(win_size))
        self.levels = int(levels)
        self.fb = float(fb_threshold)
        self.fb_factor, self.app_factor = float(fb_factor), float(appearance_factor)
        self.reregister, self.reseed = bool(reregister), bool(reseed)
        self.photometric = bool(photometric)
        self.criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 0.001)
        # LK's own status fails a window whose gradient energy is below a fixed level (OpenCV's 1e-4): on smooth 1/f
        # texture in MJPG most of them, though their estimates are as good as the rest. Where no estimate passed,
        # the point is tried again with this floor and the forward-backward and appearance checks judge it against
        # its own measured noise; where one passed, nothing changes (on lossless footage the weaker registrations
        # it lets through would be mixed into better ones). None: no second try
        self.fallback_min_eig = None if fallback_min_eig is None else float(fallback_min_eig)
        self.ref_pts = np.asarray(ref_points, np.float32).reshape(-1, 2)
        self.ref_pyr = self._pyramid(ref_image)
        self.ref_hp = self._highpass(ref_image)
        self.prev_pyr = self.ref_pyr
        self.pos = self.ref_pts.copy()
        self.ok = np.ones(len(self.ref_pts), bool)
        self.shape = ref_image.shape
        r = int(patch_radius)
        off = np.stack(np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1)), -1).reshape(-1, 2)
        self.offsets = off.astype(np.float32)
        self.ref_patch = self._patches(ref_image, self.ref_pts)
        n = len(self.ref_pts)
        self.fb_hist = np.full((self.HISTORY, n), np.nan)  # accepted forward-backward errors
        self.err_hist = np.full((self.HISTORY, n), np.nan)  # accepted patch errors (grey levels)
        self.fb_raw_hist = np.full((self.HISTORY, n), np.nan)  # the direct registration's, on the image
        self.fb_hp_hist = np.full((self.HISTORY, n), np.nan)  # and on its detail image
        self.frame_no = 0

    def _highpass(self, img):
        """Detail without the slowly varying shading: a lighting change barely alters it."""
        cv2 = self.cv2
        f = img.astype(np.float32)
        return np.clip(128.0 + 2.0 * (f - cv2.GaussianBlur(f, (0, 0), 4.0)), 0, 255).astype(np.uint8)

    def _pyramid(self, img):
        # OpenCV's Python binding does not accept prebuilt pyramids here, so LK builds its own.
        return img

    def _lk(self, pyr_a, pyr_b, pts, init=None, min_eig=1e-4):
        cv2 = self.cv2
        if init is None:
            out, st, _ = cv2.calcOpticalFlowPyrLK(pyr_a, pyr_b, pts, None, winSize=self.win, maxLevel=self.levels,
                                                  criteria=self.criteria, minEigThreshold=min_eig)
        else:
            out, st, _ = cv2.calcOpticalFlowPyrLK(pyr_a, pyr_b, pts, np.ascontiguousarray(init, np.float32).copy(),
                                                  winSize=self.win, maxLevel=self.levels, criteria=self.criteria,
                                                  flags=cv2.OPTFLOW_USE_INITIAL_FLOW, minEigThreshold=min_eig)
        return out.reshape(-1, 2), st.reshape(-1).astype(bool)

    def _patches(self, img, pts):
        grid = pts[:, None, :] + self.offsets[None]
        return self.cv2.remap(img, grid[..., 0], grid[..., 1], self.cv2.INTER_LINEAR,
                              borderMode=self.cv2.BORDER_REPLICATE).astype(np.float32)

    def _patch_error(self, img, pts, rows=slice(None)):
        """Mean absolute difference to the reference patch, both normalised to zero mean and unit
        contrast (lighting drift changes neither), in units of the patch contrast."""
        def z(p):
            p = p - p.mean(axis=1, keepdims=True)
            return p / np.maximum(p.std(axis=1, keepdims=True), 1.0)

        return np.abs(z(self._patches(img, pts)) - z(self.ref_patch[rows])).mean(axis=1)

    def _inside(self, pts):
        h, w = self.shape[:2]
        m = 2.0
        return (pts[:, 0] >= m) & (pts[:, 0] <= w - 1 - m) & (pts[:, 1] >= m) & (pts[:, 1] <= h - 1 - m)

    def _predict(self):
        """Positions for lost points from a similarity fitted on the held ones."""
        pred = self.pos.copy()
        if self.ok.sum() >= 3:
            M = fit_similarity_2d(self.ref_pts[self.ok].astype(float), self.pos[self.ok].astype(float))
            pred[~self.ok] = (self.ref_pts[~self.ok] @ M[:, :2].T + M[:, 2]).astype(np.float32)
        return pred

    def _typical(self, hist, fallback):
        """(M,) each point's recent median (the frame's median over points until it has a history)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            own = np.nanmedian(hist, axis=0)
            pooled = np.nanmedian(hist) if np.isfinite(hist).any() else fallback
        return np.where(np.isfinite(own) & (np.isfinite(hist).sum(axis=0) >= 5), own, pooled)

    def _checked(self, a, b, src, init, back_init, min_eig=1e-4):
        """LK a -> b from ``src`` (started at ``init``) and back; (positions, forward-backward error)."""
        fwd, st = self._lk(a, b, src, init, min_eig)
        back, st2 = self._lk(b, a, fwd, back_init, min_eig)
        fb = np.linalg.norm(back - src, axis=1)
        fb[~(st & st2 & self._inside(fwd))] = np.inf
        return fwd, fb

    def _combined(self, idx, p_raw, fb_raw, p_hp, fb_hp, record=True):
        """The direct registrations on the image and on its detail image as two measurements of the points
        ``idx``: weighted by the inverse square of each one's typical forward-backward error at that point (its
        noise, measured over the last frames), or the one that passed where the other failed. Detail images win
        where shading misleads LK (lighting drift), the image itself where the detail is mostly codec noise (a
        1/f texture in MJPG); neither is chosen frame by frame on its patch match (that lost to the plain LK on
        footage nobody tuned for). ``record``: the errors go into the points' history (not a second try's)."""
        if record:
            row = self.frame_no % self.HISTORY
            self.fb_raw_hist[row], self.fb_hp_hist[row] = np.nan, np.nan
            self.fb_raw_hist[row, idx] = np.where(np.isfinite(fb_raw), fb_raw, np.nan)
            self.fb_hp_hist[row, idx] = np.where(np.isfinite(fb_hp), fb_hp, np.nan)
        t_hp, t_raw = self._typical(self.fb_hp_hist, 1.0)[idx], self._typical(self.fb_raw_hist, 1.0)[idx]
        w = (t_raw**2 / np.maximum(t_hp**2 + t_raw**2, 1e-12))[:, None]
        ok_raw, ok_hp = np.isfinite(fb_raw), np.isfinite(fb_hp)
        both = (ok_raw & ok_hp)[:, None]
        p = np.where(both, w * p_hp + (1 - w) * p_raw, np.where(ok_hp[:, None], p_hp, p_raw))
        fb = np.where(both[:, 0], w[:, 0] * fb_hp + (1 - w[:, 0]) * fb_raw, np.where(ok_hp, fb_hp, fb_raw))
        return p.astype(np.float32), fb

    def _estimates(self, img, cur, which, was_ok, fb_limit, p_c, fb_c, p_d, fb_d, min_eig=None):
        """Fill the continuous (``p_c``, ``fb_c``) and direct (``p_d``, ``fb_d``) estimates of the points ``which``
        (n,) bools; returns (ok_c, ok_d) of every point. ``min_eig``: a second try at a lower floor for LK's status
        (not recorded in the points' history), else OpenCV's."""
        first = min_eig is None
        eig = 1e-4 if first else min_eig
        idx = np.flatnonzero(which & was_ok)
        if idx.size:
            p_c[idx], fb_c[idx] = self._checked(self.prev_pyr, cur, self.pos[idx], None, self.pos[idx], eig)
        ok_c = fb_c < fb_limit
        want = which & (True if self.reregister else (~ok_c & self.reseed))
        if want.any():
            init = np.where(ok_c[:, None], p_c, self._predict() if (~ok_c).any() else p_c)
            idx = np.flatnonzero(want & np.isfinite(init[:, 0]))
            p_d[idx], fb_d[idx] = self._checked(self.ref_pyr, cur, self.ref_pts[idx], init[idx], self.ref_pts[idx], eig)
            if self.photometric:  # the same registration on detail images, combined with it per point
                p_h, fb_h = self._checked(self.ref_hp, self._highpass(img), self.ref_pts[idx], init[idx],
                                          self.ref_pts[idx], eig)
                p_d[idx], fb_d[idx] = self._combined(idx, p_d[idx], fb_d[idx], p_h, fb_h, record=first)
        ok_d = fb_d < np.where(ok_c | self.reregister, fb_limit, 0.5 * fb_limit)  # re-acquiring: a closer match
        return ok_c, ok_d

    def step(self, img):
        """Track into ``img``; returns positions (M, 2) (NaN = lost), confidence (M,), re-acquired mask."""
        n = len(self.ref_pts)
        cur = self._pyramid(img)
        was_ok = self.ok.copy()
        fb_typ = self._typical(self.fb_hist, 0.05)
        fb_limit = np.maximum(self.fb, self.fb_factor * fb_typ)
        p_c = np.full((n, 2), np.nan, np.float32)
        fb_c = np.full(n, np.inf)
        p_d = np.full((n, 2), np.nan, np.float32)
        fb_d = np.full(n, np.inf)
        ok_c, ok_d = self._estimates(img, cur, np.ones(n, bool), was_ok, fb_limit, p_c, fb_c, p_d, fb_d)
        lost = ~(ok_c | ok_d)
        if self.fallback_min_eig is not None and lost.any():
            ok_c, ok_d = self._estimates(img, cur, lost, was_ok, fb_limit, p_c, fb_c, p_d, fb_d,
                                         min_eig=self.fallback_min_eig)
        err_typ = self._typical(self.err_hist, np.inf)
        e_c = np.where(ok_c, self._patch_error(img, np.nan_to_num(p_c)), np.inf)
        e_d = np.where(ok_d, self._patch_error(img, np.nan_to_num(p_d)), np.inf)
        use_c = ok_c & (~ok_d | (e_d > 1.5 * e_c + 0.05))  # the reference matches clearly worse: big expression
        pos = np.where(use_c[:, None], p_c, p_d)
        fb = np.where(use_c, fb_c, fb_d)
        err = np.where(use_c, e_c, e_d)
        ok = (ok_c | ok_d) & (err <= np.maximum(self.app_factor * err_typ, 0.5))  # occluded: unlike itself
        conf = np.where(ok, np.clip(1.0 - fb / (2.0 * fb_limit), 0.0, 1.0), 0.0)
        pos[~ok] = np.nan
        row = self.frame_no % self.HISTORY
        self.fb_hist[row] = np.where(ok, fb, np.nan)
        self.err_hist[row] = np.where(ok, err, np.nan)
        self.frame_no += 1
        self.pos = np.where(ok[:, None], pos, self.pos).astype(np.float32)
        self.ok = ok
        self.prev_pyr = cur
        return pos.astype(np.float64), conf, ok & ~was_ok


def _to_work(xy, scale):
    return (np.asarray(xy, float) + 0.5) * scale - 0.5


def to_source_pixels(xy, scale):
    return (np.asarray(xy, float) + 0.5) / scale - 0.5


def seed_points(info, ref_img, *, points, names, region, max_points):
    """Seed names and working-pixel positions from ``points`` (array or file) or a ``region``."""
    if (points is None) == (region is None):
        raise FacecapError("give exactly one of `points` (positions or a name,x,y file) and `region`")
    if region is not None:
        x, y, w, h = check_region(region, (info.height, info.width))
        box = _to_work([x, y], info.scale).tolist() + [w * info.scale, h * info.scale]
        box = [max(0, box[0]), max(0, box[1]), min(box[2], ref_img.shape[1] - max(0, box[0])),
               min(box[3], ref_img.shape[0] - max(0, box[1]))]
        names, work_pts = auto_seeds(ref_img, box, max_points=max_points)
    else:
        if isinstance(points, (str, bytes)) or hasattr(points, "__fspath__"):
            names, src_pts = read_seed_points(points)
        else:
            src_pts = np.asarray(points, float)
            if src_pts.ndim != 2 or src_pts.shape[1] != 2 or not np.isfinite(src_pts).all():
                raise FacecapError(f"`points` must be finite with shape (M, 2); got {src_pts.shape}")
            names = tuple(names) if names is not None else tuple(f"p{i:03d}" for i in range(len(src_pts)))
            if len(names) != len(src_pts):
                raise FacecapError(f"{len(names)} names for {len(src_pts)} points")
        outside = [n for n, (px, py) in zip(names, src_pts)
                   if not (0 <= px <= info.width - 1 and 0 <= py <= info.height - 1)]
        if outside:
            raise FacecapError(f"seed points outside the {info.width}x{info.height} frame: {outside}")
        work_pts = _to_work(src_pts, info.scale)
    return tuple(names), np.asarray(work_pts, float)


def track_points(footage, *, points=None, names=None, region=None, reference=None, max_points=100,
                 win_size=21, levels=3, fb_threshold=1.0, reregister=True, reseed=True, progress=None):
    """Track named 2D points through footage with pyramidal Lucas-Kanade.

    Parameters
    ----------
    footage : Footage or str
        What to track (a path is opened with default options).
    points : array (M, 2) or str, optional
        Seed positions in source pixels at the ``reference`` frame, or a ``name,x,y`` file.
    names : sequence of str, optional
        Names for array ``points`` (default ``p000``...).
    region : [x, y, w, h], optional
        Instead of ``points``: detect up to ``max_points`` corner features in this box (source pixels).
    reference : int, optional
        Neutral reference frame number (default: the first frame read). Tracking runs forward and
        backward from it.
    win_size, levels : int
        LK window (pixels, working resolution) and pyramid levels.
    fb_threshold : float
        Forward-backward error (working pixels) above which an estimate is rejected.
    reregister : bool
        Drift control: fuse each frame's continuous estimate with a direct registration to the
        reference. Without it errors accumulate frame to frame.
    reseed : bool
        Re-acquire lost points by direct registration from the reference patch.
    progress : callable(done, total) -> bool or None, optional
        Called once per frame; returning False cancels (:class:`~.reading.Cancelled`).

    Returns
    -------
    TrackResult
    """
    return track_points_job(footage, points=points, names=names, region=region, reference=reference,
                            max_points=max_points, win_size=win_size, levels=levels, fb_threshold=fb_threshold,
                            reregister=reregister, reseed=reseed).run(progress)


def track_points_job(footage, *, points=None, names=None, region=None, reference=None, max_points=100,
                     win_size=21, levels=3, fb_threshold=1.0, reregister=True, reseed=True):
    """:func:`track_points` as a :class:`~.reading.Job` that advances a frame per step (seeds checked here)."""
    if not isinstance(footage, Footage):
        footage = Footage(footage)
    info = footage.info
    ref_frame = info.frames[0] if reference is None else int(reference)
    ref_img = footage.frame(ref_frame)
    names, work_pts = seed_points(info, ref_img, points=points, names=names, region=region, max_points=max_points)
    options = dict(win_size=win_size, levels=levels, fb_threshold=fb_threshold, reregister=reregister, reseed=reseed)
    return Job(_track_steps(footage, ref_frame, ref_img, names, work_pts, options), info.n_frames, info=info)


def _track_steps(footage, ref_frame, ref_img, names, work_pts, options):
    """Generator: forward from the reference, then backward over the frames before it (cached on the way)."""
    info = footage.info
    frames = np.asarray(info.frames, dtype=np.float64)
    F, M = len(frames), len(names)
    pos = np.full((F, M, 2), np.nan)
    conf = np.zeros((F, M))
    lost = {n: [] for n in names}
    found = {n: [] for n in names}
    row = {f: i for i, f in enumerate(info.frames)}

    def track(f, img, tracker, held):
        if f == ref_frame:
            p, c, back = work_pts.astype(float), np.ones(M), np.zeros(M, bool)
            tracker.pos, tracker.ok, tracker.prev_pyr = work_pts.astype(np.float32), np.ones(M, bool), tracker.ref_pyr
        else:
            p, c, back = tracker.step(img)
        i = row[f]
        pos[i], conf[i] = p, c
        ok = np.isfinite(p[:, 0])
        for j in np.flatnonzero(held & ~ok):
            lost[names[j]].append(int(f))
        for j in np.flatnonzero(back):
            found[names[j]].append(int(f))
        return ok

    before = []
    tracker, held = LKTracker(ref_img, work_pts, **options), np.ones(M, bool)
    reader = iter(footage)
    try:
        for f, img in reader:
            if f < ref_frame:  # read once, tracked in reverse after the forward pass
                before.append((f, img))
                yield None
                continue
            held = track(f, img, tracker, held)
            yield f
    finally:
        reader.close()
    tracker, held = LKTracker(ref_img, work_pts, **options), np.ones(M, bool)
    while before:
        f, img = before.pop()
        held = track(f, img, tracker, held)
        yield f
    out = to_source_pixels(pos, info.scale)
    markers = MarkerSet(names, frames, out, fps=info.fps, units="px", source=info.path)
    return TrackResult(markers, conf, ref_frame, "lk", {k: v for k, v in lost.items() if v},
                       {k: v for k, v in found.items() if v})
