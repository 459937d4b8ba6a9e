"""Dense optical flow relative to a neutral reference, flow algebra, and flow sampled at markers.

Convention (the thesis'): a field ``f_ab`` lives on the grid of image ``a`` and points into ``b``:
``a(x) ~ b(x + f_ab(x))``. OpenCV's ``calc(prev=a, next=b)`` returns exactly this.

* composition: ``f_ac(x) = f_ab(x) + f_bc(x + f_ab(x))`` - :func:`compose` (not ``f_ab + f_bc``);
* reversal: ``f_ba`` by forward-splatting ``-f_ab`` to ``x + f_ab(x)`` and filling holes -
  :func:`reverse` (not ``-f_ab``).

The flow of frame t relative to the reference r is ``F_t = f_rt`` (on the reference grid), so a
reference point p is at ``p + F_t(p)`` in frame t. Drift control (Alg. 4.3): a continuous estimate
``compose(F_{t-1}, f_{t-1,t})`` and a direct one (``calc(r, I_t)`` started from it) are fused per
pixel with ``w_cont = E_dir / (E_cont + E_dir)``, E the blurred reconstruction errors.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError
from ..markers import MarkerSet
from .reading import Footage, Job, opencv
from .tracking import TrackResult, check_region, seed_points, to_source_pixels

METHODS = ("dis", "farneback", "tvl1")


_GRIDS = {}


def _grid(h, w):
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return gx, gy


def _grid2(h, w):
    """The pixel grid as one (h, w, 2) float32 map, cached (remap takes it as a single CV_32FC2 map)."""
    grid = _GRIDS.get((h, w))
    if grid is None:
        grid = np.ascontiguousarray(np.stack(_grid(h, w), axis=-1))
        grid.flags.writeable = False
        if len(_GRIDS) > 8:
            _GRIDS.clear()
        _GRIDS[(h, w)] = grid
    return grid


def warp(image, flow, *, interpolation=None, border=None):
    """Backward warp: ``out(x) = image(x + flow(x))`` (bilinear). ``image`` may be a flow field."""
    cv2 = opencv()
    h, w = flow.shape[:2]
    where = _grid2(h, w) + np.asarray(flow, np.float32)
    return cv2.remap(np.asarray(image, np.float32), where, None,
                     cv2.INTER_LINEAR if interpolation is None else interpolation,
                     borderMode=cv2.BORDER_REPLICATE if border is None else border)


def compose(f_ab, f_bc):
    """``f_ac = f_ab + warp(f_bc, f_ab)``: follow ``f_ab`` into b, then ``f_bc`` into c."""
    f_ab = np.asarray(f_ab, np.float32)
    return f_ab + warp(f_bc, f_ab)


def reverse(f_ab, *, max_fill_passes=12):
    """The reverse field ``f_ba`` (on b's grid) by bilinear forward splatting plus hole filling.

    Every a-pixel x sends ``-f_ab(x)`` to ``x + f_ab(x)`` in b with bilinear weights; b-pixels that
    receive nothing (disocclusions, borders) are filled by normalised convolution at growing scales.
    """
    cv2 = opencv()
    f_ab = np.asarray(f_ab, np.float32)
    h, w = f_ab.shape[:2]
    gx, gy = _grid(h, w)
    dx, dy = gx + f_ab[..., 0], gy + f_ab[..., 1]
    x0, y0 = np.floor(dx), np.floor(dy)
    ax, ay = dx - x0, dy - y0
    num = np.zeros((2, h * w))
    den = np.zeros(h * w)
    vals = -f_ab.reshape(-1, 2)
    for ox, oy, wt in ((0, 0, (1 - ax) * (1 - ay)), (1, 0, ax * (1 - ay)), (0, 1, (1 - ax) * ay), (1, 1, ax * ay)):
        xi, yi = (x0 + ox).astype(np.int64).ravel(), (y0 + oy).astype(np.int64).ravel()
        ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
        idx = yi[ok] * w + xi[ok]
        wk = wt.ravel()[ok]
        den += np.bincount(idx, weights=wk, minlength=h * w)
        num[0] += np.bincount(idx, weights=wk * vals[ok, 0], minlength=h * w)
        num[1] += np.bincount(idx, weights=wk * vals[ok, 1], minlength=h * w)
    den = den.reshape(h, w)
    filled = den > 1e-3
    out = np.zeros((h, w, 2), np.float32)
    out[filled] = (num[:, filled.ravel()] / den[filled]).T
    sigma = 1.0
    for _ in range(max_fill_passes):
        if filled.all():
            break
        m = filled.astype(np.float32)
        d = cv2.GaussianBlur(m, (0, 0), sigma)
        n = cv2.GaussianBlur(out * m[..., None], (0, 0), sigma)
        ok = ~filled & (d > 1e-4)
        out[ok] = n[ok] / d[ok][:, None]
        filled |= ok
        sigma *= 2.0
    if not filled.all():
        out[~filled] = out[filled].mean(axis=0) if filled.any() else 0.0
    return out


def sample_flow(flow, points):
    """Bilinear flow values at ``points`` (M, 2) (x, y pixels): (M, 2)."""
    cv2 = opencv()
    pts = np.asarray(points, np.float32).reshape(1, -1, 2)
    vals = cv2.remap(np.asarray(flow, np.float32), pts[..., 0], pts[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
    return vals.reshape(-1, 2).astype(np.float64)


def endpoint_error(flow, truth, mask=None):
    """Per-pixel end-point error |flow - truth| (optionally only where ``mask``)."""
    err = np.linalg.norm(np.asarray(flow, float) - truth, axis=-1)
    return err if mask is None else err[mask]


class FlowEstimator:
    """One OpenCV optical-flow backend: ``calc(a, b, init=None)`` returns ``f_ab`` (H, W, 2) float32.

    ``method``: "dis" (default), "farneback" or "tvl1". DIS ``preset``: "ultrafast", "fast",
    "balanced" (default: OpenCV's fast preset refined down to half resolution; at 640x480 about
    0.06 px end-point error at ~1.4x the speed of "medium") or "medium" (most accurate).
    ``finest_scale`` overrides the preset's finest pyramid level (0 = full resolution).
    """

    def __init__(self, method="dis", *, preset="balanced", finest_scale=None):
        cv2 = self.cv2 = opencv()
        method = str(method).lower()
        if method not in METHODS:
            raise FacecapError(f"`method` must be one of {', '.join(METHODS)}; got {method!r}")
        self.method = method
        if method == "dis":
            presets = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
                       "balanced": cv2.DISOPTICAL_FLOW_PRESET_FAST, "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
            if preset not in presets:
                raise FacecapError(f"`preset` must be one of {', '.join(presets)}; got {preset!r}")
            self._dis = cv2.DISOpticalFlow_create(presets[preset])
            if preset == "balanced":
                self._dis.setFinestScale(1)
            if finest_scale is not None:
                self._dis.setFinestScale(int(finest_scale))
        elif method == "tvl1":
            if not hasattr(cv2, "optflow"):
                raise FacecapError("TV-L1 flow needs opencv-contrib (cv2.optflow)")
            self._tvl1 = cv2.optflow.DualTVL1OpticalFlow_create()

    def calc(self, a, b, init=None):
        cv2 = self.cv2
        if self.method == "dis":
            flow = None if init is None else np.ascontiguousarray(init, np.float32).copy()
            return self._dis.calc(a, b, flow)
        if self.method == "farneback":
            flags = 0 if init is None else cv2.OPTFLOW_USE_INITIAL_FLOW
            flow = None if init is None else np.ascontiguousarray(init, np.float32).copy()
            return cv2.calcOpticalFlowFarneback(a, b, flow, 0.5, 4, 15, 5, 5, 1.1, flags)
        self._tvl1.setUseInitialFlow(init is not None)
        flow = None if init is None else np.ascontiguousarray(init, np.float32).copy()
        return self._tvl1.calc(a, b, flow)


class ReferenceFlow:
    """Flow of successive frames relative to a reference image, with drift control.

    ``drift``: "fuse" (continuous + direct, Alg. 4.3; default), "direct" (straight to the
    reference, started from the continuous estimate) or "none" (pure concatenation of
    frame-to-frame flows; drifts). ``error_sigma`` blurs the reconstruction errors used as weights.

    Every frame costs two flows plus the fusion: at 640x480 (``solvers.tools.bench.video_bench``, medians on 2
    shared cores) DIS "balanced" runs ~23 frames/s at 0.06 px end-point error after 40 frames,
    ``preset="fast"`` ~46 frames/s at 0.13 px (the direct registration bounds its error too).
    """

    def __init__(self, ref_image, *, method="dis", drift="fuse", error_sigma=3.0, preset="balanced", **options):
        if drift not in ("fuse", "direct", "none"):
            raise FacecapError(f"`drift` must be 'fuse', 'direct' or 'none'; got {drift!r}")
        self.cv2 = opencv()
        self.est = FlowEstimator(method, preset=preset, **options)
        self.ref = np.asarray(ref_image)
        self.ref_f = self.ref.astype(np.float32)
        self.drift = drift
        self.sigma = float(error_sigma)
        self.prev = self.ref
        self.field = np.zeros(self.ref.shape[:2] + (2,), np.float32)
        self.error = np.zeros(self.ref.shape[:2], np.float32)

    def _error(self, img_f, flow):
        e = self.cv2.absdiff(self.ref_f, warp(img_f, flow))
        return self.cv2.GaussianBlur(e, (0, 0), self.sigma)

    def reset(self):
        self.prev = self.ref
        self.field[:] = 0
        self.error[:] = 0

    def step(self, img):
        """Advance to ``img``; returns ``F_t`` (H, W, 2) on the reference grid."""
        img_f = np.asarray(img, np.float32)
        step = self.est.calc(self.prev, img)
        cont = compose(self.field, step)
        if self.drift == "none":
            fused = cont
            err = self._error(img_f, fused)
        else:
            direct = self.est.calc(self.ref, img, init=cont)
            e_dir = self._error(img_f, direct)
            if self.drift == "direct":
                fused, err = direct, e_dir
            else:
                e_cont = self._error(img_f, cont)
                total = e_cont + e_dir
                np.maximum(total, 1e-6, out=total)
                # The direct registration unless it reconstructs clearly worse (a large expression the
                # reference matches badly): the continuous estimate carries the drift of every step.
                w_c = (e_dir - e_cont) / total
                np.clip(w_c, 0.0, 1.0, out=w_c)
                cont -= direct  # in place: fused = direct + w_c (cont - direct)
                cont *= w_c[..., None]
                cont += direct
                fused = cont
                err = np.minimum(e_cont, e_dir)
        self.field, self.error, self.prev = np.asarray(fused, np.float32), err, img
        return self.field


@dataclass(frozen=True, eq=False)
class DenseFlowResult:
    """Flows relative to the reference frame, cropped to ``region`` and subsampled by ``grid_step``.

    ``flows`` (F, h, w, 2) are in working pixels (``scale`` of the footage); ``points`` (h, w, 2)
    are the reference-grid pixel positions (working pixels) of each flow sample.
    """

    frames: np.ndarray
    flows: np.ndarray
    points: np.ndarray
    reference: int
    method: str
    scale: float
    fps: float


def _reference_steps(footage, ref_frame, ref_img, flow_options, visit):
    """Generator: a ReferenceFlow forward then backward from the reference, calling visit(frame, F, err)."""
    before = []
    rf = ReferenceFlow(ref_img, **flow_options)
    reader = iter(footage)
    try:
        for f, img in reader:
            if f < ref_frame:  # read once, run in reverse after the forward pass
                before.append((f, img))
                yield None
                continue
            if f == ref_frame:
                rf.reset()
            visit(f, rf.field if f == ref_frame else rf.step(img), rf.error)
            yield f
    finally:
        reader.close()
    rf = ReferenceFlow(ref_img, **flow_options)
    while before:
        f, img = before.pop()
        visit(f, rf.step(img), rf.error)
        yield f


def _check_flow_options(method, options):
    """Bad method / preset / option names fail when the job is made, not at its first step."""
    options = {k: v for k, v in options.items() if k != "error_sigma"}
    FlowEstimator(method, **options)


def _open(footage, reference):
    if not isinstance(footage, Footage):
        footage = Footage(footage)
    ref_frame = footage.info.frames[0] if reference is None else int(reference)
    return footage, ref_frame, footage.frame(ref_frame)


def dense_flow(footage, *, method="dis", reference=None, region=None, grid_step=1, drift="fuse", progress=None,
               **options):
    """Dense flow of every frame relative to the neutral ``reference`` frame.

    ``region`` [x, y, w, h] (source pixels) crops what is kept; ``grid_step`` subsamples it (the flow is
    always computed on the whole frame). See :class:`ReferenceFlow` for ``drift``. ``progress(done,
    total)`` returning False cancels (:class:`~.reading.Cancelled`).
    """
    return dense_flow_job(footage, method=method, reference=reference, region=region, grid_step=grid_step,
                          drift=drift, **options).run(progress)


def dense_flow_job(footage, *, method="dis", reference=None, region=None, grid_step=1, drift="fuse", **options):
    """:func:`dense_flow` as a :class:`~.reading.Job` (a frame per step)."""
    footage, ref_frame, ref_img = _open(footage, reference)
    info = footage.info
    H, W = ref_img.shape
    if region is None:
        x0, y0, x1, y1 = 0, 0, W, H
    else:
        x, y, w, h = check_region(region, (info.height, info.width))
        s = info.scale
        x0, y0 = int(np.floor(x * s)), int(np.floor(y * s))
        x1, y1 = min(W, int(np.ceil((x + w) * s))), min(H, int(np.ceil((y + h) * s)))
    step = int(grid_step)
    if step < 1:
        raise FacecapError(f"`grid_step` must be a positive integer; got {grid_step}")
    ys, xs = np.arange(y0, y1, step), np.arange(x0, x1, step)
    row = {f: i for i, f in enumerate(info.frames)}
    flows = np.zeros((info.n_frames, len(ys), len(xs), 2), np.float32)
    _check_flow_options(method, options)

    def visit(f, F, err):
        flows[row[f]] = F[y0:y1:step, x0:x1:step]

    def steps():
        yield from _reference_steps(footage, ref_frame, ref_img, dict(method=method, drift=drift, **options), visit)
        pts = np.stack(np.meshgrid(xs, ys), axis=-1).astype(np.float32)
        return DenseFlowResult(np.asarray(info.frames, float), flows, pts, ref_frame, method, info.scale, info.fps)

    return Job(steps(), info.n_frames, info=info)


def track_with_flow(footage, *, points=None, names=None, region=None, reference=None, method="dis",
                    max_points=100, drift="fuse", error_scale=25.0, progress=None, **options):
    """Markers from dense flow: reference points moved by ``F_t`` sampled at them (see ``track_points``).

    Confidence per sample is ``max(0, 1 - E / error_scale)``, E the blurred reconstruction error
    (grey levels) of the fused flow at the point. Returns a :class:`~.tracking.TrackResult`.
    """
    return track_with_flow_job(footage, points=points, names=names, region=region, reference=reference,
                               method=method, max_points=max_points, drift=drift, error_scale=error_scale,
                               **options).run(progress)


def track_with_flow_job(footage, *, points=None, names=None, region=None, reference=None, method="dis",
                        max_points=100, drift="fuse", error_scale=25.0, **options):
    """:func:`track_with_flow` as a :class:`~.reading.Job` (a frame per step)."""

    footage, ref_frame, ref_img = _open(footage, reference)
    info = footage.info
    names, work_pts = seed_points(info, ref_img, points=points, names=names, region=region, max_points=max_points)
    _check_flow_options(method, options)
    row = {f: i for i, f in enumerate(info.frames)}
    F_, M = info.n_frames, len(names)
    pos = np.full((F_, M, 2), np.nan)
    conf = np.zeros((F_, M))
    H, W = ref_img.shape
    pts32 = np.asarray(work_pts, np.float32)
    cv2 = opencv()

    def visit(f, F, err):
        p = work_pts + sample_flow(F, pts32)
        e = cv2.remap(err, pts32[None, :, 0], pts32[None, :, 1], cv2.INTER_LINEAR).ravel()
        inside = (p[:, 0] >= 0) & (p[:, 0] <= W - 1) & (p[:, 1] >= 0) & (p[:, 1] <= H - 1)
        p[~inside] = np.nan
        pos[row[f]] = p
        conf[row[f]] = np.where(inside, np.clip(1 - e / error_scale, 0, 1), 0)

    def steps():
        yield from _reference_steps(footage, ref_frame, ref_img, dict(method=method, drift=drift, **options), visit)
        markers = MarkerSet(names, np.asarray(info.frames, float), to_source_pixels(pos, info.scale), fps=info.fps,
                            units="px", source=info.path)
        return TrackResult(markers, conf, ref_frame, method)

    return Job(steps(), F_, info=info)
