"""Per-shape everyday controls applied after a solve (issue 7): gain, offset, clamp, response
curve, smoothing, mute and lock, saved as JSON presets.

Per shape, in this order::

    y = curve(w)            "linear", "smoothstep" (3x^2 - 2x^3 of clip(x, 0, 1)), "gamma:<g>"
    y = gain * y + offset
    y = smooth(y)           zero-phase local-linear fit over +/- ``smoothing`` seconds
    y = clip(y, clamp)
    y = 0 if mute

``lock`` is not applied here: a locked shape is held at its value *in the solve*
(``RetargetSettings.locks``, built by ``locks_from_controls``), so the other shapes take up what
it does not explain; ``apply_controls`` passes a locked shape through untouched.

Controls are keyed by shape name (case, separator and alias insensitive, as
``solvers.aliases``) or by a shell glob (``mouth*``); an exact name wins over a glob, and among
globs the first listed wins. A key that matches no shape is an error (a typo would otherwise
silently do nothing).
"""

import json
from dataclasses import asdict, dataclass
from fnmatch import fnmatchcase
from pathlib import Path

import numpy as np

from ..capture.smoothing import local_polynomial
from ..errors import FacecapError, InputFileError
from ..io.files import read_text_input, write_json_atomic
from .aliases import canonical_names, name_key

CURVES = ("linear", "smoothstep", "gamma:<g>")
PRESET_FORMAT = "facecap-shape-controls"


def curve_function(spec, *, what="parallel"):
    """The response curve ``spec`` as a callable on arrays (None for "linear").

    ``what`` prefixes the error message (the strategy or control being set).
    """
    if spec in (None, "linear"):
        return None
    if spec == "smoothstep":
        return lambda x: (lambda s: s * s * (3.0 - 2.0 * s))(np.clip(x, 0.0, 1.0))
    if isinstance(spec, str) and spec.startswith("gamma:"):
        try:
            g = float(spec[6:])
        except ValueError:
            g = -1.0
        if not g > 0:
            raise FacecapError(f"{what}: gamma curve needs a positive exponent ('gamma:0.8'); got {spec!r}")
        return lambda x: np.sign(x) * np.abs(x) ** g
    raise FacecapError(f"{what}: unknown curve {spec!r}; available: {', '.join(CURVES)}")


def _number(value):
    return isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)


#: Blender's shape-key slider range: weights (clamp, lock, offset) beyond it are typos
MAX_WEIGHT = 10.0
#: Allowed range of each number of a control (upper bounds: typos beyond them; a smoothing half-window
#: of a minute already flattens any performance)
LIMITS = {"gain": (-1e3, 1e3), "offset": (-MAX_WEIGHT, MAX_WEIGHT), "smoothing": (0.0, 60.0)}


@dataclass(frozen=True)
class ShapeControl:
    """Everyday controls of one shape (defaults change nothing).

    gain, offset : y = gain * curve(w) + offset
    clamp : None or (lo, hi)
    curve : "linear", "smoothstep" or "gamma:<g>"
    smoothing : half-window in seconds of a zero-phase smoothing; 0 = off
    mute : bool, the shape is 0 on every frame
    lock : None or a value the solve holds the shape at (see ``locks_from_controls``)
    """

    gain: float = 1.0
    offset: float = 0.0
    clamp: tuple = None
    curve: str = "linear"
    smoothing: float = 0.0
    mute: bool = False
    lock: float = None

    def __post_init__(self):
        for key, (low, high) in LIMITS.items():
            value = getattr(self, key)
            if not _number(value) or not np.isfinite(value) or not low <= value <= high:
                raise FacecapError(f"shape control: `{key}` must be a number from {low:g} to {high:g}"
                                   f"{' seconds' if key == 'smoothing' else ''}; got {value!r}")
            object.__setattr__(self, key, float(value))
        if self.clamp is not None:
            c = tuple(self.clamp) if isinstance(self.clamp, (list, tuple)) else ()
            if len(c) != 2 or not all(_number(v) and np.isfinite(v) and abs(v) <= MAX_WEIGHT for v in c) or c[0] > c[1]:
                raise FacecapError(f"shape control: `clamp` must be (lo, hi) with lo <= hi, each from -{MAX_WEIGHT:g} "
                                   f"to {MAX_WEIGHT:g}; got {self.clamp!r}")
            object.__setattr__(self, "clamp", (float(c[0]), float(c[1])))
        curve_function(self.curve, what="shape control")
        if not isinstance(self.mute, (bool, np.bool_)):
            raise FacecapError(f"shape control: `mute` must be true or false; got {self.mute!r}")
        object.__setattr__(self, "mute", bool(self.mute))
        if self.lock is not None:
            if not _number(self.lock) or not np.isfinite(self.lock) or abs(self.lock) > MAX_WEIGHT:
                raise FacecapError(f"shape control: `lock` must be a number from -{MAX_WEIGHT:g} to {MAX_WEIGHT:g} or "
                                   f"None; got {self.lock!r}")
            object.__setattr__(self, "lock", float(self.lock))

    def is_identity(self):
        return self == ShapeControl()


def _is_glob(key):
    return any(c in key for c in "*?[")


def _keys(name):
    canon = canonical_names(name)
    return {name_key(name)} | ({name_key(canon[0])} if len(canon) == 1 else set())


def resolve_controls(names, controls):
    """One ``ShapeControl`` (or None) per shape name; exact names (alias-insensitive) before globs.

    Raises FacecapError naming the keys that match no shape.
    """
    names = tuple(names)
    exact, globs = {}, []
    for key, control in (controls or {}).items():
        if not isinstance(control, ShapeControl):
            raise FacecapError(f"shape control '{key}': expected a ShapeControl; got {type(control).__name__}")
        if _is_glob(key):
            globs.append((key, control))
        else:
            for k in _keys(key):
                exact.setdefault(k, (key, control))
    out, used = [], set()
    for n in names:
        hit = next((exact[k] for k in sorted(_keys(n)) if k in exact), None)
        if hit is None:
            hit = next(((p, c) for p, c in globs if fnmatchcase(n, p)), None)
        if hit is not None:
            used.add(hit[0])
        out.append(None if hit is None else hit[1])
    unused = [k for k in (controls or {}) if k not in used]
    if unused:
        raise FacecapError(f"shape controls: key(s) {unused} match no shape; shapes are {', '.join(names[:8])}"
                           f"{'...' if len(names) > 8 else ''}")
    return out


def _smooth(column, half_window):
    """Zero-phase local-linear smoothing of one shape's curve; NaN frames stay NaN and are skipped."""

    ok = np.isfinite(column)
    out = local_polynomial(np.where(ok, column, 0.0), half_window=half_window, order=1, weights=ok.astype(float))
    out = np.where(np.isfinite(out), out, column)
    out[~ok] = np.nan
    return out


def apply_controls(weights, names, controls, fps):
    """Apply per-shape controls to solved weights.

    Parameters
    ----------
    weights : (F, K) weights, NaN where unsolved (stays NaN)
    names : K shape names
    controls : {shape name or glob: ShapeControl}
    fps : frames per second (converts ``smoothing`` seconds to frames)

    Returns
    -------
    (F, K) new array; the input is not modified
    """
    W = np.array(weights, dtype=np.float64)
    names = tuple(names)
    if W.ndim != 2 or W.shape[1] != len(names):
        raise FacecapError(f"apply_controls: `weights` must have shape (F, {len(names)}); got {W.shape}")
    if not fps > 0:
        raise FacecapError(f"apply_controls: `fps` must be > 0; got {fps}")
    for k, c in enumerate(resolve_controls(names, controls)):
        if c is None or c.lock is not None:  # a locked shape keeps the value the solve held it at
            continue
        y = W[:, k]
        curve = curve_function(c.curve, what=f"shape control '{names[k]}'")
        if curve is not None:
            y = curve(y)
        y = c.gain * y + c.offset
        half = int(round(c.smoothing * fps))
        if half > 0:
            y = _smooth(y, half)
        if c.clamp is not None:
            y = np.clip(y, *c.clamp)
        if c.mute:
            y = np.where(np.isnan(y), np.nan, 0.0)
        W[:, k] = y
    return W


def locks_from_controls(controls, names=None):
    """``((pattern, value), ...)`` for ``RetargetSettings.locks`` from the controls that lock a shape.

    With the character's shape ``names``, keys are resolved as ``apply_controls`` does (aliases,
    exact before glob) and the result names shapes exactly; without, the keys are returned as given.
    """
    if names is None:
        return tuple((key, c.lock) for key, c in (controls or {}).items() if c.lock is not None)
    return tuple((n, c.lock) for n, c in zip(names, resolve_controls(names, controls)) if c is not None and c.lock is not None)


def controls_from_gain_offset(names, gain, offset, *, tol=1e-9):
    """``{shape: ShapeControl(gain, offset)}`` for the shapes ``tuning.fit_gain_offset`` changed."""
    gain, offset = np.asarray(gain, dtype=np.float64), np.asarray(offset, dtype=np.float64)
    if gain.shape != (len(names),) or offset.shape != (len(names),):
        raise FacecapError(f"controls_from_gain_offset: gain and offset must have shape ({len(names)},); "
                           f"got {gain.shape} and {offset.shape}")
    return {n: ShapeControl(gain=float(g), offset=float(o)) for n, g, o in zip(names, gain, offset)
            if abs(g - 1.0) > tol or abs(o) > tol}


# -- presets ---------------------------------------------------------------------------------------
FIELDS = tuple(ShapeControl.__dataclass_fields__)


def control_from_dict(body, *, where):
    """A ShapeControl from a preset / config table; ``where`` names it in errors."""
    if not isinstance(body, dict):
        raise FacecapError(f"{where}: expected a table of controls ({', '.join(FIELDS)}); got {body!r}")
    unknown = [k for k in body if k not in FIELDS]
    if unknown:
        raise FacecapError(f"{where}: unknown control(s) {unknown}; known: {', '.join(FIELDS)}")
    try:
        return ShapeControl(**{k: (tuple(v) if k == "clamp" and isinstance(v, list) else v) for k, v in body.items()})
    except FacecapError as exc:
        raise FacecapError(f"{where}: {str(exc).removeprefix('shape control: ')}") from None


def save_preset(path, controls):
    """Write ``controls`` as a JSON preset, atomically (only the fields that differ from the defaults)."""
    default = asdict(ShapeControl())
    shapes = {}
    for key, c in controls.items():
        if not isinstance(c, ShapeControl):
            raise FacecapError(f"save_preset: control '{key}' must be a ShapeControl; got {type(c).__name__}")
        d = asdict(c)
        shapes[key] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items() if v != default[k]}
    write_json_atomic(Path(path), {"format": PRESET_FORMAT, "version": 1, "shapes": shapes})


def load_preset(path):
    """``{key: ShapeControl}`` from a JSON preset; errors name the file and the field."""
    path = Path(path)
    try:
        data = json.loads(read_text_input(path, "preset file not found"))  # a regular file, within its size
    except json.JSONDecodeError as exc:
        raise InputFileError(path, f"not valid JSON: {exc.msg}", line=exc.lineno) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot read: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != PRESET_FORMAT:
        raise InputFileError(path, f"not a shape-controls preset (expected \"format\": \"{PRESET_FORMAT}\")",
                             field="format")
    shapes = data.get("shapes")
    if not isinstance(shapes, dict):
        raise InputFileError(path, "expected a table of shapes", field="shapes")
    out = {}
    for key, body in shapes.items():
        try:
            out[key] = control_from_dict(body, where=f"shapes.{key}")
        except FacecapError as exc:
            raise InputFileError(path, str(exc).split(": ", 1)[1], field=f"shapes.{key}") from None
    return out
