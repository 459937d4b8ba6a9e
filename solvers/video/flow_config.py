"""Video takes in a take config: ``[source] video`` with ``[tracking]`` and ``[flow]`` (no markers).

::

    [source]
    video = "clip.mp4"              # video file, image folder, glob or printf pattern
    first = 1                       # optional: frame range / step / downscale / rate
    last = 150
    step = 1
    scale = 1.0
    fps = 30.0

    [tracking]
    method = "dis"                  # dense flow: "dis" (default) | "farneback" | "tvl1"; or "landmarks"
    region = [x, y, w, h]           # the face, source pixels (default: the whole frame)
    reference = 1                   # the neutral frame (default: the first frame read)
    stable_region = [x, y, w, h]    # or [[x, y, w, h], ...]: moves with the head only (optional)
    grid_step = 4                   # flow sample spacing, working pixels (default: ~4,000 samples)
    drift = "fuse"                  # "fuse" | "direct" | "none"
    preset = "balanced"             # DIS: "ultrafast" | "fast" | "balanced" | "medium"

    [flow]
    components = 12                 # PCA components per frame ...
    variance = 0.99                 # ... or the fewest explaining this fraction

    [solve]
    strategy = "linear"             # "linear" (default for video) | "rbf" | "pca"

    [examples]
    weights = "posed.csv"           # frame,<shape>,... character weights posed at footage frames

Frame numbers (``first``, ``last``, ``reference``, the ``[examples]`` weights) follow the project's
one convention: frame 1 is the first frame of the footage, as in Blender and in marker files. Frame 0
and the removed ``frame_offset`` key are errors that say so (see :data:`FRAME_CONVENTION`), never a
silent one-frame shift.

With ``method = "landmarks"`` (keys ``smoothing``, ``iris``, ``models``) the footage's face landmarks
are the take: it is solved like markers (``[stabilise]``, ``[neutral]``, ``[binding]`` apply, with
the defaults of :func:`landmark_defaults`), so ``[flow]`` and ``[examples]`` do not.

``split_video_sections`` takes these keys out of the parsed TOML before the marker-take schema
check; ``video_take`` validates them (errors name ``[section.key]``); ``check_against_footage``
checks what needs the footage's size and frames.
"""

from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError, FacecapError
from .features import EXAMPLE_STRATEGIES
from .flow_solve import FlowSolveSettings, check_box

SOURCE_KEYS = ("video", "first", "last", "step", "scale", "frame_offset")  # fps is shared with marker takes
#: The one frame-numbering rule, quoted by every message about a frame number.
FRAME_CONVENTION = ("frames count from 1: frame 1 is the first frame of the footage, as in Blender and in marker "
                    "files (configs written for the earlier 0-based video numbering: add 1 to [source] first/last "
                    "and [tracking] reference)")


def frame_number_error(key, value):
    """The message for a bad frame number ``value`` of config key ``key``, or None when it is fine."""
    if key == "source.frame_offset":
        return (f"`frame_offset` was removed: {FRAME_CONVENTION}; frame numbers are those of the footage "
                "itself, so delete the key")
    if not _int(value):
        return f"expected a frame number (an integer >= 1); got {value!r}"
    if value < 1:
        return f"frame {value} does not exist: {FRAME_CONVENTION}"
    return None
TRACKING_KEYS = ("method", "region", "reference", "stable_region", "grid_step", "drift", "preset")
LANDMARK_KEYS = ("method", "smoothing", "iris", "models", "bundle", "blendshapes")
FLOW_KEYS = ("components", "variance")
METHODS = ("dis", "farneback", "tvl1")
NOT_FOR_VIDEO = ("clean", "stabilise", "neutral", "align", "calibration", "mapping", "refine", "binding")


@dataclass(frozen=True)
class VideoTake:
    """``[source] video`` and how it is read (``footage``: Footage keyword options) and solved (``flow``)."""

    path: str
    footage: dict
    flow: FlowSolveSettings


@dataclass(frozen=True)
class LandmarkTake:
    """``[source] video`` with ``[tracking] method = "landmarks"``: read (``footage``) and tracked by the
    face-landmark detector, then solved like a marker take in metres (``landmarks.metric_take``)."""

    path: str
    footage: dict
    smoothing: bool = True
    iris: bool = True
    models: str = None
    bundle: str = "auto"  # the Face Landmarker bundle: "auto" (installed, else the older models) or a path
    blendshapes: str = "fuse"  # "fuse" its blendshape scores with the solve, or "ignore" them


def is_landmark_take(raw):
    """True when ``split_video_sections`` output asks for face landmarks."""
    return raw is not None and isinstance(raw.get("tracking"), dict) and raw["tracking"].get("method") == "landmarks"


def landmark_defaults(data, rigid):
    """Fill in what a landmark take does not need to be told (in the parsed TOML ``data``, for the
    marker-take parser): stabilise on the detector's head-rigid points ``rigid``, the neutral detected
    from the take, the binding by position found automatically, no human template (the detector's points
    do not move as the template's skin does: rendered ICT footage solved worse with it, docs/video.md). A
    key the config gives is kept."""
    data.setdefault("actor", {}).setdefault("template", "none")
    stabilise = data.setdefault("stabilise", {})
    stabilise.setdefault("markers", list(rigid))
    neutral = data.setdefault("neutral", {})
    if not any(k in neutral for k in ("frames", "file", "detect")):
        neutral["detect"] = True
    data.setdefault("binding", {}).setdefault("mode", "nearest")


def split_video_sections(data):
    """Remove ``[tracking]``, ``[flow]`` and the video keys of ``[source]`` from ``data``; returns them
    as ``{"source": {...}, "tracking": {...}, "flow": {...}}``, or None when the take has no video."""
    source = data.get("source", {}) if isinstance(data.get("source"), dict) else {}
    raw = {"source": {k: source.pop(k) for k in SOURCE_KEYS if k in source},
           "tracking": data.pop("tracking", None), "flow": data.pop("flow", None)}
    if not raw["source"] and raw["tracking"] is None and raw["flow"] is None:
        return None
    if "video" in raw["source"]:
        raw["source"]["fps"] = source.get("fps")
    return raw


def _number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _int(value):
    return isinstance(value, int) and not isinstance(value, bool)


def _is_box(value):
    return isinstance(value, list) and len(value) == 4 and all(_number(v) for v in value) \
        and value[2] > 0 and value[3] > 0 and value[0] >= 0 and value[1] >= 0


def video_take(path, raw, data, strategy):
    """A :class:`VideoTake` from ``split_video_sections`` output; ConfigError naming the key otherwise."""
    def fail(key, message):
        raise ConfigError(message, path=path, key=key)

    src, trk, flw = raw["source"], raw["tracking"], raw["flow"]
    landmarks = is_landmark_take(raw)
    if landmarks and flw is not None:
        raise ConfigError("[flow] does not apply to a landmark take (method = \"landmarks\")", path=path)
    for section, table, keys in (("tracking", trk, LANDMARK_KEYS if landmarks else TRACKING_KEYS),
                                 ("flow", flw, FLOW_KEYS)):
        if table is None:
            continue
        if not isinstance(table, dict):
            raise ConfigError(f"[{section}] must be a table", path=path)
        unknown = sorted(set(table) - set(keys))
        if unknown:
            fail(f"{section}.{unknown[0]}", f"unknown key; known keys: {', '.join(keys)}")
    trk, flw = trk or {}, flw or {}
    if "video" not in src:
        given = [f"source.{k}" for k in src if k != "fps"] or [s for s in ("tracking", "flow") if raw[s] is not None]
        fail("source.video", f"missing (needed by [{given[0]}]: a video file or image sequence)")
    video = src["video"]
    if not isinstance(video, str) or not video:
        fail("source.video", f"expected a path string; got {video!r}")
    for other in ("markers", "weights"):
        if other in data.get("source", {}):
            fail(f"source.{other}", "give [source] video or markers / weights, not both")
    footage = _footage_options(src, fail)
    base = Path(path).parent
    video_path = Path(video)
    video_path = str(video_path if video_path.is_absolute() else (base / video_path).resolve())
    if landmarks:
        if strategy not in ("geometric", "semantic"):
            fail("solve.strategy", f"a landmark take solves with geometric (the default: the character's shapes at "
                                   f"the bound landmarks) or semantic; got '{strategy}'")
        models = trk.get("models")
        if models is not None:
            models = str(Path(models) if Path(models).is_absolute() else (base / models).resolve())
        bundle = trk.get("bundle")
        if bundle is not None:
            bundle = str(Path(bundle) if Path(bundle).is_absolute() else (base / bundle).resolve())
        return LandmarkTake(video_path, footage, bool(trk.get("smoothing", True)), bool(trk.get("iris", True)),
                            models, bundle or "auto", trk.get("blendshapes", "fuse"))
    for section in NOT_FOR_VIDEO:
        if section in data:
            raise ConfigError(f"[{section}] does not apply to a [source] video take (flow features: [tracking], "
                              "[flow])", path=path)
    if "markers" in data.get("examples", {}):
        fail("examples.markers", "a video take's examples are frames of the footage itself")
    if strategy not in EXAMPLE_STRATEGIES:
        fail("solve.strategy", f"a [source] video take solves with {', '.join(EXAMPLE_STRATEGIES)} from flow features; "
                               f"got '{strategy}'")
    method = trk.get("method", "dis")
    if method not in METHODS:
        fail("tracking.method", f"a video take follows dense flow: one of {', '.join(METHODS)}; got {method!r}")
    region = trk.get("region")
    if region is not None and not _is_box(region):
        fail("tracking.region", f"expected [x, y, w, h] in pixels (w, h > 0); got {region!r}")
    stable = trk.get("stable_region", [])
    boxes = [stable] if stable and _number(stable[0]) else stable
    if not isinstance(boxes, list) or not all(_is_box(b) for b in boxes):
        fail("tracking.stable_region", f"expected [x, y, w, h] or [[x, y, w, h], ...] in pixels; got {stable!r}")
    if "reference" in trk and (problem := frame_number_error("tracking.reference", trk["reference"])):
        fail("tracking.reference", problem)
    if "grid_step" in trk and not (_int(trk["grid_step"]) and trk["grid_step"] >= 1):
        fail("tracking.grid_step", f"expected a positive integer; got {trk['grid_step']!r}")
    drift = trk.get("drift", "fuse")
    if drift not in ("fuse", "direct", "none"):
        fail("tracking.drift", f"expected \"fuse\", \"direct\" or \"none\"; got {drift!r}")
    preset = trk.get("preset", "balanced")
    if preset not in ("ultrafast", "fast", "balanced", "medium"):
        fail("tracking.preset", f"expected one of ultrafast, fast, balanced, medium; got {preset!r}")
    if "components" in flw and "variance" in flw:
        fail("flow.variance", "give components or variance, not both")
    components = flw.get("components", 12)
    if not _int(components) or components < 1:
        fail("flow.components", f"expected an integer >= 1; got {components!r}")
    variance = flw.get("variance")
    if variance is not None and (not _number(variance) or not 0 < variance <= 1):
        fail("flow.variance", f"must be in (0, 1]; got {variance!r}")
    flow = FlowSolveSettings(method=method, reference=trk.get("reference"),
                             region=None if region is None else tuple(float(v) for v in region),
                             stable_region=tuple(tuple(float(v) for v in b) for b in boxes),
                             grid_step=trk.get("grid_step"), drift=drift, preset=preset, n_components=components,
                             variance=None if variance is None else float(variance))
    return VideoTake(video_path, footage, flow)


def _footage_options(src, fail):
    """Footage keyword options from ``[source]`` (frame range, step, scale, rate), checked."""
    footage = {}
    for key in ("first", "last", "frame_offset"):
        if key in src and (problem := frame_number_error(f"source.{key}", src[key])):
            fail(f"source.{key}", problem)
        if key in src:
            footage[key] = src[key]
    if "step" in src:
        if not _int(src["step"]) or src["step"] < 1:
            fail("source.step", f"expected a positive integer; got {src['step']!r}")
        footage["step"] = src["step"]
    if "scale" in src:
        if not _number(src["scale"]) or not 0 < src["scale"] <= 1:
            fail("source.scale", f"must be in (0, 1]; got {src['scale']!r}")
        footage["scale"] = float(src["scale"])
    if src.get("fps") is not None:
        footage["fps"] = float(src["fps"])
    return footage


def check_against_footage(path, take, info):
    """Region, stable boxes and reference frame against the footage (``FootageInfo``); ConfigError naming the key."""
    if isinstance(take, LandmarkTake):
        return
    size = (info.width, info.height)
    flow = take.flow
    for key, boxes in (("tracking.region", [] if flow.region is None else [flow.region]),
                       ("tracking.stable_region", list(flow.stable_region))):
        for box in boxes:
            try:
                check_box(box, key.split(".")[1], size)
            except FacecapError as exc:
                raise ConfigError(str(exc), path=path, key=key) from None
    if flow.reference is not None and flow.reference not in info.frames:
        raise ConfigError(f"frame {flow.reference} is not in the footage ({info.frames[0]}-{info.frames[-1]}; "
                          "frame 1 is the first)", path=path, key="tracking.reference")
