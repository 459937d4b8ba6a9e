"""The names a take config gives, checked against what exists, as early as each can be known: input files first
of all (``headless.preflight``); marker names once the take is read (before Blender opens the character); objects, bones
and shape keys as soon as the character is open (before anything is solved). Every problem names the config
file and its key, with a "did you mean" for a near miss, and all of one stage's problems come at once.
"""

from fnmatch import fnmatchcase
from pathlib import Path

from ..character.shape_controls import resolve_controls
from ..errors import ConfigError, FacecapError, Problems, suggest


def input_files(config):
    """{config key: absolute path} of every input file a TakeConfig names ([source] video may be a glob or an
    image pattern and [tracking] models a folder: their own readers check them)."""
    s, tuning = config.settings, config.tuning
    named = {
        "target.blend": config.target_blend, "source.markers": config.markers_path,
        "source.weights": config.weights_path, "binding.map": config.binding_map_path,
        "neutral.file": s.neutral_file, "neutral.master": s.master, "actor.profile": config.actor_profile_path,
        "calibration.markers": config.calibration_path, "calibration.basis": config.actor_basis_path,
        "examples.weights": config.examples_weights_path, "examples.markers": config.examples_markers_path,
        "refine.training": config.training_path, "controls.preset": config.controls_preset,
        "tuning.corrections": getattr(tuning, "corrections", None), "tuning.library": getattr(tuning, "library", None),
    }
    return {key: Path(value) for key, value in named.items() if isinstance(value, (str, Path))}


def missing_file(config_path, key, path):
    """A ConfigError for ``[key]``'s file ``path`` when it does not exist (None when it does), suggesting the
    closest file name in its folder."""
    path = Path(path)
    if path.exists():
        return None
    folder = path.parent
    if folder.is_dir():
        try:
            hint = suggest(path.name, sorted(p.name for p in folder.iterdir() if p.is_file()))
        except OSError:
            hint = ""
    else:
        hint = f" (no folder {folder})"
    return ConfigError(f"{path}: file not found{hint}", path=config_path, key=key)


def check_input_files(config):
    """ConfigError(s) for every input file ``config`` (a TakeConfig) names that is not there, all at once: the
    first check of a run, before anything is read or Blender starts."""
    problems = Problems()
    for key, path in input_files(config).items():
        error = missing_file(config.path, key, path)
        if error is not None:
            problems.add(error)
    problems.raise_any()


def _unknown_names(names, markers, what):
    """"no marker 'x' (did you mean 'y'?), 'z' in take.csv (...)" for each of ``names`` not in ``markers``
    (a MarkerSet), or ''."""
    present = set(markers.names)
    unknown = [n for n in names if n not in present]
    if not unknown:
        return ""
    listed = ", ".join(f"'{n}'{suggest(n, markers.names)}" for n in unknown)
    source = markers.source or "the take"
    return (f"no {what} {listed} in {Path(source).name} ({len(present)} {what}s; "
            f"`python -m facecap inspect {source}` lists them)")


def _patterns_matching_nothing(patterns, names, what):
    """"'x' matches no <what> (did you mean 'y'?)" for each pattern that matches none of ``names``, or ''."""
    return "; ".join(f"'{p}' matches no {what}{suggest(p, names)}" for p in patterns
                     if not any(fnmatchcase(n, p) for n in names))


def check_take_names(config, markers=None, calibration=None):
    """ConfigError(s) for marker names of ``config`` that the take (``markers``, a MarkerSet) or the calibration
    take does not have: [stabilise] markers, [calibration] stable_markers, [neutral] landmarks, the markers of
    [solve] regions. Landmark and region entries are patterns: one that matches nothing is the error."""
    s, problems = config.settings, Problems()

    def add(key, message):
        if message:
            problems.add(ConfigError(message, path=config.path, key=key))

    if markers is not None:
        add("stabilise.markers", _unknown_names(s.stable_markers, markers, "marker"))
        if s.landmarks:
            add("neutral.landmarks", _patterns_matching_nothing(s.landmarks, markers.names, "marker of the take"))
        for region in s.regions:
            add(f"solve.regions.{region.name}",
                _patterns_matching_nothing(region.markers, markers.names, "marker of the take"))
    cal_markers = s.calibration.stable_markers
    if calibration is not None and cal_markers:
        add("calibration.stable_markers", _unknown_names(cal_markers, calibration, "marker"))
    problems.raise_any()


def check_scene_names(config, objects, shapes=None, bones_of=None, where="the .blend"):
    """ConfigError(s) for the objects, bones and shape keys ``config`` names that the open .blend lacks.

    objects : dict of str -> str
        Every object's name -> its type (``MESH``, ``ARMATURE``, ``CAMERA``...).
    shapes : sequence of str, optional
        The target object's shape keys (not its reference key); None when it has none or a rig is the target.
    bones_of : callable, optional
        Armature object name -> its bone names.
    """
    problems = Problems()

    def add(key, message):
        problems.add(ConfigError(message, path=config.path, key=key))

    name = config.target_object
    if name not in objects:
        meshes = sorted(n for n, kind in objects.items() if kind == "MESH")
        add("target.object", f"no object named '{name}' in {where}{suggest(name, list(objects))}"
                             + (f"; its meshes: {', '.join(meshes[:12])}" if meshes else "; it has no mesh"))
    head = config.settings.head_target
    if head:
        obj_name, _, bone = head.partition(":")
        if obj_name not in objects:
            add("output.head", f"no object named '{obj_name}' in {where}{suggest(obj_name, list(objects))}")
        elif bone and bones_of is not None:
            bones = list(bones_of(obj_name))
            if bone not in bones:
                add("output.head", f"'{obj_name}' has no bone '{bone}'{suggest(bone, bones)}")
    camera = config.camera_name
    if camera and objects.get(camera) != "CAMERA":
        cameras = [n for n, kind in objects.items() if kind == "CAMERA"]
        add("solve.camera", f"no camera named '{camera}' in {where}{suggest(camera, cameras)}")
    if shapes is not None and config.rig is None:
        _check_shapes(config, list(shapes), add)
    problems.raise_any()


def _check_shapes(config, shapes, add):
    s = config.settings
    for key, entries in (("solve.locks", s.locks), ("solve.bounds", s.bounds)):
        for pattern, *_ in entries:
            message = _patterns_matching_nothing([pattern], shapes, "shape key of the character")
            if message:
                add(f"{key}.{pattern}", message)
    for region in s.regions:
        message = _patterns_matching_nothing(region.shapes, shapes, "shape key of the character")
        if message:
            add(f"solve.regions.{region.name}", message)
    for key, control in (config.controls or {}).items():
        try:
            resolve_controls(shapes, {key: control})
        except FacecapError:  # the key matches no shape (exact names alias-insensitively, or as a glob)
            add(f"controls.{key}", f"'{key}' matches no shape key of the character{suggest(key, shapes)}")
