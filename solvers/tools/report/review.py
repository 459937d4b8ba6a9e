"""What a review page shows, computed from a ``RetargetResult`` without Blender: the frames worth a
picture, the removed head motion, and the markers carried onto the character.

The Blender layer (``facecap_addon/render/review.py``) renders the character at the frames ``pick_frames``
chooses and projects ``MarkerGeometry``'s points into the same camera; ``page.write_review_page``
turns a ``Review`` into the HTML page.
"""

import warnings
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from ...capture.align import align_actor
from ...errors import InputFileError
from ...io.csv import read_weights_csv
from ...pipeline.stages import normalise_stabilised


@dataclass(frozen=True, eq=False)
class Truth:
    """Known weights of the take (``--truth``): frames (F,), shape names (K,), values (F, K)."""

    frames: np.ndarray
    names: tuple
    values: np.ndarray
    source: str = ""

    def aligned(self, frames, names):
        """(F', K') values on ``frames`` for ``names`` (NaN where the truth has no such frame or shape)."""
        frames = np.asarray(frames, dtype=np.float64)
        out = np.full((frames.size, len(names)), np.nan)
        order = np.argsort(self.frames, kind="stable")
        pos = np.clip(np.searchsorted(self.frames[order], frames), 0, max(self.frames.size - 1, 0))
        found = self.frames[order][pos] == frames if self.frames.size else np.zeros(frames.size, dtype=bool)
        cols = [(j, self.names.index(n)) for j, n in enumerate(names) if n in self.names]
        if cols and found.any():
            dst, src = np.array(cols).T
            out[np.ix_(np.flatnonzero(found), dst)] = self.values[np.ix_(order[pos[found]], src)]
        return out


def read_truth(path):
    """A truth weights CSV (``frame,<shape>,...``); InputFileError naming the file when it is not one."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "truth weights file not found (--truth)")
    frames, names, values = read_weights_csv(path)
    return Truth(frames, tuple(names), values, str(path))


@dataclass(frozen=True, eq=False)
class Tile:
    """One rendered frame of the contact sheet.

    ``png``: the render (RGB PNG bytes, ``width`` x ``height``); ``captured`` / ``model`` (U, 2): the
    take's markers and the character's bound points at that frame projected into the render (pixels
    from the top left; NaN where a marker is missing); ``distance_mm`` (U,) between the two.
    """

    frame: float
    label: str
    kind: str  # "worst", "peak" or "binding"
    png: bytes
    width: int
    height: int
    captured: np.ndarray = None
    model: np.ndarray = None
    distance_mm: np.ndarray = None
    source_png: bytes = None  # the footage frame (a video take): shown as the source beside the character


@dataclass(frozen=True, eq=False)
class ContactSheet:
    tiles: tuple  # Tile per picked frame, in take order
    marker_names: tuple = ()  # the U markers of every tile's points
    binding: Tile = None  # the neutral character with the bound points and the aligned actor neutral
    seconds: float = 0.0  # time spent rendering


@dataclass(frozen=True, eq=False)
class Review:
    """Everything one review page shows.

    result : RetargetResult; take : the take's name; character : "<blend>: <object>"; settings :
    RetargetSettings (the strategy and its options); source : the markers / weights file; notes :
    warnings from reading the take (before the solve's own); timings : seconds per stage (over
    ``result.timings``); truth : Truth or None; sheet : ContactSheet or None, with ``sheet_note``
    saying why there is none; geometry : MarkerGeometry or None (the binding distances); head_angles :
    (F, 3) the head's yaw, pitch, roll in radians on the result's frames as a phone measured them (Live
    Link Face; a take of solved weights has no stabilisation to show instead), or None.
    """

    result: object
    take: str
    character: str = ""
    settings: object = None
    source: str = ""
    fps: float = None
    notes: tuple = ()
    timings: dict = field(default_factory=dict)
    truth: Truth = None
    sheet: ContactSheet = None
    sheet_note: str = ""
    geometry: object = None  # MarkerGeometry: the binding plot (None: no binding to show)
    head_angles: np.ndarray = None  # (F, 3) radians: the phone's head yaw, pitch, roll (Live Link Face)

    @cached_property
    def truth_values(self):
        """(F, K) the truth on the result's frames and shapes (NaN where it has none), or None."""
        if self.truth is None:
            return None
        return self.truth.aligned(self.result.frames, self.result.shape_names)


def _spaced(order, frames, spacing, count, taken=()):
    """The first ``count`` indices of ``order`` at least ``spacing`` frames from each other and ``taken``."""
    chosen = list(taken)
    out = []
    for i in order:
        if len(out) == count:
            break
        if all(abs(frames[i] - frames[j]) >= spacing for j in chosen):
            chosen.append(i)
            out.append(i)
    return out


def pick_frames(result, *, worst=3, peaks=5, min_peak=0.05, fps=None):
    """The frames worth a picture: the worst residuals and the peaks of the strongest expressions.

    Worst frames are at least a second apart (1/20 of the take if shorter), peaks at least a quarter
    of that from every other pick (a left/right pair peaking together is one picture).

    Returns
    -------
    list of (row index, kind, label), in take order; kind is "worst" or "peak".
    """
    frames = np.asarray(result.frames, dtype=np.float64)
    F = frames.size
    spacing = min(float(fps or 60.0), max(1.0, F / 20.0))
    picks = []
    residual = np.asarray(result.residual_rms, dtype=np.float64)
    if np.isfinite(residual).any():
        order = np.argsort(np.where(np.isfinite(residual), -residual, np.inf), kind="stable")
        order = order[np.isfinite(residual[order])]
        unit = "mm" if result.residual_space in ("character", "actor") else ""
        for rank, i in enumerate(_spaced(order, frames, spacing, worst), 1):
            picks.append((int(i), "worst", f"worst #{rank}: {residual[i] * 1e3:.2f} {unit}".strip()))
    w = np.asarray(result.weights, dtype=np.float64)
    if w.size and np.isfinite(w).any():
        peak = np.nanmax(np.where(np.isfinite(w), w, -np.inf), axis=0)
        for k in np.argsort(-peak, kind="stable"):
            if sum(kind == "peak" for _, kind, _ in picks) == peaks or peak[k] < min_peak:
                break
            i = int(np.nanargmax(np.where(np.isfinite(w[:, k]), w[:, k], -np.inf)))
            if _spaced([i], frames, spacing / 4.0, 1, [p[0] for p in picks]):
                picks.append((i, "peak", f"peak {result.shape_names[k]} {peak[k]:.2f}"))
    return sorted(picks)


def head_motion(stabilise):
    """The removed head motion per frame, or None (no stabilisation).

    Returns
    -------
    dict with ``rotation`` (F, 3) degrees about X, Y, Z (XYZ Euler angles of the head relative to the
    reference; 2D takes: (F, 1) in-plane angle), ``translation`` (F, 3) millimetres the head's centre
    (the stable markers' centroid) moved from the reference (2D: (F, 2) pixels), ``rms`` (F,) stable-marker fit residual (mm; 2D: px),
    ``flagged`` and ``unreliable`` (F,) bool, and ``units`` ("mm" or "px").
    """
    if stabilise is None:
        return None
    R = np.asarray(stabilise.head_rotations(), dtype=np.float64)  # (F, D, D), raw = R @ stabilised + ...
    t = np.asarray(stabilise.translations, dtype=np.float64)
    scale = np.asarray(stabilise.scale_array(), dtype=np.float64)
    # the head's centre (the stable markers' centroid in the reference) as it moved in the raw take
    centre = np.nanmean(np.asarray(stabilise.reference, dtype=np.float64), axis=0)
    origin = np.einsum("fij,fj->fi", R, centre[None] - t) / scale[:, None] - centre
    F = R.shape[0]
    if R.shape[1] == 3:
        rotation = np.degrees(np.stack([np.arctan2(R[:, 2, 1], R[:, 2, 2]),
                                        np.arcsin(np.clip(-R[:, 2, 0], -1.0, 1.0)),
                                        np.arctan2(R[:, 1, 0], R[:, 0, 0])], axis=1))
        units, to_unit = "mm", 1e3
    else:
        rotation = np.degrees(np.arctan2(R[:, 1, 0], R[:, 0, 0]))[:, None]
        units, to_unit = "px", 1.0
    flagged = np.asarray(stabilise.flagged, dtype=bool)
    rotation[flagged], origin[flagged] = np.nan, np.nan
    unreliable = np.zeros(F, dtype=bool) if stabilise.unreliable is None else np.asarray(stabilise.unreliable, bool)
    return {"rotation": rotation, "translation": origin * to_unit, "rms": np.asarray(stabilise.rms) * to_unit,
            "flagged": flagged, "unreliable": unreliable, "units": units}


@dataclass(frozen=True, eq=False)
class MarkerGeometry:
    """The take's markers carried into the character's space, beside the character's bound points.

    ``names`` (U,): markers on both; ``bound`` (U, 3): the bound points on the character's neutral;
    ``actor_neutral`` (U, 3): the take's neutral aligned onto them (``binding_mm``: the distance of
    each, the binding's quality). ``captured(rows)`` / ``model(rows)``: (R, U, 3) the take's markers at
    those rows (stabilised, relative to the neutral, aligned) and the bound points as the solved weights
    pose them. For ``geometric`` their distance is the solve's own per-marker residual; a solve in the actor's
    space (``semantic``) fits the actor's shapes, so there it is how far the character follows the markers.
    """

    names: tuple
    bound: np.ndarray
    actor_neutral: np.ndarray
    binding_mm: np.ndarray
    alignment: object
    deltas: object  # (F, U, 3) callable rows -> actor-space deltas
    shape_deltas: np.ndarray  # (K, U, 3): the result's shapes at the bound points
    weights: np.ndarray  # (F, K)

    def captured(self, rows):
        return self.bound[None] + self.alignment.apply_vectors(self.deltas(rows))

    def model(self, rows):
        K, U, _ = self.shape_deltas.shape
        w = np.nan_to_num(self.weights[rows])
        return self.bound[None] + (w @ self.shape_deltas.reshape(K, U * 3)).reshape(-1, U, 3)


def marker_geometry(result, basis, settings):
    """The ``MarkerGeometry`` of a 3D marker take on a character ``basis`` (its shape keys at the bound
    points, as ``facecap_addon.scene.scene_data.basis_from_object`` reads them), or (None, why not)."""
    stab = result.stabilise
    if stab is None:
        return None, "this take has no markers (the strategy maps solved weights)"
    if stab.markers.dim != 3:
        return None, "2D image tracks are not carried onto the character"
    if basis is None:
        return None, "the character has no vertex groups named after the markers (no binding)"
    names = tuple(n for n in (result.marker_names or stab.markers.names)
                  if n in set(basis.marker_names) and n in set(stab.markers.names))
    if len(names) < 3:
        return None, f"only {len(names)} marker(s) of the take are bound on the character"
    neutral, offsets, _ = normalise_stabilised(stab, settings, [])
    cols = [stab.markers.names.index(n) for n in names]
    actor = neutral[cols]
    bound = basis.neutral[[basis.marker_names.index(n) for n in names]]
    alignment = result.alignment
    if alignment is None or tuple(result.marker_names) != names:
        ok = np.isfinite(actor).all(axis=1)
        if ok.sum() < 3:
            return None, "fewer than 3 markers have a neutral position"
        alignment = align_actor(np.where(ok[:, None], actor, bound), bound, names)
    positions = stab.markers.positions

    def deltas(rows):
        rows = np.atleast_1d(rows)
        d = positions[rows][:, cols] - actor[None]
        return d if offsets is None else d + offsets[rows][:, cols]

    shape_idx = [basis.shape_names.index(n) if n in basis.shape_names else -1 for n in result.shape_names]
    pts = [basis.marker_names.index(n) for n in names]
    shape_deltas = np.stack([basis.deltas[k][pts] if k >= 0 else np.zeros((len(names), 3)) for k in shape_idx])
    aligned = alignment.apply(np.nan_to_num(actor))
    binding = np.where(np.isfinite(actor).all(axis=1), np.linalg.norm(aligned - bound, axis=1), np.nan)
    return MarkerGeometry(names, bound, aligned, binding * 1e3, alignment, deltas, shape_deltas,
                          np.asarray(result.weights, dtype=np.float64)), ""


@dataclass(frozen=True, eq=False)
class SourceView:
    """The take's markers as the actor made them, for the contact sheet's source panel: a front view in
    the panel's pixels (from the top left), oriented like the character (the actor-to-character
    alignment's rotation; without one, the face's own principal axes), at the actor's own scale.

    ``names`` (M,); ``neutral`` (M, 2): each marker's median position; ``at(rows)`` (R, M, 2) the
    markers at those rows (NaN where missing).
    """

    names: tuple
    neutral: np.ndarray
    positions: np.ndarray  # (F, M, 2) pixels
    width: int
    height: int

    def at(self, rows):
        return self.positions[np.atleast_1d(rows)]


def source_view(result, geometry, width, height, *, margin=1.25):
    """The ``SourceView`` of a 3D marker take (its stabilised markers), or None without one."""
    stab = result.stabilise
    if stab is None or getattr(stab, "markers", None) is None or stab.markers.dim != 3:
        return None
    P = np.asarray(stab.markers.positions, dtype=np.float64)
    if not np.isfinite(P).any():
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a marker never seen: an all-NaN column
        neutral = np.nanmedian(P, axis=0)
    seen = np.isfinite(neutral).all(axis=1)
    centre = neutral[seen].mean(axis=0)
    rotation = getattr(getattr(geometry, "alignment", None), "rotation", None)
    if rotation is None:
        rotation = _face_axes(neutral[seen] - centre)
    # the character's front view: x to the right, z up (Blender's front view looks along +Y)
    flat = (P - centre) @ np.asarray(rotation).T
    base = (neutral - centre) @ np.asarray(rotation).T
    u, v = flat[..., 0], flat[..., 2]
    nu, nv = base[seen, 0], base[seen, 2]
    extent = max(np.ptp(nv), np.ptp(nu) * height / width) * margin or 1.0
    mid_u, mid_v = 0.5 * (nu.max() + nu.min()), 0.5 * (nv.max() + nv.min())
    per_px = extent / height

    def px(a, b):
        return np.stack([width / 2 + (a - mid_u) / per_px, height / 2 - (b - mid_v) / per_px], axis=-1)

    return SourceView(tuple(stab.markers.names), px(base[:, 0], base[:, 2]), px(u, v), int(width), int(height))


def _face_axes(points):
    """A rotation taking a face's markers (N, 3) to the character's frame: depth (least spread) to -Y,
    up as close to +Z as that allows."""
    _, _, vt = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)
    depth = vt[2]
    up = np.array([0.0, 0.0, 1.0]) - depth * depth[2]
    up = up / np.linalg.norm(up) if np.linalg.norm(up) > 1e-6 else vt[0]
    right = np.cross(up, -depth)
    return np.stack([right, -depth, up])
