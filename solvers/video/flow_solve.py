"""Retarget footage without markers: flow-PCA features + frames an animator posed -> every frame's weights.

``retarget_flow`` runs dense flow over the face region relative to the neutral reference frame
(drift-controlled, :mod:`.flow`), removes the head's per-frame similarity fitted at the stable
samples (``stable_region`` boxes; they may lie outside the face region), reduces the face's flow
to a few PCA coefficients per frame (centred on the neutral) and maps them to character weights
with the ``linear``, ``rbf`` or ``pca`` strategy learned from the posed example frames. The
result is a :class:`~facecap.solvers.pipeline.RetargetResult` like any other retarget's, keyed
and written by the same code. There is no marker fit, so ``residual_rms`` is NaN on every frame
(``residual_space`` None); ``info["flow"]`` has the flow / PCA figures instead.

The long part (the flow) is a :class:`~.reading.Job`: a frame per step, cancellable between two
frames with nothing produced (``retarget_flow_job``; the CLI's Ctrl-C and Blender's Esc).
"""

import time
from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError
from ..options import default
from ..pipeline import RetargetSettings, hold_locks
from ..pipeline.result import assemble
from ..strategies.wiring import example_weights, shape_target
from .features import EXAMPLE_STRATEGIES, FlowFeatures, fit_from_flow, remove_similarity
from .flow import dense_flow_job
from .pca import flow_pca
from .reading import Footage, Job

TARGET_SAMPLES = 4000  # automatic grid step: about this many flow samples over the face region


@dataclass(frozen=True)
class FlowSolveSettings:
    """How footage becomes features (the take config's ``[tracking]`` and ``[flow]``).

    method : "dis" (default), "farneback" or "tvl1"
    reference : neutral reference frame number (None: the first frame read)
    region : (x, y, w, h) face region, source pixels (None: the whole frame)
    stable_region : ((x, y, w, h), ...) boxes that move with the head only (forehead, temples, a
        head-cam rig); the head similarity fitted there is removed. () = keep head motion in.
    grid_step : flow sample spacing in working pixels (None: about 4,000 samples over the crop)
    drift, preset : as :class:`~.flow.ReferenceFlow`
    n_components, variance : PCA components kept (``variance``, when given, wins: the fewest
        components explaining that fraction)
    """

    method: str = default("tracking.method")
    reference: int = None
    region: tuple = None
    stable_region: tuple = ()
    grid_step: int = None
    drift: str = default("tracking.drift")
    preset: str = default("tracking.preset")
    n_components: int = default("flow.components")
    variance: float = None


def _box(value, what, size):
    """(x, y, w, h) floats inside a ``size`` = (W, H) frame, else a FacecapError naming ``what``."""
    try:
        x, y, w, h = (float(v) for v in value)
    except (TypeError, ValueError):
        raise FacecapError(f"`{what}` must be [x, y, w, h] in pixels; got {value!r}") from None
    W, H = size
    if not (w > 0 and h > 0 and x >= 0 and y >= 0 and x + w <= W and y + h <= H):
        raise FacecapError(f"`{what}` {list(value)} must be a non-empty box inside the {W}x{H} frame")
    return x, y, w, h


def check_flow_settings(flow, info):
    """Validate ``flow`` (FlowSolveSettings) against footage ``info``; returns (region, stable boxes)."""
    size = (info.width, info.height)
    region = (0.0, 0.0, float(info.width), float(info.height)) if flow.region is None else \
        _box(flow.region, "region", size)
    stable = tuple(_box(b, "stable_region", size) for b in flow.stable_region)
    if flow.reference is not None and int(flow.reference) not in info.frames:
        raise FacecapError(f"`reference` frame {flow.reference} is not in the footage "
                           f"({info.frames[0]}-{info.frames[-1]})")
    if flow.variance is None and int(flow.n_components) < 1:
        raise FacecapError(f"`n_components` must be >= 1; got {flow.n_components}")
    if flow.variance is not None and not 0 < float(flow.variance) <= 1:
        raise FacecapError(f"`variance` must be in (0, 1]; got {flow.variance}")
    if flow.grid_step is not None and int(flow.grid_step) < 1:
        raise FacecapError(f"`grid_step` must be a positive integer; got {flow.grid_step}")
    return region, stable


def example_matrix(examples, target, frames, *, only=()):
    """(example frames (N,), weights (N, K) in ``target``'s shape order, notes) from ExamplePairs;
    ``only`` (``[examples] frames``) keeps just those posed frames."""

    ex_frames = np.asarray(examples.frames, dtype=np.float64).reshape(-1)
    values = np.asarray(examples.weights, dtype=np.float64)
    if ex_frames.size == 0 or values.shape != (ex_frames.size, len(examples.names)):
        raise FacecapError(f"examples: weights must have shape (N, {len(examples.names)}) for N > 0 posed frames; "
                           f"got {values.shape}")
    if len(only):
        want = np.asarray(only, dtype=np.float64)
        missing = [f for f in want.tolist() if not np.any(np.abs(ex_frames - f) < 1e-6)]
        if missing:
            raise FacecapError(f"examples: frame(s) {missing[:8]} have no posed weights")
        rows = [int(np.flatnonzero(np.abs(ex_frames - f) < 1e-6)[0]) for f in want]
        ex_frames, values = ex_frames[rows], values[rows]
    notes = []
    W = example_weights(examples.names, values, target, notes)
    have = np.asarray(frames, dtype=np.float64)
    absent = [f for f in ex_frames.tolist() if not np.any(np.abs(have - f) < 1e-6)]
    if absent:
        raise FacecapError(f"examples: posed frame(s) {absent[:8]} are not in the footage ({have[0]:g}-{have[-1]:g})")
    if ex_frames.size < 2:
        raise FacecapError(f"examples: need at least 2 posed frames; got {ex_frames.size}")
    return ex_frames, W, notes


def _strategy_options(settings):
    """Keyword options of the strategy class from RetargetSettings (as ``strategies.wiring``)."""
    e, name = settings.examples, settings.strategy
    if name == "linear":
        return {"ridge": e.ridge}
    if name == "rbf":
        extra = {} if e.n_components is None else {"n_components": e.n_components}
        return {"kernel": e.kernel, "smoothing": e.rbf_smoothing, "degree": e.degree, "far": e.far, **extra}
    p = settings.pca
    return {"mode": p.mode, "ica": p.ica, "n_basis": p.n_basis, "variance": p.variance, "n_components": e.n_components,
            "smoothing": tuple(settings.smoothing)}


def _crop(region, stable, scale):
    """Flow crop (source pixels) covering the face region and the stable boxes, and the grid step."""
    boxes = [region, *stable]
    x0, y0 = min(b[0] for b in boxes), min(b[1] for b in boxes)
    x1, y1 = max(b[0] + b[2] for b in boxes), max(b[1] + b[3] for b in boxes)
    return (x0, y0, x1 - x0, y1 - y0), (region[2] * scale) * (region[3] * scale)


def _inside(points, boxes, scale):
    """(h, w) bool: flow samples (working pixels) inside any of ``boxes`` (source pixels)."""
    p = np.asarray(points, dtype=np.float64) / scale
    mask = np.zeros(p.shape[:2], dtype=bool)
    for x, y, w, h in boxes:
        mask |= (p[..., 0] >= x) & (p[..., 0] <= x + w) & (p[..., 1] >= y) & (p[..., 1] <= y + h)
    return mask


def retarget_flow(footage, character, examples, *, settings=None, flow=None, progress=None):
    """Character weights for every footage frame from dense flow and posed example frames.

    Parameters
    ----------
    footage : Footage or a path (video file, image folder, glob or printf pattern)
    character : Target, Basis or shape names (output shapes and their bounds)
    examples : ExamplePairs (frames of the footage, weights (N, S), shape names S)
    settings : RetargetSettings, optional
        ``strategy`` ("linear" default, "rbf", "pca"), ``examples`` / ``pca`` options, ``bounds``,
        ``locks``, ``smoothing`` (pca).
    flow : FlowSolveSettings, optional
    progress : callable(done, total) -> bool, optional; False cancels (:class:`~.reading.Cancelled`)

    Returns
    -------
    RetargetResult (``residual_rms`` NaN: no markers are fitted; ``info["flow"]`` has the figures)
    """
    return retarget_flow_job(footage, character, examples, settings=settings, flow=flow).run(progress)


def retarget_flow_job(footage, character, examples, *, settings=None, flow=None):
    """:func:`retarget_flow` as a :class:`~.reading.Job` (a footage frame per step; the features and
    the solve run after the last frame). Everything is validated before the first step."""

    t0 = time.perf_counter()
    settings = RetargetSettings((), (1, 1), strategy="linear") if settings is None else settings
    flow = FlowSolveSettings() if flow is None else flow
    if settings.strategy not in EXAMPLE_STRATEGIES:
        raise FacecapError(f"flow features drive {', '.join(EXAMPLE_STRATEGIES)}; got strategy {settings.strategy!r}")
    target = shape_target(character, settings)
    footage = footage if isinstance(footage, Footage) else Footage(footage)
    info = footage.info
    region, stable = check_flow_settings(flow, info)
    ex_frames, W, notes = example_matrix(examples, target, info.frames, only=settings.examples.frames)
    options = _strategy_options(settings)
    crop, area = _crop(region, stable, info.scale)
    step = int(flow.grid_step) if flow.grid_step is not None else max(1, int(np.ceil(np.sqrt(area / TARGET_SAMPLES))))
    inner = dense_flow_job(footage, method=flow.method, reference=flow.reference, region=crop, grid_step=step,
                           drift=flow.drift, preset=flow.preset)

    def steps():
        t_flow = time.perf_counter()
        dense = yield from inner._steps  # the flow job's own generator: its frames are this job's steps
        t_feat = time.perf_counter()
        flows = dense.flows
        stable_mask = _inside(dense.points, stable, info.scale) if stable else None
        if stable_mask is not None:
            flows = remove_similarity(flows, dense.points, stable_mask)
        face = _inside(dense.points, [region], info.scale)
        rows, cols = np.flatnonzero(face.any(axis=1)), np.flatnonzero(face.any(axis=0))
        face_flows = flows[:, rows[0]: rows[-1] + 1, cols[0]: cols[-1] + 1]
        pca = flow_pca(face_flows, n_components=flow.n_components, variance=flow.variance, center="reference",
                       frames=dense.frames)
        features = FlowFeatures(np.asarray(dense.frames, dtype=np.float64), pca.coefficients, pca,
                                stable_mask is not None)
        recon = face_flows.reshape(len(face_flows), -1) - pca.coefficients @ pca.components
        recon_px = np.sqrt(np.mean(recon.reshape(len(recon), -1, 2) ** 2, axis=1).sum(axis=1))
        t_solve = time.perf_counter()
        fitted = fit_from_flow(features, target, strategy=settings.strategy, example_frames=ex_frames,
                               example_weights=W, **options)
        res = fitted.solve(features.coefficients)
        weights = hold_locks(target.names, res.weights, settings, notes)
        t_end = time.perf_counter()
        F = len(features.frames)
        figures = {
            "method": flow.method, "preset": flow.preset, "drift": flow.drift, "reference": dense.reference,
            "region_px": [round(v, 3) for v in region], "stable_region_px": [[round(v, 3) for v in b] for b in stable],
            "stabilised": stable_mask is not None, "grid_step": step,
            "samples": int(face.sum()), "stable_samples": 0 if stable_mask is None else int(stable_mask.sum()),
            "components": int(pca.n_components),
            "explained_variance_ratio": [round(float(v), 6) for v in pca.explained_variance_ratio],
            "explained_variance": round(float(np.sum(pca.explained_variance_ratio)), 6),
            "reconstruction_rms_px": {"mean": round(float(np.mean(recon_px)), 6),
                                      "max": round(float(np.max(recon_px)), 6)},
            "frames": F, "example_frames": int(ex_frames.size),
            "flow_frames_per_s": round(F / max(t_feat - t_flow, 1e-9), 3),
            "footage": {"path": info.path, "width": info.width, "height": info.height, "fps": info.fps,
                        "scale": info.scale},
            "residual": "not defined: flow features fit no markers (residual_rms is NaN on every frame)",
        }
        timings = {"flow": t_feat - t_flow, "features": t_solve - t_feat, "solve": t_end - t_solve,
                   "total": t_end - t0}
        names = tuple(f"flow_pc{i + 1}" for i in range(pca.n_components))
        return assemble(fitted, res, weights, frames=features.frames, settings=settings,
                        notes=[*notes, *res.warnings], timings=timings, info={"flow": figures},
                        source=(features.coefficients, names))

    return Job(steps(), inner.total, info=info)
