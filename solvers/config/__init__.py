"""Take configs: a TOML file describing one retarget (paths resolve against the file's folder).

Sections: [target] [source] [clean] [binding] [stabilise] [neutral] [solve] [output], plus the
strategy sections [calibration] [mapping] [examples] [pca] [refine] (see
``solvers/strategies/README.md`` for every key and its default). ``[stabilise] markers`` and
``[neutral] frames`` are required for marker strategies; ``parallel`` reads ``[source] weights``
instead of ``[source] markers``; a video take reads ``[source] video`` with ``[tracking]`` and ``[flow]``
(flow-PCA features for linear / rbf / pca; ``solvers.video.flow_config``).

Stabilisation and normalisation (issue 4): ``[stabilise] markers = "auto"`` suggests the stable set
from the take, ``mode = "rigid" | "similarity"``; ``[neutral] frames = [first, last]`` or several
ranges ``[[1, 30], [571, 600]]`` (start and end T-poses), or ``file = "neutral.csv"``, or
``detect = true``; ``master = "master.csv"`` normalises to the performer's master T-pose on the
``landmarks`` (glob patterns; default eye and mouth corners); ``[align] regions = true`` (upper /
lower face) or ``{name = [patterns]}`` with separate scales, ``flag_mm`` the residual that flags a
binding; ``[output] head = "Object"`` or ``"Armature:bone"`` keys the removed head motion there.

The animator feedback loop (issue 7): ``[tuning]`` and ``[controls]``, see ``solvers.config.tuning``.
"""

import tomllib
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError, FacecapError
from ..markers import UNIT_SCALE
from ..pipeline import STRATEGIES, RetargetSettings
from ..character.shape_options import Region
from .strategies import strategy_settings
from .tuning import parse_controls, parse_tuning

# section -> {key: (type(s), required)}
SCHEMA = {
    "target": {"blend": (str, False), "object": (str, True)},
    "source": {
        "markers": (str, False),
        "weights": (str, False),
        "format": (str, False),
        "units": (str, False),
        "unit_scale": ((int, float), False),
        "fps": ((int, float), False),
        "up_axis": (str, False),
        "delimiter": (str, False),
        "decimal": (str, False),
    },
    "clean": {
        "fix_swaps": (bool, False),
        "swap_ratio": ((int, float), False),
        "spike_speed": ((int, float), False),
        "spike_mad": ((int, float), False),
        "fill_spline": (int, False),
        "fill_model": (int, False),
        "model_rank": (int, False),
        "lowpass_hz": ((int, float), False),
        "lowpass_order": (int, False),
        "one_euro": (list, False),
    },
    "binding": {"vertex_groups": (bool, False)},
    "stabilise": {
        "markers": ((list, str), False),
        "mode": (str, False),
        "fine_iterations": (int, False),
        "fine_weight": ((int, float), False),
        "head_smoothing": ((int, float), False),
    },
    "neutral": {"frames": (list, False), "file": (str, False), "detect": (bool, False), "master": (str, False),
                "landmarks": (list, False)},
    "align": {"regions": ((bool, dict), False), "flag_mm": ((int, float), False)},
    "solve": {
        "strategy": (str, False),
        "regularisation": ((int, float), False),
        "sparsity": ((int, float), False),
        "symmetry": ((int, float), False),
        "smoothing": (list, False),
        "bounds": (dict, False),
        "locks": (dict, False),
        "regions": (dict, False),
        "projection": (str, False),  # 2D takes: "front" (orthographic) or "camera" (the scene camera)
        "camera": (str, False),  # 2D takes: camera object name for projection = "camera" (default: scene camera)
    },
    "output": {"blend": (str, False), "weights": (str, False), "report": (str, False), "action": (str, False),
               "actor_basis": (str, False),
               "head": (str, False)},
    "calibration": {
        "markers": (str, False),
        "units": (str, False),
        "fps": ((int, float), False),
        "neutral": (list, False),
        "poses": (dict, False),
        "split": (list, False),
        "stable_markers": (list, False),
        "basis": (str, False),
        "align": (str, False),
    },
    "mapping": {
        "aliases": (bool, False),
        "keyed_by": (str, False),
        "table": (dict, False),
        "gain": ((int, float, dict), False),
        "offset": ((int, float, dict), False),
        "clamp": ((list, dict), False),
        "curve": ((str, dict), False),
        "mirror": (bool, False),
        "neutral": (list, False),
    },
    "examples": {
        "weights": (str, False),
        "markers": (str, False),
        "frames": (list, False),
        "ridge": ((int, float), False),
        "kernel": (str, False),
        "rbf_smoothing": ((int, float), False),
        "degree": (int, False),
        "n_components": (int, False),
        "far": ((int, float), False),
    },
    "pca": {"mode": (str, False), "ica": (bool, False), "n_basis": (int, False), "variance": ((int, float), False)},
    "refine": {
        "training": (str, False),
        "max_iterations": (int, False),
        "tol": ((int, float), False),
        "stiffness": ((int, float), False),
    },
}


@dataclass(frozen=True)
class TakeConfig:
    """A parsed take config with absolute paths."""

    path: Path
    target_blend: Path | None
    target_object: str
    markers_path: Path
    units: str | None  # None: from the file, or guessed from the face size
    fps: float | None  # None: from the file
    read_options: dict  # format, unit_scale, up_axis, delimiter, decimal
    clean: object  # CleanSettings
    bind_vertex_groups: bool
    settings: RetargetSettings
    output_blend: Path | None
    output_weights: Path | None
    output_report: Path | None
    action_name: str
    weights_path: Path | None = None  # [source] weights: solved weights for ``parallel``
    calibration_path: Path | None = None  # [calibration] markers
    calibration_units: str | None = None
    calibration_fps: float | None = None
    actor_basis_path: Path | None = None  # [calibration] basis (a stored library, Basis.save_npz)
    examples_weights_path: Path | None = None  # [examples] weights (frame,<shape>... posed weights)
    examples_markers_path: Path | None = None  # [examples] markers (the take they belong to; default this one)
    training_path: Path | None = None  # [refine] training (default: the take itself)
    output_actor_basis: Path | None = None  # [output] actor_basis: the actor library used (refine: refined)
    projection: str = "front"  # [solve] projection for 2D takes: "front" or "camera"
    camera_name: str | None = None  # [solve] camera: camera object (None: the scene camera)
    tuning: object = None  # [tuning]: TuningConfig (solvers.config.tuning)
    controls: dict = None  # [controls]: {shape or glob: ShapeControl}
    video: object = None  # [source] video + [tracking] / [flow]: VideoTake (solvers.video.flow_config)


def load_take_config(path):
    """Parse and validate a take config.

    Raises
    ------
    ConfigError naming the file and the offending [section] key.
    """
    path = Path(path).resolve()
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError("config file not found", path=path) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"not valid TOML: {exc}", path=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read: {exc}", path=path) from None
    free = {k: data.pop(k) for k in ("tuning", "controls") if k in data}  # parsed by tuning_config
    from ..video.flow_config import split_video_sections, video_take

    video_raw = split_video_sections(data)  # [source] video, [tracking], [flow]: a markerless video take
    _check_schema(path, data)
    base = path.parent

    def get(section, key, default=None):
        return data.get(section, {}).get(key, default)

    def resolve(value):
        return None if value is None else (base / value).resolve()

    units = get("source", "units")
    if units is not None and units not in (*UNIT_SCALE, "bu", "px"):
        raise ConfigError(f"units must be one of {sorted((*UNIT_SCALE, 'bu', 'px'))}; got '{units}'", path=path, key="source.units")
    fps = get("source", "fps")
    if fps is not None and fps <= 0:
        raise ConfigError(f"fps must be positive; got {fps}", path=path, key="source.fps")
    read_options = {k: get("source", k) for k in ("format", "unit_scale", "up_axis", "delimiter", "decimal")}
    read_options = {k: v for k, v in read_options.items() if v is not None}
    if units == "bu" and "unit_scale" not in read_options:
        raise ConfigError("Blender units need unit_scale (metres per unit)", path=path, key="source.unit_scale")
    clean = _clean_settings(path, data.get("clean", {}))
    strategy = get("solve", "strategy", "geometric" if video_raw is None else "linear")
    if strategy not in STRATEGIES:
        raise ConfigError(f"unknown strategy '{strategy}'; available: {', '.join(STRATEGIES)}", path=path, key="solve.strategy")
    video = None if video_raw is None else video_take(path, video_raw, data, strategy)
    if video is None:
        _check_source(path, data, strategy)
    stable, frames = (), [1, 1]
    normalise = {}
    if video is None and (strategy != "parallel" or "markers" in data.get("stabilise", {}) or data.get("neutral")):
        stable, frames, normalise = _stabilise_neutral(path, data, resolve)
    defaults = RetargetSettings(stable_markers=(), neutral_frames=(1, 1))
    numbers = {}
    for section, key in (
        ("solve", "regularisation"), ("solve", "sparsity"), ("solve", "symmetry"),
        ("stabilise", "fine_weight"), ("stabilise", "head_smoothing"), ("stabilise", "fine_iterations"),
    ):
        value = get(section, key, getattr(defaults, key))
        if value < 0:
            raise ConfigError(f"must be >= 0; got {value}", path=path, key=f"{section}.{key}")
        numbers[key] = value
    smoothing = get("solve", "smoothing", list(defaults.smoothing))
    if len(smoothing) != 2 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and v >= 0 for v in smoothing):
        raise ConfigError(f"expected [first_difference, second_difference] weights >= 0; got {smoothing}", path=path, key="solve.smoothing")
    shape_options = _shape_options(path, data.get("solve", {}))
    projection, camera_name = _projection(path, data.get("solve", {}))
    if not get("binding", "vertex_groups", True):
        raise ConfigError("only vertex-group binding is available (set vertex_groups = true)", path=path, key="binding.vertex_groups")
    markers_path = resolve(get("source", "markers"))
    weights_path = resolve(get("source", "weights"))
    strategy_options = strategy_settings(path, data, strategy)
    cal_units = get("calibration", "units")
    if cal_units is not None and cal_units not in (*UNIT_SCALE, "px"):  # px: a filmed calibration (2D tracks)
        raise ConfigError(f"units must be one of {sorted((*UNIT_SCALE, 'px'))}; got '{cal_units}'", path=path,
                          key="calibration.units")
    cal_fps = get("calibration", "fps")
    if cal_fps is not None and cal_fps <= 0:
        raise ConfigError(f"fps must be positive; got {cal_fps}", path=path, key="calibration.fps")
    return TakeConfig(
        path=path,
        target_blend=resolve(get("target", "blend")),
        target_object=get("target", "object"),
        markers_path=markers_path,
        units=units,
        fps=None if fps is None else float(fps),
        read_options=read_options,
        clean=clean,
        bind_vertex_groups=True,
        settings=RetargetSettings(
            stable_markers=tuple(stable),
            neutral_frames=(frames[0], frames[1]),
            **normalise,
            head_target=get("output", "head", ""),
            strategy=strategy,
            smoothing=(float(smoothing[0]), float(smoothing[1])),
            **numbers,
            **shape_options,
            **strategy_options,
        ),
        output_blend=resolve(get("output", "blend")),
        output_weights=resolve(get("output", "weights")),
        output_report=resolve(get("output", "report")),
        action_name=get("output", "action", (markers_path or weights_path or Path(getattr(video, "path", ""))).stem),
        weights_path=weights_path,
        calibration_path=resolve(get("calibration", "markers")),
        calibration_units=cal_units,
        calibration_fps=None if cal_fps is None else float(cal_fps),
        actor_basis_path=resolve(get("calibration", "basis")),
        examples_weights_path=resolve(get("examples", "weights")),
        examples_markers_path=resolve(get("examples", "markers")),
        training_path=resolve(get("refine", "training")),
        output_actor_basis=resolve(get("output", "actor_basis")),
        projection=projection,
        camera_name=camera_name,
        tuning=parse_tuning(path, free.get("tuning"), base),
        controls=parse_controls(path, free.get("controls"), base),
        video=video,
    )


def _projection(path, solve):
    """[solve] projection / camera: how a 2D take sees the character (video takes)."""
    projection = solve.get("projection", "front")
    if projection not in ("front", "camera"):
        raise ConfigError(f"expected \"front\" or \"camera\"; got '{projection}'", path=path, key="solve.projection")
    camera = solve.get("camera")
    if camera is not None and projection != "camera":
        raise ConfigError("a camera is only used with projection = \"camera\"", path=path, key="solve.camera")
    if camera is not None and not camera.strip():
        raise ConfigError("expected a camera object name", path=path, key="solve.camera")
    return projection, camera


def _frame_pair(value):
    return (isinstance(value, list) and len(value) == 2 and all(isinstance(v, int) and not isinstance(v, bool)
            for v in value) and value[0] <= value[1])


def _stabilise_neutral(path, data, resolve):
    """[stabilise] markers / mode, [neutral] frames / file / detect / master / landmarks, [align]."""
    st, ne, al = data.get("stabilise", {}), data.get("neutral", {}), data.get("align", {})
    out = {}
    if "markers" not in st:
        raise ConfigError("missing required key (a list of marker names, or \"auto\")", path=path, key="stabilise.markers")
    stable = st["markers"]
    if isinstance(stable, str):
        if stable != "auto":
            raise ConfigError(f"expected a list of marker names or \"auto\"; got '{stable}'", path=path,
                              key="stabilise.markers")
        stable, out["auto_stable"] = (), True
    elif not all(isinstance(s, str) for s in stable) or len(stable) < 3:
        raise ConfigError("expected a list of at least 3 marker names (or \"auto\")", path=path, key="stabilise.markers")
    mode = st.get("mode", "rigid")
    if mode not in ("rigid", "similarity"):
        raise ConfigError(f"expected \"rigid\" or \"similarity\"; got '{mode}'", path=path, key="stabilise.mode")
    out["stabilise_mode"] = mode
    frames = ne.get("frames")
    if frames is None:
        if not (ne.get("detect") or "file" in ne):
            raise ConfigError("missing required key (or set detect = true, or file = \"neutral.csv\")", path=path,
                              key="neutral.frames")
        if "master" in ne:
            raise ConfigError("master T-pose normalisation needs the take's T-pose frames", path=path, key="neutral.frames")
        frames = [1, 1]
    elif frames and all(isinstance(r, list) for r in frames):
        if not all(_frame_pair(r) for r in frames):
            raise ConfigError(f"expected [[first, last], ...] frame ranges; got {frames}", path=path, key="neutral.frames")
        out["neutral_ranges"] = tuple(tuple(r) for r in frames)
        frames = frames[0]
    elif not _frame_pair(frames):
        raise ConfigError(f"expected [first, last] frame numbers or [[first, last], ...]; got {frames}", path=path,
                          key="neutral.frames")
    if ne.get("detect"):
        if "frames" in ne:
            raise ConfigError("give frames or detect = true, not both", path=path, key="neutral.detect")
        out["neutral_detect"] = True
    for key, field in (("file", "neutral_file"), ("master", "master")):
        if key in ne:
            p = resolve(ne[key])
            if not p.is_file():
                raise ConfigError(f"file not found: {p}", path=path, key=f"neutral.{key}")
            out[field] = str(p)
    if "landmarks" in ne:
        marks = ne["landmarks"]
        if len(marks) < 3 or not all(isinstance(v, str) for v in marks):
            raise ConfigError("expected a list of at least 3 marker names or patterns", path=path, key="neutral.landmarks")
        out["landmarks"] = tuple(marks)
    regions = al.get("regions", False)
    if isinstance(regions, dict):
        for name, pats in regions.items():
            if not (isinstance(pats, list) and pats and all(isinstance(v, str) for v in pats)):
                raise ConfigError("expected a non-empty list of marker patterns", path=path, key=f"align.regions.{name}")
    from ..capture.align import region_patterns

    out["align_regions"] = region_patterns(regions)
    if "flag_mm" in al:
        if al["flag_mm"] <= 0:
            raise ConfigError(f"must be > 0; got {al['flag_mm']}", path=path, key="align.flag_mm")
        out["align_flag_mm"] = float(al["flag_mm"])
    return stable, frames, out


def _check_source(path, data, strategy):
    """Exactly one of [source] markers / weights, the one the strategy reads."""
    source = data.get("source", {})
    if strategy == "parallel":
        if "weights" not in source:
            raise ConfigError("strategy 'parallel' needs [source] weights (a Live Link Face / ARKit / MediaPipe CSV "
                              "of solved weights)", path=path, key="source.weights")
        if "markers" in source:
            raise ConfigError("give [source] weights or markers, not both (parallel reads weights)", path=path,
                              key="source.markers")
    else:
        if "markers" not in source:
            raise ConfigError("missing required key" + ("" if "weights" not in source else
                              f" (strategy '{strategy}' solves markers; [source] weights is for 'parallel')"),
                              path=path, key="source.markers")
        if "weights" in source:
            raise ConfigError(f"[source] weights is only read by strategy 'parallel', not '{strategy}'", path=path,
                              key="source.weights")


def _check_schema(path, data):
    for section, body in data.items():
        if section not in SCHEMA:
            raise ConfigError(f"unknown section [{section}]; known: {', '.join(SCHEMA)}", path=path)
        if not isinstance(body, dict):
            raise ConfigError(f"[{section}] must be a table", path=path)
        for key, value in body.items():
            if key not in SCHEMA[section]:
                raise ConfigError(
                    f"unknown key; known keys: {', '.join(SCHEMA[section])}", path=path, key=f"{section}.{key}"
                )
            kind, _ = SCHEMA[section][key]
            allows_bool = kind is bool or (isinstance(kind, tuple) and bool in kind)
            if not isinstance(value, kind) or (not allows_bool and isinstance(value, bool)):
                raise ConfigError(f"wrong type {type(value).__name__}", path=path, key=f"{section}.{key}")
    for section, keys in SCHEMA.items():
        for key, (_, required) in keys.items():
            if required and key not in data.get(section, {}):
                raise ConfigError("missing required key", path=path, key=f"{section}.{key}")


def _number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _shape_options(path, solve):
    """bounds / locks / regions of [solve]: shape-name glob patterns mapped to values."""
    bounds = []
    for pattern, value in solve.get("bounds", {}).items():
        if not (isinstance(value, list) and len(value) == 2 and all(_number(v) for v in value) and value[0] <= value[1]):
            raise ConfigError(f"expected [lower, upper] with lower <= upper; got {value}", path=path, key=f"solve.bounds.{pattern}")
        bounds.append((pattern, float(value[0]), float(value[1])))
    locks = []
    for pattern, value in solve.get("locks", {}).items():
        if not _number(value):
            raise ConfigError(f"expected a number; got {value!r}", path=path, key=f"solve.locks.{pattern}")
        locks.append((pattern, float(value)))
    regions = []
    for name, body in solve.get("regions", {}).items():
        key = f"solve.regions.{name}"
        if not isinstance(body, dict) or set(body) != {"shapes", "markers"}:
            raise ConfigError("expected a table with 'shapes' and 'markers' lists of name patterns", path=path, key=key)
        for field in ("shapes", "markers"):
            if not (isinstance(body[field], list) and body[field] and all(isinstance(v, str) for v in body[field])):
                raise ConfigError(f"'{field}' must be a non-empty list of name patterns", path=path, key=key)
        regions.append(Region(name, tuple(body["shapes"]), tuple(body["markers"])))
    return {"bounds": tuple(bounds), "locks": tuple(locks), "regions": tuple(regions)}


def _clean_settings(path, section):
    """[clean] -> CleanSettings (every step off unless named)."""
    from ..capture.cleaning import CleanSettings

    values = dict(section)
    if "one_euro" in values:
        v = values["one_euro"]
        if len(v) != 3 or not all(_number(x) and x > 0 for x in v):
            raise ConfigError(f"expected [min_cutoff_hz, beta, d_cutoff_hz] > 0; got {v}", path=path, key="clean.one_euro")
        values["one_euro"] = tuple(float(x) for x in v)
    for key, value in values.items():
        if _number(value) and value < 0:
            raise ConfigError(f"must be >= 0; got {value}", path=path, key=f"clean.{key}")
    try:
        return CleanSettings(**values)
    except FacecapError as exc:
        raise ConfigError(str(exc), path=path, key="clean") from None
