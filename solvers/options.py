"""Every take-config option, defined once: name, kind, default, allowed range, one-line doc, and
where the sidebar shows it.

From this table come the take config's schema and value checks (``solvers.config``), the defaults
of the settings dataclasses (``default("solve.regularisation")``), the Blender property defaults,
ranges and descriptions (``facecap_addon.ui.properties``), and ``docs/config.md``
(``python -m facecap config-docs``). A test checks that every option has a sidebar control or says
why it is headless-only, and that every sidebar setting is an option or says why it is not.

Kinds: ``bool``, ``int``, ``float``, ``str``, ``choice`` (one of ``choices``), ``path`` (a file
or folder, relative to the config's folder), ``frames`` ([first, last] frame numbers),
``names`` (a list of names or glob patterns), ``floats`` (a fixed-length list of numbers),
``table`` (a TOML table checked by the section's own parser), or a tuple of kinds for a value
that may take several forms. ``ui`` names the controls, comma-separated: ``facecap.<prop>`` (a
``Scene.facecap`` setting, ``facecap.video.<prop>`` for the video group) or ``op:<operator>.<prop>``
(an operator's option); an empty ``ui`` needs a ``headless`` reason.
"""

import math
from dataclasses import dataclass

#: Frame rates above this are refused as typos (a 10 kHz optical system is already unusual).
MAX_FPS = 10_000.0
GUIDE_HEADLESS = "the sidebar finds it (Actor calibration > Guide, then Save Performer Profile)"
#: Frame numbers above this are refused (Blender's own limit is 1,048,574).
MAX_FRAME = 1_048_574
#: Blender keeps at most this many bytes of an ID's name (objects, actions, cameras) and cuts the rest.
MAX_NAME_BYTES = 63


@dataclass(frozen=True)
class Option:
    section: str
    key: str
    kind: object
    default: object = None
    doc: str = ""
    low: float = None  # inclusive lower bound of a number (or of each number of a list)
    high: float = None  # inclusive upper bound
    above: float = None  # exclusive lower bound (``> above``)
    choices: tuple = ()
    length: int = None  # ``floats``: how many numbers
    required: bool = False
    ui: str = ""  # the sidebar control (see the module docstring)
    headless: str = ""  # why there is no control, when ``ui`` is empty
    hint: str = ""  # said before what was expected when a value is refused
    max_bytes: int = None  # ``str``: longest value in UTF-8 bytes (Blender's name limit)

    @property
    def name(self):
        return f"{self.section}.{self.key}"

    def check(self, value):
        """None when ``value`` is allowed, else what was expected (one line)."""
        kinds = self.kind if isinstance(self.kind, tuple) else (self.kind,)
        problems = [_problem(self, kind, value) for kind in kinds]
        if None in problems:
            return None
        return f"{self.hint}: {problems[0]}" if self.hint else problems[0]

    def range_text(self):
        """The allowed range in words (for messages and docs), or ''."""
        parts = [f"{sign} {_number_text(v)}" for sign, v in (("> ", self.above), (">=", self.low), ("<=", self.high))
                 if v is not None]
        return " and ".join(p.replace(">  ", "> ") for p in parts)


def _number_text(v):
    """A bound in words: ``%g`` (1e+06, 0.5), or every digit of a whole number ``%g`` would round (1048574)."""
    short = f"{v:g}"
    return str(int(v)) if float(v).is_integer() and float(short) != float(v) else short


def _is_int(v):
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _number_problem(option, v, what="a number"):
    if not _is_number(v):
        return f"expected {what}; got {v!r}"
    if isinstance(v, float) and not math.isfinite(v):
        return f"expected a finite number; got {v!r}"
    if (option.above is not None and not v > option.above) or (option.low is not None and v < option.low) \
            or (option.high is not None and v > option.high):
        return f"expected {what} {option.range_text()}; got {v!r}"
    return None


def _problem(option, kind, v):
    if kind == "bool":
        return None if isinstance(v, bool) else f"expected true or false; got {v!r}"
    if kind == "int":
        return _number_problem(option, v, "an integer") if _is_int(v) else f"expected an integer; got {v!r}"
    if kind == "float":
        return _number_problem(option, v)
    if kind in ("str", "path"):
        if not isinstance(v, str) or not v.strip():
            return f"expected a {'file name' if kind == 'path' else 'text'}; got {v!r}"
        if "\0" in v:
            return "must not contain NUL characters"
        if option.max_bytes is not None and len(v.encode("utf-8")) > option.max_bytes:
            return f"at most {option.max_bytes} bytes (Blender's limit for a name); got {len(v.encode('utf-8'))}"
        return None
    if kind == "choice":
        if v in option.choices:
            return None
        return f"expected one of {', '.join(map(str, option.choices))}; got {v!r}"
    if kind == "frames":
        ok = isinstance(v, list) and len(v) == 2 and all(_is_int(x) for x in v) and v[0] <= v[1]
        return None if ok else f"expected [first, last] frame numbers with first <= last; got {v!r}"
    if kind == "names":
        ok = isinstance(v, list) and all(isinstance(x, str) and x and "\0" not in x for x in v)
        return None if ok else f"expected a list of names; got {v!r}"
    if kind == "floats":
        if not (isinstance(v, list) and len(v) == option.length):
            return f"expected a list of {option.length} numbers; got {v!r}"
        return next((p for p in (_number_problem(option, x) for x in v) if p), None)
    if kind == "table":
        return None if isinstance(v, dict) else f"expected a table; got {v!r}"
    if kind == "list":
        return None if isinstance(v, list) else f"expected a list; got {v!r}"
    raise ValueError(f"unknown option kind {kind!r}")


O = Option
UNITS = ("m", "cm", "mm", "bu", "px")
STRATEGIES = ("semantic", "geometric", "calibrated", "parallel", "linear", "rbf", "pca", "refine")
RBF_KERNELS = ("thin_plate_spline", "cubic", "quintic", "linear", "gaussian", "multiquadric",
               "inverse_multiquadric", "inverse_quadratic")
OUTPUT_FILE = "an output of a headless run (the sidebar saves with File > Save)"

OPTIONS = (
    # -- [target] ----------------------------------------------------------------------------------
    O("target", "blend", "path", doc="The character's .blend (default: the open file)",
      headless="the sidebar works on the open .blend"),
    O("target", "object", "str", required=True, max_bytes=MAX_NAME_BYTES, doc="The mesh object with the shape keys",
      ui="facecap.target"),
    # -- [source] ----------------------------------------------------------------------------------
    O("source", "markers", "path", doc="Marker take: C3D, TRC, CSV (wide or long) or JSON",
      ui="facecap.markers_path"),
    O("source", "weights", "path", doc="Solved weights (Live Link Face / ARKit / MediaPipe CSV) for `parallel`",
      ui="facecap.weights_path"),
    O("source", "video", "path", doc="Video file, image folder, glob or printf pattern (a markerless video take)",
      headless="the sidebar reads the footage of a Movie Clip"),
    O("source", "format", "choice", choices=("c3d", "trc", "csv", "csv-long", "json"),
      doc="File format (default: from the extension and content)", headless="File > Import picks the format"),
    O("source", "units", "choice", choices=UNITS,
      doc="Units of the coordinates (default: the file's, else guessed from the face size with a note)",
      ui="facecap.units, op:facecap.import_markers.units"),
    O("source", "unit_scale", "float", above=0.0, high=1e3, doc="Metres per unit for `units = \"bu\"` (Blender units)",
      ui="op:facecap.import_markers.unit_scale"),
    O("source", "fps", "float", above=0.0, high=MAX_FPS, doc="Frame rate (default: the file's)",
      ui="facecap.fps"),
    O("source", "up_axis", "choice", choices=("Z", "Y"), doc="The file's up axis; Y-up files are turned Z-up",
      ui="op:facecap.import_markers.up_axis"),
    O("source", "delimiter", "choice", choices=(",", ";", "\t", "|"), doc="CSV delimiter (default: detected)",
      headless="detected on import"),
    O("source", "decimal", "choice", choices=(".", ","), doc="CSV decimal mark (default: detected)",
      headless="detected on import"),
    O("source", "columns", "names", doc="A marker CSV without a header row: its columns, `frame` or `time` then "
      "marker names (a name stands for its x, y, z columns; `name_x`, `name_y` for 2D tracks)",
      headless="File > Import reads CSVs with a header row"),
    O("source", "first", "int", high=MAX_FRAME, doc="Video takes: first footage frame read",
      headless="the Movie Clip's frame range"),
    O("source", "last", "int", high=MAX_FRAME, doc="Video takes: last footage frame read",
      headless="the Movie Clip's frame range"),
    O("source", "step", "int", default=1, low=1, high=1000, doc="Video takes: read every n-th frame",
      headless="the Movie Clip's frame range"),
    O("source", "scale", "float", default=1.0, above=0.0, high=1.0, doc="Video takes: downscale before the flow",
      headless="the Movie Clip's proxy settings"),
    O("source", "frame_offset", "int", default=0, low=-MAX_FRAME, high=MAX_FRAME,
      doc="Video takes: added to footage frame numbers",
      headless="the Movie Clip's start frame"),
    # -- [clean] -----------------------------------------------------------------------------------
    O("clean", "fix_swaps", "bool", default=False, doc="Detect and undo label swaps between neighbouring markers",
      ui="op:facecap.clean_markers.fix_swaps"),
    O("clean", "swap_ratio", "float", default=0.5, above=0.0, high=1.0,
      doc="A swap is taken when the swapped labels cost less than this times the kept ones",
      headless="an expert setting of the swap test"),
    O("clean", "spike_speed", "float", above=0.0, high=1e9,
      doc="Remove samples moving faster than this (units per second)",
      headless="the sidebar uses the robust spike test (spike_mad)"),
    O("clean", "spike_mad", "float", above=0.0, high=1e3,
      doc="Remove spikes beyond this many robust sigmas of acceleration",
      ui="op:facecap.clean_markers.spike_mad"),
    O("clean", "fill_spline", "int", default=0, low=0, high=100_000, doc="Longest gap (frames) filled by a spline",
      ui="op:facecap.clean_markers.fill_spline"),
    O("clean", "fill_model", "int", default=0, low=0, high=1_000_000,
      doc="Longest gap (frames) rebuilt from the other markers (low-rank model)",
      ui="op:facecap.clean_markers.fill_model"),
    O("clean", "model_rank", "int", low=1, high=200, doc="Components of the gap model (default: 99.5 % of variance)",
      headless="an expert setting of the gap model"),
    O("clean", "lowpass_hz", "float", above=0.0, high=MAX_FPS / 2,
      doc="Zero-phase Butterworth low-pass cutoff (Hz, below fps / 2)",
      ui="op:facecap.clean_markers.lowpass_hz"),
    O("clean", "lowpass_order", "int", default=4, low=1, high=12, doc="Butterworth filter order",
      headless="an expert setting of the low-pass filter"),
    O("clean", "one_euro", "floats", length=3, above=0.0, high=1e4,
      doc="One-Euro filter [min_cutoff_hz, beta, d_cutoff_hz] instead of the low-pass",
      headless="an alternative filter for live-style captures"),
    # -- [binding] ---------------------------------------------------------------------------------
    O("binding", "mode", "choice", default="vertex_groups", choices=("vertex_groups", "map", "nearest"),
      doc="How markers find their place on the character: vertex groups named after them, a `map` file, or "
          "the `nearest` surface point once the actor's neutral is aligned to the face (docs/binding.md)",
      ui="facecap.binding_mode"),
    O("binding", "vertex_groups", "bool",
      doc="Older configs: true is mode = \"vertex_groups\" (false needs a mode)",
      headless="kept for older configs; the sidebar sets the binding mode"),
    O("binding", "map", "path", doc="mode = \"map\": a marker,target CSV (target: vertex group, vertex index or x,y,z)",
      ui="facecap.binding_map"),
    O("binding", "landmarks", "table",
      doc="mode = \"nearest\": {marker = \"vertex group or index\"}, at least 3 pairs (absent: automatic alignment)",
      ui="facecap.binding_landmarks"),
    O("binding", "max_distance_mm", "float", default=8.0, above=0.0, high=1000.0,
      doc="map / nearest: markers farther than this (mm) from the surface stay unbound (head bands, strays)",
      ui="facecap.binding_max_distance"),
    # -- [stabilise] -------------------------------------------------------------------------------
    O("stabilise", "markers", ("names", "str"),
      doc="Markers that move only with the head, or \"auto\" to suggest them (required for marker takes)",
      ui="facecap.markers, facecap.auto_stable"),
    O("stabilise", "mode", "choice", default="rigid", choices=("rigid", "similarity"),
      doc="Per-frame head fit: rotation + translation, or also a uniform scale", ui="facecap.stabilise_mode"),
    O("stabilise", "fine_iterations", "int", default=2, low=0, high=10,
      doc="Hierarchical stabilisation: refits of the head on all markers against the solve",
      ui="facecap.fine_iterations"),
    O("stabilise", "fine_weight", "float", default=1.0, low=0.0, high=1e3,
      doc="Trust of deforming markers in the head refits, relative to stable ones",
      headless="an expert setting of the head refits"),
    O("stabilise", "head_smoothing", "float", default=0.1, low=0.0, high=2.0,
      doc="Half-window (s) of the zero-phase head-pose smoothing; 0 = off", ui="facecap.head_smoothing"),
    # -- [neutral] ---------------------------------------------------------------------------------
    O("neutral", "frames", ("frames", "list"), doc="Neutral / T-pose frames [first, last], or [[first, last], ...]",
      ui="facecap.neutral_first, facecap.neutral_last, facecap.neutral_end_first, facecap.neutral_end_last"),
    O("neutral", "file", "path", doc="A neutral captured in a separate file", ui="facecap.neutral_file"),
    O("neutral", "detect", "bool", default=False, doc="Detect the most neutral frames (the pose held longest)",
      ui="facecap.neutral_mode"),
    O("neutral", "master", "path", doc="The performer's master T-pose (offsets carried through the take)",
      ui="facecap.use_master, facecap.master_data, facecap.master_source"),
    O("neutral", "landmarks", "names", doc="Markers the master alignment uses (default: eye and mouth corners)",
      ui="facecap.landmarks"),
    # -- [align] -----------------------------------------------------------------------------------
    O("align", "regions", ("bool", "table"), default=False,
      doc="Actor->character alignment per region with separate scales (true: upper/lower face)",
      ui="facecap.align_regions"),
    O("align", "flag_mm", "float", above=0.0, high=1e4, doc="Alignment residual (mm) that flags a binding",
      headless="the default robust threshold suits the sidebar"),
    # -- [solve] -----------------------------------------------------------------------------------
    O("solve", "strategy", "choice", default="semantic", choices=STRATEGIES,
      doc="Cross-mapping strategy: semantic solves the actor's expressions from what is known of the actor's face "
          "([actor], [calibration]); geometric uses the character's shapes as the actor's (video takes: linear, rbf "
          "or pca)", ui="facecap.strategy, facecap.video.flow_strategy"),
    O("solve", "regularisation", "float", default=1e-3, low=0.0, high=100.0,
      doc="Ridge weight relative to the basis scale: larger keeps weights smaller and steadier",
      ui="facecap.regularisation"),
    O("solve", "sparsity", "float", default=1e-3, low=0.0, high=100.0,
      doc="L1 weight relative to the basis scale: pulls shapes that only explain noise to zero",
      ui="facecap.sparsity"),
    O("solve", "symmetry", "float", default=0.0, low=0.0, high=100.0,
      doc="Coupling of Left/Right shape pairs: a side with missing markers follows the other",
      ui="facecap.symmetry"),
    O("solve", "smoothing", "floats", default=(0.0, 0.3), length=2, low=0.0, high=1000.0,
      doc="Temporal weights [first difference, second difference]; [0, 0] solves frames independently",
      ui="facecap.smoothing_first, facecap.smoothing_second"),
    O("solve", "bounds", "table", doc="{shape pattern = [lower, upper]} overriding the slider ranges",
      ui="facecap.shapes"),
    O("solve", "locks", "table", doc="{shape pattern = value}: shapes held fixed (animator-owned)",
      ui="facecap.shapes"),
    O("solve", "regions", "table", doc="{name = {shapes = [...], markers = [...]}}: shapes solved from their markers",
      ui="facecap.regions"),
    O("solve", "unseen_shapes", "choice", default="rest", choices=("rest", "solve"),
      doc="semantic: shapes that move no marker by 1.5 mm (gaze on skin markers, tongue) are held at rest, or solved "
          "anyway", ui="facecap.unseen_shapes"),
    O("solve", "exclusive", "bool", default=True,
      doc="semantic: opposing shapes (jawLeft/jawRight, gaze in/out and up/down, blink/wide) are never both active",
      ui="facecap.exclusive"),
    O("solve", "projection", "choice", default="front", choices=("front", "camera"),
      doc="2D takes: the character seen from the front (orthographic) or through a camera",
      ui="facecap.video.projection"),
    O("solve", "camera", "str", max_bytes=MAX_NAME_BYTES,
      doc="2D takes: camera object for projection = \"camera\" (default: scene camera)",
      ui="facecap.video.camera"),
    # -- [output] ----------------------------------------------------------------------------------
    O("output", "blend", "path", doc="The .blend written with the solve layer", headless=OUTPUT_FILE),
    O("output", "weights", "path", doc="Weights CSV frame,<shape>,...", headless=OUTPUT_FILE),
    O("output", "report", "path", doc="JSON report (accuracy, warnings, timings)", headless=OUTPUT_FILE),
    O("output", "html", "path", doc="Review page: the solve's plots and renders, one HTML file (docs/review.md)",
      ui="op:facecap.export_review.filepath"),
    O("output", "actor_basis", "path", doc="The actor library used (refine: refined), as .npz", headless=OUTPUT_FILE),
    O("output", "profile", "path", doc="semantic: the performer profile this take's calibration measured (.npz), for "
      "[actor] profile of later takes; a landmark take's with [calibration] video: the blendshape scores' response",
      headless=OUTPUT_FILE),
    O("output", "gltf", "path",
      doc="Binary glTF (.glb) for game engines: the character with its shape keys as morph targets and the "
          "take's animation (solve and animator layers baked into one action, plus the head motion when keyed)",
      ui="op:facecap.export_take.filepath"),
    O("output", "fbx", "path", doc="FBX (.fbx) of the same: the character, its shape keys and the baked take",
      ui="op:facecap.export_take.filepath"),
    O("output", "action", "str", max_bytes=MAX_NAME_BYTES - 5, ui="facecap.take_name",
      doc="Name of the new action (default: the take file's name; room is kept for Blender's \" Head\")"),
    O("output", "head", "str", doc="Key the removed head motion on \"Object\" or \"Armature:bone\"",
      ui="facecap.head_target, facecap.head_bone"),
    # -- [actor] (semantic) ------------------------------------------------------------------------
    O("actor", "profile", "path", doc="semantic: this performer's stored profile (.npz, written by [output] profile "
      "from a take with calibration poses); landmark takes: its blendshape scores' response (a ROM on camera)",
      ui="facecap.actor_profile"),
    O("actor", "template", "str", default="auto",
      doc="semantic: a human face template fitted to the actor's neutral: \"auto\" (the one `python -m facecap "
          "template convert` installed, if any), \"none\", or a path", ui="facecap.actor_template"),
    O("actor", "normalise", "bool", default=True,
      doc="semantic, nothing known about the actor: scale the actor's motion per marker to the character's range",
      headless="an expert setting of the semantic solve"),
    # -- [calibration] (calibrated, refine; semantic: a ROM sequence or poses) --------------------------------------------------------
    O("calibration", "markers", "path", doc="The actor's calibration take",
      ui="facecap.calib_source, facecap.calib_path, facecap.calib_collection"),
    O("calibration", "units", "choice", choices=("m", "cm", "mm", "px"), doc="Units of the calibration take",
      ui="facecap.calib_units"),
    O("calibration", "fps", "float", above=0.0, high=MAX_FPS, doc="Frame rate of the calibration take",
      headless="taken from the imported calibration take"),
    O("calibration", "neutral", "frames", doc="The calibration take's neutral (default: [neutral] frames)",
      ui="facecap.calib_neutral_first, facecap.calib_neutral_last"),
    O("calibration", "poses", "table", doc="{pose = [first, last] or [[first, last], ...]}: held poses",
      ui="facecap.calib_poses, facecap.calib_pose_name"),
    O("calibration", "split", "names", doc="Poses split into <pose>Left / <pose>Right by marker side",
      ui="facecap.calib_poses"),
    O("calibration", "stable_markers", "names", doc="Stable markers of the calibration take (default: the take's)",
      headless="the sidebar uses the take's stable markers"),
    O("calibration", "sequence", ("str", "list"),
      doc="semantic: a range-of-motion session in the order performed, its holds found in [calibration] markers (or "
          "the take itself): a built-in sheet (\"facecap-24\", \"arkit-51\") or a list of ARKit names and tables of "
          "shape = weight (optional `label`); see docs/rom.md. A landmark take: the sheet of [calibration] video (or "
          "of the take itself), which calibrates the blendshape scores", ui="facecap.calib_sheet"),
    O("calibration", "video", "path",
      doc="Landmark takes: the performer's ROM filmed with this camera ([calibration] sequence: its sheet); its "
          "holds found in the blendshape scores calibrate each score's response (docs/video.md)",
      headless="the sidebar's video takes use [actor] profile (a profile written by a headless ROM run)"),
    O("calibration", "guide", "path", ui="facecap.calib_guide",
      doc="Landmark takes: the ARKit weights (a Live Link Face CSV, another weights file) of a guide the performer "
          "followed in [calibration] video (or the take): the clip joins the fusion map for them (docs/video.md)"),
    O("calibration", "guide_start", "float", low=1.0, high=MAX_FRAME, headless=GUIDE_HEADLESS,
      doc="The clip's frame number where the guide's first frame is performed (default: found)"),
    O("calibration", "guide_fps", "float", above=0.0, high=MAX_FPS, headless="the sidebar reads the file's rate",
      doc="The guide's frame rate (default: the file's; a CSV of frames without times is read at 60)"),
    O("calibration", "holds", "table", doc="{pose label = middle frame}: where the [calibration] sequence's poses are "
      "held, used instead of the holds found (a ROM on camera too: frame numbers of its clip)",
      headless="the sidebar's holds are the timeline markers `ROM: <label>` that Find Poses places"),
    O("calibration", "basis", "path", doc="A stored actor library (.npz) instead of markers + poses",
      headless="the sidebar keeps library versions in the .blend (Tuning panel)"),
    O("calibration", "align", "choice", default="rigid", choices=("rigid", "similarity", "none"),
      doc="How the take's neutral is brought onto the calibration neutral", ui="facecap.calib_align"),
    # -- [mapping] (calibrated, refine, parallel) --------------------------------------------------
    O("mapping", "aliases", "bool", default=True, doc="Match names through ARKit / MediaPipe / FACS alias tables",
      ui="facecap.mapping_aliases"),
    O("mapping", "keyed_by", "choice", default="source", choices=("source", "target"),
      doc="Whether [mapping] table is keyed by source channel or by character shape",
      headless="the sidebar's table has both columns"),
    O("mapping", "table", "table", doc="{source = {shape = gain}} (or keyed by target): many-to-many mapping",
      ui="facecap.mapping"),
    O("mapping", "gain", ("float", "table"), default=1.0, low=-1e3, high=1e3, doc="parallel: gain, or {shape = gain}",
      ui="facecap.parallel_gain"),
    O("mapping", "offset", ("float", "table"), default=0.0, low=-10.0, high=10.0,
      doc="parallel: offset, or {shape = offset}",
      ui="facecap.parallel_offset"),
    O("mapping", "clamp", ("floats", "table"), length=2, low=-10.0, high=10.0,
      doc="parallel: [lo, hi], or {shape = [lo, hi]}",
      headless="the Shapes panel's per-shape clamp does this in the sidebar"),
    O("mapping", "curve", ("str", "table"), default="linear",
      doc="parallel: \"linear\", \"smoothstep\", \"gamma:<g>\", or {shape = curve}",
      ui="facecap.parallel_curve, facecap.parallel_gamma"),
    O("mapping", "mirror", "bool", default=False, doc="parallel: swap Left/Right source channels",
      ui="facecap.parallel_mirror"),
    O("mapping", "neutral", "frames", doc="parallel: frames whose median is subtracted from the source",
      ui="facecap.parallel_use_neutral, facecap.parallel_neutral_first, facecap.parallel_neutral_last"),
    # -- [examples] (linear, rbf, pca) -------------------------------------------------------------
    O("examples", "weights", "path", doc="frame,<shape>,... character weights posed at frames of the take",
      ui="facecap.examples_action"),
    O("examples", "markers", "path", doc="The take the example frames belong to (default: this take)",
      headless="the sidebar's examples are frames of the imported take"),
    O("examples", "frames", "list", doc="Use only these posed frames (default: all)",
      headless="the sidebar uses every keyed frame of the Examples action"),
    O("examples", "ridge", "float", default=1e-3, low=0.0, high=1e6, doc="linear: ridge weight of the map",
      ui="facecap.ridge"),
    O("examples", "kernel", "choice", default="thin_plate_spline", choices=RBF_KERNELS, doc="rbf: kernel",
      ui="facecap.rbf_kernel"),
    O("examples", "rbf_smoothing", "float", default=0.0, low=0.0, high=1e6,
      doc="rbf: smoothing; 0 reproduces the examples exactly", ui="facecap.rbf_smoothing"),
    O("examples", "degree", "int", default=1, low=-1, high=2, doc="rbf: polynomial tail degree (-1 = none)",
      ui="facecap.rbf_degree"),
    O("examples", "n_components", "int", low=1, high=1000,
      doc="rbf / pca: principal components (default: the strategy's)",
      ui="facecap.n_components"),
    O("examples", "far", "float", default=2.0, above=0.0, high=1e6,
      doc="rbf: frames farther than this x the example spacing are reported as extrapolated", ui="facecap.rbf_far"),
    # -- [pca] -------------------------------------------------------------------------------------
    O("pca", "mode", "choice", default="related", choices=("related", "posed"),
      doc="Related-basis regression or posed basis frames (Chuang & Bregler)", ui="facecap.pca_mode"),
    O("pca", "ica", "bool", default=False, doc="Rotate the components to independent ones (FastICA)",
      ui="facecap.pca_ica"),
    O("pca", "n_basis", "int", default=8, low=1, high=1000,
      doc="Leading components whose extreme frames are basis frames",
      ui="facecap.pca_n_basis"),
    O("pca", "variance", "float", default=0.99, above=0.0, high=1.0, doc="Share of the variance kept",
      ui="facecap.pca_variance"),
    # -- [refine] ----------------------------------------------------------------------------------
    O("refine", "training", "path", doc="Take the library is refined on (default: this take)",
      headless="the sidebar refines on the imported take"),
    O("refine", "max_iterations", "int", default=10, low=0, high=100, doc="Choe & Ko iterations at most",
      ui="facecap.refine_max_iterations"),
    O("refine", "tol", "float", default=1e-3, low=0.0, high=1.0,
      doc="Stop when the fit error falls by less than this fraction", ui="facecap.refine_tol"),
    O("refine", "stiffness", "float", default=1e-2, low=0.0, high=1e6,
      doc="Pull towards the original library (larger = smaller corrections)", ui="facecap.refine_stiffness"),
    # -- [tracking] and [flow] (video takes) -------------------------------------------------------
    O("tracking", "method", "choice", default="dis", choices=("dis", "farneback", "tvl1", "landmarks"),
      doc="Dense optical flow method, or \"landmarks\": the face's landmarks solved like markers (no examples)",
      ui="facecap.video.flow_method", hint="a video take follows dense flow or face landmarks"),
    O("tracking", "smoothing", "bool", default=True,
      doc="Landmarks: filter the detector's jitter out of the landmarks and the fused weights (zero lag)",
      ui="facecap.video.landmark_smoothing"),
    O("tracking", "iris", "bool", default=True, doc="Landmarks: eyelids and gaze from the iris model",
      headless="the sidebar always refines the eyes"),
    O("tracking", "models", "path", doc="Landmarks: folder of the face-mesh model files (default: found)",
      headless="the extension bundles the models"),
    O("tracking", "bundle", "path", doc="Landmarks: the Face Landmarker bundle (default: installed by `landmark-models "
      "fetch`, else the older models)", headless="the sidebar uses the installed bundle"),
    O("tracking", "blendshapes", "choice", default="fuse", choices=("fuse", "ignore"),
      doc="Landmarks: combine the Face Landmarker's blendshape scores with the solve (the fusion map; docs/video.md)",
      headless="the sidebar always combines them"),
    O("tracking", "region", "floats", length=4, low=0.0, high=1e6,
      doc="Face region [x, y, w, h] in pixels (default: the frame)",
      ui="facecap.video.region"),
    O("tracking", "reference", "int", high=MAX_FRAME, doc="The neutral reference frame (default: the first frame read)",
      headless="the sidebar uses the current frame"),
    O("tracking", "stable_region", "list", doc="[x, y, w, h] or [[x, y, w, h], ...] that move with the head only",
      ui="facecap.video.stable_region"),
    O("tracking", "grid_step", "int", low=1, high=256, doc="Flow sample spacing in pixels (default: ~4,000 samples)",
      ui="facecap.video.flow_grid_step"),
    O("tracking", "drift", "choice", default="fuse", choices=("fuse", "direct", "none"),
      doc="How flow drift is controlled against the reference", headless="an expert setting of the flow"),
    O("tracking", "preset", "choice", default="balanced", choices=("ultrafast", "fast", "balanced", "medium"),
      doc="DIS quality preset", headless="an expert setting of the flow"),
    O("flow", "components", "int", default=12, low=1, high=200, doc="Flow-PCA components per frame",
      ui="facecap.video.flow_components"),
    O("flow", "variance", "float", above=0.0, high=1.0, doc="Keep the fewest components explaining this share instead",
      headless="the sidebar sets the component count"),
    # -- [rig] (a rig's controls as the target) ----------------------------------------------------
    O("rig", "preset", "choice", choices=("rigify_face", "arkit_sliders", "shape_keys"),
      doc="Solve a rig's controls instead of the shape keys: a Rigify face, a control object whose ARKit-named "
          "sliders drive the face, or the undriven shape keys (correctives fire through their drivers)",
      ui="facecap.rig_preset"),
    O("rig", "object", "str", doc="The rig: the Rigify armature or the sliders' control object (presets)",
      ui="facecap.rig_object"),
    O("rig", "controls", "list",
      doc="Controls named one by one: [{object, path, axes, lower, upper}], path 'pose.bones[\"b\"].location' "
          "or '.rotation', '[\"property\"]' or 'key_blocks[\"shape\"].value' (added to the preset's)",
      headless="the sidebar solves a preset's controls"),
    O("rig", "method", "choice", default="probed", choices=("probed", "poses"),
      doc="How the solver sees the rig: probed (evaluated around rest, a model with its pairwise terms) or a "
          "pose library (one control pose per shape)", ui="facecap.rig_method"),
    O("rig", "poses", "str", doc="method = \"poses\": the action holding one pose per frame, named by its pose "
      "markers (ARKit / FACS names)", ui="facecap.rig_poses"),
    O("rig", "nonlinear", "bool", default=True,
      doc="Solve the rig's curvature and combination terms after the linear solve (bounded Gauss-Newton)",
      ui="facecap.rig_nonlinear"),
    O("rig", "refine", "bool", default=True,
      doc="Refine the frames where the real rig differs from its model, through the rig itself",
      ui="facecap.rig_refine"),
    O("rig", "probes", "int", default=600, low=0, high=100_000,
      doc="Random poses probed besides the single-control and pairwise probes", ui="facecap.rig_probes"),
    # -- [tuning] and [controls] ------------------------------------------------------------------
    O("tuning", "corrections", "path", doc="frame,<shape>,... corrected weights (the `tune` command)",
      ui="facecap.tuning_frames"),
    O("tuning", "mu", "float", above=0.0, high=1e12,
      doc="Prior of the correction (absent: chosen automatically; inf = gains only)",
      ui="facecap.tune_auto_mu, facecap.tune_mu"),
    O("tuning", "library", "path", doc="A stored library version to solve with",
      ui="facecap.library_active, facecap.library_versions"),
    O("tuning", "out", "path", doc="Where new versions go (default: beside the [output] files)",
      headless="the sidebar stores versions in the .blend"),
    O("controls", "preset", "path", doc="Per-shape controls preset (.json); table entries win",
      ui="op:facecap.controls_load.filepath"),
    O("controls", "<shape>", "table",
      doc="{gain, offset, clamp = [lo, hi], curve, smoothing, mute, lock} for a shape name or glob",
      ui="facecap.shapes"),
)

BY_NAME = {o.name: o for o in OPTIONS}
SECTIONS = tuple(dict.fromkeys(o.section for o in OPTIONS))

def option(name):
    """The ``Option`` called ``name`` ("section.key")."""
    return BY_NAME[name]


def default(name):
    """The default value of option ``name`` (a tuple for list defaults)."""
    return BY_NAME[name].default
