"""The strategy sections of a take config: [actor] [calibration] [mapping] [examples] [pca] [refine].

``strategy_settings`` validates them (errors name ``[section.key]``) into the frozen settings of
``solvers.strategies.options``; ``load_strategy_inputs`` reads the files they name (calibration
take, stored actor basis, posed example weights, training take, solved weights) into
``StrategyInputs``. Defaults are those of the settings dataclasses.
"""

import warnings

import numpy as np

from ..capture.cleaning import clean
from ..character.basis import Basis
from ..character.template import HumanTemplate, template_path
from ..errors import ConfigError, FacecapError, InputFileError
from ..io import import_markers
from ..io.csv import read_weights_csv
from ..io.weights import read_weights
from ..strategies.options import (
    ActorSettings,
    CalibrationSettings,
    ExamplePairs,
    ExampleSettings,
    MappingSettings,
    PCASettings,
    RefineSettings,
    StrategyInputs,
)
from ..rom.sheets import sequence_poses
from ..strategies.parallel import parallel_curve
from ..strategies.wiring import NEEDS
from ..video.response import profile_contents

ALIGN = ("rigid", "similarity", "none")
KERNELS = ("thin_plate_spline", "cubic", "quintic", "linear", "gaussian", "multiquadric",
           "inverse_multiquadric", "inverse_quadratic")  # as strategies.rbf.KERNELS (scipy stays unimported here)
PCA_MODES = ("related", "posed")


def _number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool)


#: Largest gain and offset magnitudes of [mapping] (as the option table's bounds: typos beyond them)
MAX_GAIN, MAX_OFFSET = 1e3, 10.0


def _bounded(limit):
    return lambda v: _number(v) and np.isfinite(v) and abs(v) <= limit


def _frame_pair(value):
    return isinstance(value, list) and len(value) == 2 and all(isinstance(v, int) and not isinstance(v, bool)
                                                               for v in value) and value[0] <= value[1]


def strategy_settings(path, data, strategy):
    """``{calibration, mapping, examples, pca, refine}`` settings for RetargetSettings."""
    cal = data.get("calibration", {})
    ex = data.get("examples", {})

    def fail(key, message):
        raise ConfigError(message, path=path, key=key)

    if strategy in ("calibrated", "refine"):
        has_take = "markers" in cal and "poses" in cal
        if "basis" in cal and ("markers" in cal or "poses" in cal):
            fail("calibration.basis", "give either a stored basis or calibration markers + poses, not both")
        if not has_take and "basis" not in cal:
            fail("calibration.markers" if "markers" not in cal else "calibration.poses",
                 f"strategy '{strategy}' needs {NEEDS[strategy]}")
    if strategy in ("linear", "rbf", "pca") and "weights" not in ex:
        fail("examples.weights", f"strategy '{strategy}' needs {NEEDS[strategy]}")
    if strategy == "semantic" and "basis" in cal and ("markers" in cal or "poses" in cal or "sequence" in cal):
        fail("calibration.basis", "give either a stored basis or calibration markers + poses, not both")
    if "sequence" in cal and strategy != "semantic":
        fail("calibration.sequence", f"a ROM sequence calibrates the semantic strategy; [solve] strategy is '{strategy}'")
    return {
        "actor": _actor(data.get("actor", {}), data.get("solve", {}), fail),
        "calibration": _calibration(cal, fail),
        "mapping": _mapping(data.get("mapping", {}), fail),
        "examples": _examples(ex, fail),
        "pca": _pca(data.get("pca", {}), fail),
        "refine": _refine(data.get("refine", {}), fail),
    }


def _actor(actor, solve, fail):
    """[actor] template / normalise and the semantic solve's [solve] unseen_shapes / exclusive."""
    d = ActorSettings()
    template = actor.get("template", d.template)
    if not isinstance(template, str) or not template.strip():
        fail("actor.template", f'expected "auto", "none" or a path to a template; got {template!r}')
    for section, table, key in (("actor", actor, "normalise"), ("solve", solve, "exclusive")):
        if key in table and not isinstance(table[key], bool):
            fail(f"{section}.{key}", f"expected true or false; got {table[key]!r}")
    unseen = solve.get("unseen_shapes", d.unseen_shapes)
    if unseen not in ("rest", "solve"):
        fail("solve.unseen_shapes", f'expected "rest" or "solve"; got {unseen!r}')
    return ActorSettings(template=template, normalise=actor.get("normalise", d.normalise), unseen_shapes=unseen,
                         exclusive=solve.get("exclusive", d.exclusive))


def _calibration(cal, fail):
    poses = []
    for name, spec in cal.get("poses", {}).items():
        ranges = [spec] if _frame_pair(spec) else spec
        if not (isinstance(ranges, list) and ranges and all(_frame_pair(r) for r in ranges)):
            fail(f"calibration.poses.{name}", f"expected [first, last] or [[first, last], ...] with first <= last; got {spec}")
        poses.append((name, tuple(tuple(r) for r in ranges)))
    split = cal.get("split", [])
    if not all(isinstance(s, str) for s in split):
        fail("calibration.split", "expected a list of pose names")
    unknown = [s for s in split if s not in dict(poses)]
    if unknown and poses:
        fail("calibration.split", f"names pose(s) not in [calibration] poses: {unknown}")
    neutral = cal.get("neutral")
    if neutral is not None and not _frame_pair(neutral):
        fail("calibration.neutral", f"expected [first, last] frame numbers; got {neutral}")
    stable = cal.get("stable_markers", [])
    if stable and (len(stable) < 3 or not all(isinstance(s, str) for s in stable)):
        fail("calibration.stable_markers", "expected a list of at least 3 marker names")
    align = cal.get("align", "rigid")
    if align not in ALIGN:
        fail("calibration.align", f"expected one of {ALIGN}; got '{align}'")
    sequence, holds = _sequence(cal, fail)
    return CalibrationSettings(poses=tuple(poses), neutral_frames=None if neutral is None else tuple(neutral),
                               split=tuple(split), stable_markers=tuple(stable), align=align, sequence=sequence,
                               holds=holds)


def _sequence(cal, fail):
    """[calibration] sequence (a ROM sheet's name or its poses) and holds ({label = middle frame})."""
    if "sequence" not in cal:
        if "holds" in cal:
            fail("calibration.holds", "holds place the poses of a [calibration] sequence; give the sequence")
        return (), None
    if "poses" in cal:
        fail("calibration.sequence", "give either a ROM sequence (its holds are found) or poses with frame ranges, "
                                     "not both")
    try:
        poses = sequence_poses(cal["sequence"], where="")
    except FacecapError as exc:  # the key is said by fail(): the message keeps the item
        fail("calibration.sequence", str(exc).lstrip(": "))
    holds = cal.get("holds")
    return poses, None if holds is None else check_holds(holds, poses, fail)


def check_holds(holds, poses, fail):
    """``[calibration] holds`` ({pose label = middle frame}) checked against the sequence's ``poses``:
    ((label, frame), ...); ``fail(key, message)`` raises."""
    labels = {p.label for p in poses}
    if not isinstance(holds, dict) or not holds:
        fail("calibration.holds", 'expected a table of pose label = middle frame, e.g. { "jaw open" = 212 }')
    for label, frame in holds.items():
        if label not in labels:
            fail("calibration.holds", f"'{label}' is not a pose of the sequence; its poses: {sorted(labels)}")
        if not _number(frame) or not np.isfinite(frame):
            fail("calibration.holds", f"the middle frame of '{label}' must be a number; got {frame!r}")
    return tuple((label, float(frame)) for label, frame in holds.items())


def _table(table, keyed_by, fail):
    rows = []
    for outer, entry in table.items():
        key = f"mapping.table.{outer}"
        if isinstance(entry, str):
            entry = {entry: 1.0}
        elif isinstance(entry, list) and all(isinstance(e, str) for e in entry):
            entry = {e: 1.0 for e in entry}
        if not isinstance(entry, dict) or not entry:
            fail(key, "expected a name, a list of names or { name = gain, ... }")
        for inner, gain in entry.items():
            if not _bounded(MAX_GAIN)(gain):
                fail(key, f"gain for '{inner}' must be a number between -{MAX_GAIN:g} and {MAX_GAIN:g}; got {gain!r}")
            source, target = (outer, inner) if keyed_by == "source" else (inner, outer)
            rows.append((source, target, float(gain)))
    return tuple(rows)


def _per_shape(value, key, fail, check):
    """A scalar, or a {shape: value} table -> ((shape, value), ...)."""
    if isinstance(value, dict):
        for shape, v in value.items():
            if not check(v):
                fail(f"{key}.{shape}", f"invalid value {v!r}")
        return tuple((shape, tuple(v) if isinstance(v, list) else v) for shape, v in value.items())
    if not check(value):
        fail(key, f"invalid value {value!r}")
    return tuple(value) if isinstance(value, list) else value


def _curve_ok(spec):
    try:
        parallel_curve(spec)
    except FacecapError:
        return False
    return True


def _mapping(m, fail):
    keyed_by = m.get("keyed_by", "source")
    if keyed_by not in ("source", "target"):
        fail("mapping.keyed_by", f"expected 'source' or 'target'; got '{keyed_by}'")
    neutral = m.get("neutral")
    if neutral is not None and not _frame_pair(neutral):
        fail("mapping.neutral", f"expected [first, last] frame numbers of the source weights; got {neutral}")
    clamp = m.get("clamp")
    clamp_ok = lambda v: (isinstance(v, list) and len(v) == 2 and all(_bounded(MAX_OFFSET)(x) for x in v)  # noqa: E731
                          and v[0] <= v[1])
    return MappingSettings(
        table=_table(m.get("table", {}), keyed_by, fail),
        keyed_by=keyed_by,
        aliases=m.get("aliases", True),
        gain=_per_shape(m.get("gain", 1.0), "mapping.gain", fail, _bounded(MAX_GAIN)),
        offset=_per_shape(m.get("offset", 0.0), "mapping.offset", fail, _bounded(MAX_OFFSET)),
        clamp=None if clamp is None else _per_shape(clamp, "mapping.clamp", fail, clamp_ok),
        curve=_per_shape(m.get("curve", "linear"), "mapping.curve", fail, _curve_ok),
        mirror=m.get("mirror", False),
        neutral_frames=None if neutral is None else tuple(neutral),
    )


def _examples(ex, fail):
    d = ExampleSettings()
    frames = ex.get("frames", [])
    if not all(_number(f) for f in frames):
        fail("examples.frames", "expected a list of frame numbers")
    for key in ("ridge", "rbf_smoothing"):
        if ex.get(key, 0) < 0:
            fail(f"examples.{key}", f"must be >= 0; got {ex[key]}")
    if ex.get("far", 1) <= 0:
        fail("examples.far", f"must be > 0; got {ex['far']}")
    kernel = ex.get("kernel", d.kernel)
    if kernel not in KERNELS:
        fail("examples.kernel", f"unknown kernel '{kernel}'; available: {', '.join(KERNELS)}")
    degree = ex.get("degree", d.degree)
    if degree not in (-1, 0, 1, 2):
        fail("examples.degree", f"must be -1 (none), 0, 1 or 2; got {degree}")
    n_components = ex.get("n_components")
    if n_components is not None and n_components < 1:
        fail("examples.n_components", f"must be >= 1; got {n_components}")
    return ExampleSettings(frames=tuple(float(f) for f in frames), ridge=float(ex.get("ridge", d.ridge)), kernel=kernel,
                           rbf_smoothing=float(ex.get("rbf_smoothing", d.rbf_smoothing)), degree=degree,
                           n_components=n_components, far=float(ex.get("far", d.far)))


def _pca(p, fail):
    d = PCASettings()
    mode = p.get("mode", d.mode)
    if mode not in PCA_MODES:
        fail("pca.mode", f"expected one of {PCA_MODES}; got '{mode}'")
    if p.get("n_basis", 1) < 1:
        fail("pca.n_basis", f"must be >= 1; got {p['n_basis']}")
    variance = p.get("variance", d.variance)
    if not 0 < variance <= 1:
        fail("pca.variance", f"must be in (0, 1]; got {variance}")
    return PCASettings(mode=mode, ica=p.get("ica", d.ica), n_basis=p.get("n_basis", d.n_basis), variance=float(variance))


def _refine(r, fail):
    d = RefineSettings()
    for key in ("max_iterations", "tol", "stiffness"):
        if r.get(key, 0) < 0:
            fail(f"refine.{key}", f"must be >= 0; got {r[key]}")
    return RefineSettings(max_iterations=r.get("max_iterations", d.max_iterations), tol=float(r.get("tol", d.tol)),
                          stiffness=float(r.get("stiffness", d.stiffness)))


def load_strategy_inputs(config, *, read_markers=None):
    """Read the files a take config's strategy needs into ``StrategyInputs``.

    Parameters
    ----------
    config : TakeConfig
    read_markers : callable(path, units, fps) -> MarkerSet, optional
        How extra marker takes (calibration, example take, training take) are read; default
        ``readers.import_markers`` with the [source] read options and the [clean] steps.
    """


    notes = []
    if read_markers is None:
        options = {k: v for k, v in config.read_options.items() if k != "format"}

        def read_markers(path, units, fps):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                imported = import_markers(path, units=units, fps=fps, **options)
            notes.extend(f"{path.name}: {w.message}" for w in caught)
            return clean(imported.markers, config.clean).markers

    def need(path, what):
        if not path.is_file():
            raise InputFileError(path, f"file not found (config {what})")
        return path

    strategy = config.settings.strategy
    inputs = {}
    if strategy in ("calibrated", "refine"):
        if config.actor_basis_path is not None:
            try:
                inputs["actor_basis"] = Basis.load_npz(need(config.actor_basis_path, "[calibration] basis"))
            except (OSError, KeyError, ValueError) as exc:
                raise InputFileError(config.actor_basis_path, f"not a stored basis (Basis.save_npz): {exc}") from None
        else:
            path = need(config.calibration_path, "[calibration] markers")
            inputs["calibration"] = read_markers(path, config.calibration_units or config.units,
                                                 config.calibration_fps or config.fps)
        if strategy == "refine" and config.training_path is not None:
            inputs["training"] = read_markers(need(config.training_path, "[refine] training"), config.units, config.fps)
    if strategy == "semantic":
        inputs.update(_semantic_inputs(config, need, read_markers, notes))
    if strategy in ("linear", "rbf", "pca"):
        frames, names, values = read_weights_csv(need(config.examples_weights_path, "[examples] weights"))
        markers = None
        if config.examples_markers_path is not None:
            markers = read_markers(need(config.examples_markers_path, "[examples] markers"), config.units, config.fps)
        inputs["examples"] = ExamplePairs(np.asarray(frames, dtype=np.float64), values, tuple(names), markers)
    if strategy == "parallel":
        track = read_weights(need(config.weights_path, "[source] weights"), fps=config.fps)
        notes.extend(f"{config.weights_path.name}: {n}" for n in track.notes)
        inputs["weights"] = track
    return StrategyInputs(**inputs, notes=tuple(notes))


def _semantic_inputs(config, need, read_markers, notes):
    """What the semantic solve knows of the actor: a calibration take ([calibration] markers; poses labelled in
    the take itself need no file), a stored library or performer profile, the human template."""
    out = {}
    if config.calibration_path is not None:
        out["calibration"] = read_markers(need(config.calibration_path, "[calibration] markers"),
                                          config.calibration_units or config.units, config.calibration_fps or config.fps)
    for path, key in ((config.actor_basis_path, "actor_basis"), (config.actor_profile_path, "profile")):
        if path is not None:
            name = f"[{'calibration] basis' if key == 'actor_basis' else 'actor] profile'}"
            if key == "profile" and not profile_contents(need(path, name))[0]:
                notes.append(f"[actor] profile {path.name} holds the blendshape scores' response of a ROM on camera "
                             "and no measured shapes: the semantic solve knows this actor from the template or the "
                             "character")
                continue
            out[key] = Basis.load_npz(need(path, name))
    template = config.settings.actor.template
    if template != "none":
        path = template_path() if template == "auto" else config.path.parent / template
        if template == "auto" and not path.is_file():
            return out
        out["template"] = HumanTemplate.load(need(path, "[actor] template") if template != "auto" else path)
        notes.append(f"the human template: {path}")
    return out
