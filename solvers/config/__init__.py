"""Take configs: a TOML file describing one retarget (paths resolve against the file's folder).

Sections: [target] [source] [clean] [binding] [stabilise] [neutral] [solve] [output], plus the
strategy sections [calibration] [mapping] [examples] [pca] [refine] (see
``docs/strategies.md`` for every key and its default). ``[stabilise] markers`` and
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

import math
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path

from ..capture.align import region_patterns
from ..capture.cleaning import CleanSettings
from ..character.binding_map import BindingSettings
from ..character.shape_options import Region
from ..errors import ConfigError, FacecapError, InputFileError, Problems, table_problems
from ..io.limits import MAX_TEXT_BYTES, check_input_file
from ..io.outputs import user_path
from ..options import OPTIONS, SECTIONS, default
from ..pipeline import RetargetSettings
from ..video.flow_config import is_landmark_take, landmark_defaults, split_video_sections, video_take
from ..video.landmarks import RIGID as LANDMARK_RIGID
from .binding import parse_binding
from .rig import parse_rig
from .strategies import strategy_settings
from .tuning import parse_controls, parse_tuning
from .video_rom import video_rom


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
    actor_profile_path: Path | None = None  # [actor] profile: this performer's stored profile (semantic)
    output_profile: Path | None = None  # [output] profile: the profile this take's calibration measured
    projection: str = "front"  # [solve] projection for 2D takes: "front" or "camera"
    camera_name: str | None = None  # [solve] camera: camera object (None: the scene camera)
    tuning: object = None  # [tuning]: TuningConfig (solvers.config.tuning)
    controls: dict = None  # [controls]: {shape or glob: ShapeControl}
    video: object = None  # [source] video + [tracking] / [flow]: VideoTake (solvers.video.flow_config)
    video_rom: object = None  # [calibration] video / sequence of a landmark take: VideoRom (config.video_rom)
    controls_preset: Path | None = None  # [controls] preset
    output_gltf: Path | None = None  # [output] gltf: binary glTF (.glb) of the character and the take
    output_fbx: Path | None = None  # [output] fbx: the same as FBX
    output_html: Path | None = None  # [output] html: the review page (solvers.tools.report)
    truth_path: Path | None = None  # retarget --truth: known weights the review page overlays (no config key)
    binding: object = None  # [binding]: BindingSettings (solvers.character.binding_map)
    rig: object = None  # [rig]: RigSettings (solvers.config.rig), None when the target is the shape keys

    @property
    def binding_map_path(self):
        """[binding] map, the marker,target CSV (None unless mode = "map")."""
        return None if self.binding is None else self.binding.map_path


#: [output] key -> the file name ending its exporter writes
EXPORT_SUFFIXES = {"gltf": ".glb", "fbx": ".fbx"}


def _export_path(path, key, value):
    """``value`` ([output] gltf / fbx) when it ends in the format's suffix, else ConfigError."""
    suffix = EXPORT_SUFFIXES[key]
    if value is not None and value.suffix.lower() != suffix:
        raise ConfigError(f"expected a file name ending in {suffix}; got '{value.name}'", path=path,
                          key=f"output.{key}")
    return value


def read_config_toml(path):
    """(absolute path, the TOML tables) of a config file.

    Raises
    ------
    ConfigError naming the file when it cannot be read or is not valid TOML.
    """
    path = Path(os.path.expanduser(str(path))).resolve()
    try:
        check_input_file(path, limit=MAX_TEXT_BYTES, missing="config file not found")
        return path, tomllib.loads(path.read_text(encoding="utf-8-sig"))  # a UTF-8 BOM is fine
    except InputFileError as exc:
        raise ConfigError(str(exc).removeprefix(f"{path}: "), path=path) from None
    except FileNotFoundError:
        raise ConfigError("config file not found", path=path) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"not valid TOML: {exc}", path=path) from None
    except RecursionError:
        raise ConfigError("not valid TOML: values nested too deeply", path=path) from None
    except ValueError as exc:  # an integer beyond Python's digit limit
        raise ConfigError(f"not valid TOML: {exc}", path=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read: {exc}", path=path) from None


def load_take_config(path, data=None):
    """Parse and validate a take config.

    ``data``: the config's TOML tables when they are already read (a batch take with its batch
    file's defaults merged in: ``solvers.config.batch``); relative paths still resolve against
    ``path``'s folder.

    Raises
    ------
    ConfigError naming the file and the offending [section] key.
    """
    if data is None:
        path, data = read_config_toml(path)
    else:
        path = Path(os.path.expanduser(str(path))).resolve()
        data = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}  # popped below: a copy
    problems = Problems()
    data = _check_schema(path, data, problems)
    free = {k: data.pop(k) for k in ("tuning", "controls") if k in data}  # parsed by config.tuning
    part = problems.part

    video_raw = split_video_sections(data)  # [source] video, [tracking], [flow]: a markerless video take
    landmarks = is_landmark_take(video_raw)  # ... whose face landmarks are solved like markers
    if landmarks:
        landmark_defaults(data, LANDMARK_RIGID)
    base = path.parent

    def get(section, key, default=None):
        return data.get(section, {}).get(key, default)

    def resolve(value):
        return None if value is None else user_path(value, base)

    units = get("source", "units")
    fps = get("source", "fps")
    read_options = {k: get("source", k) for k in ("format", "unit_scale", "up_axis", "delimiter", "decimal", "columns")}
    read_options = {k: v for k, v in read_options.items() if v is not None}
    if units == "bu" and "unit_scale" not in read_options:
        problems.add(ConfigError("Blender units need unit_scale (metres per unit)", path=path, key="source.unit_scale"))
    clean = part(_clean_settings, path, data.get("clean", {}), default=CleanSettings())
    # a landmark take solves like markers (semantic: onto the sample character 0.274 -> 0.197 visible-shape RMSE
    # on rendered footage, held out 0.207 -> 0.178; onto another person as geometric); a flow take on posed
    # examples; a probed rig's controls on geometric (its model stands for the character's shapes)
    probed_rig = isinstance(data.get("rig"), dict) and data["rig"].get("method", default("rig.method")) == "probed"
    strategy = get("solve", "strategy", ("geometric" if probed_rig else default("solve.strategy"))
                   if video_raw is None or landmarks else "linear")
    video = None if video_raw is None else part(video_take, path, video_raw, data, strategy)
    rom_on_camera = part(video_rom, path, data, video)  # before the strategy's [calibration] is read
    if video_raw is None:
        part(_check_source, path, data, strategy)
    stable, frames = (), [1, 1]
    normalise = {}
    if (video_raw is None or landmarks) and (strategy != "parallel" or "markers" in data.get("stabilise", {})
                                             or data.get("neutral")):
        stable, frames, normalise = part(_stabilise_neutral, path, data, resolve, default=((), [1, 1], {}))
    numbers = {key: get(section, key, default(f"{section}.{key}")) for section, key in (
        ("solve", "regularisation"), ("solve", "sparsity"), ("solve", "symmetry"),
        ("stabilise", "fine_weight"), ("stabilise", "head_smoothing"), ("stabilise", "fine_iterations"),
    )}
    smoothing = get("solve", "smoothing", default("solve.smoothing"))
    shape_options = part(_shape_options, path, data.get("solve", {}), default={})
    projection, camera_name = part(_projection, path, data.get("solve", {}), default=("front", None))
    binding = part(parse_binding, path, data.get("binding"), default=BindingSettings())
    markers_path = resolve(get("source", "markers"))
    weights_path = resolve(get("source", "weights"))
    strategy_options = {}
    if not (video_raw is not None and video is None):  # a broken video take: its strategy inputs are no news
        strategy_options = part(strategy_settings, path, data, strategy, default={})
    part(_check_profile_output, path, data, strategy, rom_on_camera)
    outputs = {key: part(_export_path, path, key, resolve(get("output", key))) for key in EXPORT_SUFFIXES}
    tuning = part(parse_tuning, path, free.get("tuning"), base)
    controls = part(parse_controls, path, free.get("controls"), base)
    rig = part(parse_rig, path, data.get("rig"))
    problems.raise_any()
    cal_units = get("calibration", "units")
    cal_fps = get("calibration", "fps")
    try:
        settings = RetargetSettings(
            stable_markers=tuple(stable),
            neutral_frames=(frames[0], frames[1]),
            **normalise,
            head_target=get("output", "head", ""),
            strategy=strategy,
            smoothing=(float(smoothing[0]), float(smoothing[1])),
            **numbers,
            **shape_options,
            **strategy_options,
        )
    except FacecapError as exc:  # how the sections' values fit together
        raise ConfigError(str(exc), path=path) from None
    return TakeConfig(
        path=path,
        target_blend=resolve(get("target", "blend")),
        target_object=get("target", "object"),
        markers_path=markers_path,
        units=units,
        fps=None if fps is None else float(fps),
        read_options=read_options,
        clean=clean,
        bind_vertex_groups=binding.mode == "vertex_groups",
        settings=settings,
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
        actor_profile_path=resolve(get("actor", "profile")),
        output_profile=resolve(get("output", "profile")),
        output_gltf=outputs["gltf"],
        output_fbx=outputs["fbx"],
        output_html=resolve(get("output", "html")),
        projection=projection,
        camera_name=camera_name,
        tuning=tuning,
        controls=controls,
        controls_preset=resolve(free.get("controls", {}).get("preset")),
        video=video,
        video_rom=rom_on_camera,
        binding=binding,
        rig=rig,
    )


def _check_profile_output(path, data, strategy, rom_on_camera=None):
    """``[output] profile`` stores measured shapes of the actor: the semantic strategy with calibration poses (or a
    stored library or profile to pass on), or the blendshape scores' response from a ROM on camera."""
    if "profile" not in data.get("output", {}) or rom_on_camera is not None:
        return
    cal, actor = data.get("calibration", {}), data.get("actor", {})
    if strategy != "semantic" or not ("poses" in cal or "sequence" in cal or "basis" in cal or "profile" in actor):
        raise ConfigError("a performer profile holds the actor's measured shapes: give [calibration] sequence (a ROM "
                          "session) or poses (with markers, or frames of this take) and the semantic strategy; for a "
                          "landmark take, [calibration] video (the ROM on camera) and sequence, or guide",
                          path=path, key="output.profile")


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


def _check_schema(path, data, problems):
    """Every section and key known and every value of its kind and in its range (``solvers.options``),
    each problem kept in ``problems``; returns ``data`` without what was refused (so that the sections'
    own parsers, which check how values fit together, see only values of the right kind)."""
    for key, message, covers in table_problems(data, OPTIONS):
        problems.add(ConfigError(message, path=path, key=key), covers=covers)
    kept = {}
    for section, body in data.items():
        if section not in SECTIONS or not isinstance(body, dict) or problems.covered(section):
            continue
        kept[section] = {k: v for k, v in body.items() if not problems.covered(f"{section}.{k}")}
    return kept


def _number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool)


#: Blender's shape-key slider range: bounds and lock values outside it are typos
SLIDER_LIMIT = 10.0


def _weight(value):
    return _number(value) and math.isfinite(value) and abs(value) <= SLIDER_LIMIT


def _shape_options(path, solve):
    """bounds / locks / regions of [solve]: shape-name glob patterns mapped to values."""
    bounds = []
    for pattern, value in solve.get("bounds", {}).items():
        if not (isinstance(value, list) and len(value) == 2 and all(_weight(v) for v in value) and value[0] <= value[1]):
            raise ConfigError(f"expected [lower, upper] with lower <= upper, each between -{SLIDER_LIMIT:g} and "
                              f"{SLIDER_LIMIT:g}; got {value}", path=path, key=f"solve.bounds.{pattern}")
        bounds.append((pattern, float(value[0]), float(value[1])))
    locks = []
    for pattern, value in solve.get("locks", {}).items():
        if not _weight(value):
            raise ConfigError(f"expected a number between -{SLIDER_LIMIT:g} and {SLIDER_LIMIT:g}; got {value!r}",
                              path=path, key=f"solve.locks.{pattern}")
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
