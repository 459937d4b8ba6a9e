"""The ``parallel`` strategy: already-solved weights (ARKit / Live Link Face / MediaPipe) to shape keys.

Per frame and character shape ``k``, in this order::

    x  = source channels - neutral offset       (median of the neutral segment, per channel)
    x  = mirror(x)                              (optional: swap Left/Right channels)
    m  = mapping(x)                             (by name / alias, or a table with gains)
    y_k = clip(offset_k + gain_k * curve_k(m_k), clamp_k)

Curves are defined on [0, 1]: ``"linear"``, ``"smoothstep"`` (3x^2 - 2x^3 of clip(x, 0, 1)),
``"gamma:<g>"`` (sign(x) |x|^g) — an exponent g < 1 boosts small values, g > 1 suppresses them.
Per-channel options are dicts keyed by character shape name (alias and case-insensitive); a
scalar applies to every shape; the ``"*"`` key sets the default inside a dict.
"""

import numpy as np

from ..character.aliases import canonical_names, mirror_name, name_key
from ..character.shape_controls import curve_function
from ..errors import FacecapError
from .base import StrategyResult, as_target
from .mapping import Mapping


def parallel_curve(spec):
    """The shared response curve (``shape_controls.curve_function``) with parallel's error prefix."""
    return curve_function(spec, what="parallel")


class ParallelStrategy:
    """Copy solved weights onto the character's shape keys.

    Parameters (keyword-only)
    ----------
    mapping : None, Mapping or dict (as in ``CalibratedStrategy``; None = by name and alias)
    keyed_by : "source" or "target", for a dict ``mapping``
    aliases : bool (default True)
    gain : float or {shape: float}, default 1
    offset : float or {shape: float}, default 0
    clamp : (lo, hi), {shape: (lo, hi)} or None; default None = the character's slider bounds
    curve : "linear", "smoothstep", "gamma:<g>" or {shape: ...}; default "linear"
    mirror : bool, swap Left/Right source channels (mirrored video, or a tracker that names sides
        from the camera's point of view)
    """

    name = "parallel"
    source_kind = "weights"

    def __init__(self, *, mapping=None, keyed_by="source", aliases=True, gain=1.0, offset=0.0, clamp=None,
                 curve="linear", mirror=False):
        self.mapping_spec = mapping
        self.keyed_by = keyed_by
        self.aliases = aliases
        self.gain = gain
        self.offset = offset
        self.clamp = clamp
        self.curve = curve
        self.mirror = bool(mirror)
        for spec in (curve.values() if isinstance(curve, dict) else [curve]):
            parallel_curve(spec)
        self.target = None
        self.mapping = None
        self.source_names = None
        self.neutral = None
        self.notes = ()

    def fit(self, character, *, source_names, neutral=None):
        """Build the channel mapping.

        Parameters
        ----------
        character : Basis or shape names
        source_names : names of the source channels (CSV header without the frame column)
        neutral : ndarray (N, S) or (S,), optional
            Source values over a neutral segment (the actor's relaxed face); their per-channel
            median is subtracted from every frame (a tracker that reads 0.1 on a relaxed brow).
        """
        self.target = as_target(character)
        self.source_names = tuple(str(n) for n in source_names)
        S = len(self.source_names)
        if neutral is not None:
            neutral = np.asarray(neutral, dtype=np.float64)
            if neutral.ndim == 1:
                neutral = neutral[None]
            if neutral.ndim != 2 or neutral.shape[1] != S or neutral.shape[0] == 0:
                raise FacecapError(f"parallel: `neutral` must have shape (N, {S}) or ({S},); got {neutral.shape}")
            neutral = np.nan_to_num(np.nanmedian(neutral, axis=0)) if np.isfinite(neutral).any() else np.zeros(S)
        self.neutral = np.zeros(S) if neutral is None else neutral
        spec = self.mapping_spec
        if spec is None:
            self.mapping = Mapping.by_name(self.source_names, self.target.names, aliases=self.aliases)
        elif isinstance(spec, Mapping):
            self.mapping = spec
        elif isinstance(spec, dict):
            self.mapping = Mapping.from_table(spec, self.source_names, self.target.names, keyed_by=self.keyed_by,
                                              aliases=self.aliases)
        else:
            raise FacecapError(f"parallel: `mapping` must be None, a Mapping or a dict; got {type(spec).__name__}")
        if not np.any(self.mapping.matrix):
            raise FacecapError(
                f"parallel: none of the {len(self.source_names)} source channel(s) ({', '.join(self.source_names[:6])}"
                f"{'...' if len(self.source_names) > 6 else ''}) maps to a shape of the character "
                f"({', '.join(self.target.names[:6])}...): name them alike or give a [mapping] table")
        self._mirror_perm = self._mirror_permutation() if self.mirror else None
        self._gain = self._per_shape(self.gain, 1.0, "gain")
        self._offset = self._per_shape(self.offset, 0.0, "offset")
        self._lo, self._hi = self._bounds()
        self._curves = self._per_shape_curves()
        self.notes = tuple(self.mapping.notes)
        return self

    # -- per-shape option tables -----------------------------------------------------------------
    def _lookup(self, table, default, what):
        keys = {}
        for key, value in table.items():
            if key == "*":
                continue
            canon = canonical_names(key)
            keys[name_key(key)] = value
            if len(canon) == 1:
                keys.setdefault(name_key(canon[0]), value)
        known = {name_key(n) for n in self.target.names} | {
            name_key(c) for n in self.target.names for c in canonical_names(n)
        }
        unknown = [k for k in table if k != "*" and name_key(k) not in known
                   and not any(name_key(c) in known for c in canonical_names(k))]
        if unknown:
            raise FacecapError(f"parallel: `{what}` names unknown character shape(s) {unknown}")
        base = table.get("*", default)
        out = []
        for n in self.target.names:
            canon = canonical_names(n)
            value = keys.get(name_key(n), keys.get(name_key(canon[0]), base) if len(canon) == 1 else base)
            out.append(value)
        return out

    def _per_shape(self, spec, default, what):
        values = self._lookup(spec, default, what) if isinstance(spec, dict) else [spec] * self.target.n_shapes
        arr = np.asarray(values, dtype=np.float64)
        if not np.isfinite(arr).all():
            raise FacecapError(f"parallel: `{what}` must be finite")
        return arr

    def _bounds(self):
        if self.clamp is None:
            return self.target.lower.copy(), self.target.upper.copy()
        if isinstance(self.clamp, dict):
            pairs = self._lookup(self.clamp, None, "clamp")
            pairs = [(lo, hi) if p is None else p for p, lo, hi in zip(pairs, self.target.lower, self.target.upper)]
        else:
            pairs = [self.clamp] * self.target.n_shapes
        arr = np.asarray(pairs, dtype=np.float64)
        if arr.shape != (self.target.n_shapes, 2) or np.any(arr[:, 0] > arr[:, 1]):
            raise FacecapError("parallel: `clamp` must be (lo, hi) with lo <= hi (or a dict of them)")
        return arr[:, 0], arr[:, 1]

    def _per_shape_curves(self):
        specs = self._lookup(self.curve, "linear", "curve") if isinstance(self.curve, dict) else [self.curve] * self.target.n_shapes
        return [parallel_curve(s) for s in specs]

    def _mirror_permutation(self):
        index = {name_key(n): i for i, n in enumerate(self.source_names)}
        return np.array([index.get(name_key(mirror_name(n)), i) for i, n in enumerate(self.source_names)])

    # -- solving -------------------------------------------------------------------------------
    def solve(self, source, *, names=None, neutral=None, confidence=None):
        """Character weights (F, K) from source channel values (F, S); NaN stays NaN.

        ``names`` reorders the source columns to the fitted ``source_names``; ``neutral`` and
        ``confidence`` are accepted for interface compatibility and ignored (the neutral offset
        is set by ``fit``).
        """
        if self.mapping is None:
            raise FacecapError("parallel: call fit() before solve()")
        X = np.asarray(source, dtype=np.float64)
        if X.ndim != 2:
            raise FacecapError(f"parallel: `source` must have shape (F, S) weights; got {X.shape}")
        if names is not None:
            lookup = {name_key(n): i for i, n in enumerate(names)}
            if len(lookup) != X.shape[1]:
                raise FacecapError(f"parallel: `names` has {len(names)} entries for {X.shape[1]} columns")
            cols = [lookup.get(name_key(n)) for n in self.source_names]
            X = np.stack([X[:, c] if c is not None else np.full(len(X), np.nan) for c in cols], axis=1)
        if X.shape[1] != len(self.source_names):
            raise FacecapError(f"parallel: `source` has {X.shape[1]} channels; fitted on {len(self.source_names)}")
        x = X - self.neutral
        if self._mirror_perm is not None:
            x = x[:, self._mirror_perm]
        missing = np.isnan(x)
        m = self.mapping.apply(np.where(missing, 0.0, x))
        nan_rows = (np.abs(self.mapping.matrix) @ missing.T.astype(float)).T > 0  # a driving channel is NaN
        for k, curve in enumerate(self._curves):
            if curve is not None:
                m[:, k] = curve(m[:, k])
        y = self._offset + self._gain * m
        out = np.clip(y, self._lo, self._hi)
        clamped = (np.abs(out - y) > 1e-12) & ~nan_rows
        out[nan_rows] = np.nan
        solved = ~nan_rows.all(axis=1)
        return StrategyResult(
            weights=out, shape_names=self.target.names, solved=solved, warnings=self.notes,
            source_weights=x, source_names=self.source_names, residual_rms=None,
            clamped=clamped.sum(axis=1), info={"mirror": self.mirror},
        )
