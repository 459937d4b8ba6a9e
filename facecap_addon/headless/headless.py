"""The one headless path: a take config -> open the character -> ``solvers.solve`` -> key -> write.

``retarget``, ``tune`` and a ``[source] video`` take all run ``run_take``; what differs is only what
the ``SolveRequest`` carries (corrections to retune from, footage instead of markers). Expected
failures raise ``FacecapError`` with one line naming the file and key; the CLI turns them into
exit status 1.
"""

import contextlib
import dataclasses
import time
import warnings
from pathlib import Path

import numpy as np

from ...solvers.capture.cleaning import clean
from ...solvers.character.binding_map import BindingSettings
from ...solvers.config.checks import check_against_take
from ...solvers.config.names import check_input_files, check_scene_names, check_take_names
from ...solvers.config.paths import check_outputs, expected_sizes, take_outputs
from ...solvers.config.strategies import load_strategy_inputs
from ...solvers.engine.split import LONG_TAKE_FRAMES, release_freed_memory, run_beside
from ...solvers.errors import ConfigError, InputFileError
from ...solvers.io import import_markers
from ...solvers.io.csv import write_weights_csv
from ...solvers.io.files import remove_stale_temporaries, write_json_atomic
from ...solvers.io.locks import output_lock
from ...solvers.io.outputs import check_free_space
from ...solvers.markers import UNIT_SCALE
from ...solvers.pipeline import SAMPLES_CHARACTER
from ...solvers.solve import SolveRequest, solve_job
from ...solvers.tuning.store import load_version
from ...solvers.video.cli import run_showing_progress, showing_progress
from ...solvers.video.flow_config import LandmarkTake, check_against_footage
from ...solvers.video.reading import Cancelled, Footage
from . import console
from .actor_outputs import store_retune, versions_folder, write_actor_basis, write_profile
from .blend_files import (names_in_file, open_blend, remove_earlier_solve, save_blend_atomic, stamp_target,
                          start_blender, target_changed)
from .landmark_take import follow_clip, landmark_request, performer_of, read_landmarks, score_response
from ..render.review import read_review_truth, write_take_review
from .take_request import corrections_for, rig_request, shape_names, source_fields, with_driven_keys

#: Take files larger than this are read in a forked child while Blender starts (smaller ones are
#: read in less time than the fork costs).
PARALLEL_READ_BYTES = 4 << 20
#: The take report's schema version (its first key, ``"facecap_report"``, also marks it as facecap's own)
REPORT_SCHEMA = 1
#: Weights (frames x shapes) above which the weights CSV is written in a forked child.
PARALLEL_WRITE_VALUES = 200_000


def progress_line(message):
    """The command line's ``say``: a progress line, or (``warning: ...``) a warning, through logging."""
    if message.startswith("warning: "):
        console.log.warning(message.removeprefix("warning: "))
    else:
        console.log.info(message)


def run_take(config, *, quiet=False, tune=False, replace=False, overwrite=False, say=None, characters=None,
             review=None):
    """Solve a take config end to end and write its outputs; returns (RetargetResult, outputs dict).

    ``[tuning] library`` and ``[controls]`` are honoured; with ``tune``, ``[tuning] corrections``
    are retuned from and the new library version stored (``[tuning] out``). An existing output
    .blend is added to (everything in it kept, the new solve the active layer) unless ``replace``:
    then the run starts from ``[target] blend``; a run adding to it holds its lock from reading it to
    writing it back (``solvers.io.locks``: a second run waits). Nothing is read or solved before every
    output path is checked (``preflight``; ``overwrite`` lets outputs replace files facecap did not
    write). ``say``: where progress and warning lines go (default: stderr unless ``quiet``);
    ``characters``: a cache of sampled characters kept across takes (a batch worker's ``CharacterCache``).
    On takes of ``LONG_TAKE_FRAMES`` or more the returned result's stabilised markers are released
    before keying (its head poses stay), unless the review page is written.
    ``[output] html`` writes the review page last (``review``: its ``facecap_addon.render.review.ReviewOptions``;
    ``config.truth_path`` the known weights it overlays).
    """
    say = say or ((lambda _m: None) if quiet else progress_line)
    t0 = time.perf_counter()
    preflight(config, tune=tune, replace=replace, overwrite=overwrite)  # before waiting for a lock
    truth = read_review_truth(config)  # a bad --truth file fails before the solve
    lock = output_lock(config.output_blend, say=say) if config.output_blend is not None else contextlib.nullcontext()
    with lock:
        base = choose_base(config, replace=replace)  # under the lock: the file as the last writer left it
        return _run_locked(config, base, say=say, t0=t0, truth=truth, quiet=quiet, tune=tune, characters=characters,
                           review=review)


def _run_locked(config, base, *, say, t0, truth, quiet, tune, characters, review):
    timings = {}
    take, obj, timings["read"], t_open = _read_and_open(config, say, base, quiet=quiet)
    said = len(take.notes)  # said by _read_and_open
    config, driven = with_driven_keys(config, obj, take)
    take.notes = tuple(take.notes) + driven
    changed = target_changed(config.target_blend) if base.mode == "added" else None
    if changed:
        take.notes = tuple(take.notes) + (changed,)
    t1 = time.perf_counter()
    request, source_info = _request(config, obj, take, tune=tune, characters=characters, base=base, quiet=quiet)
    timings["load_character"] = time.perf_counter() - t1 + t_open
    columns = request.rig.control_names if request.rig is not None else shape_names(request.character)
    base_size = base.path.stat().st_size if base.path is not None and base.path.is_file() else 0
    check_free_space(expected_sizes(config, take.n_frames(), len(columns), base_size), config=config.path)
    say(f"[3/5] solving {take.describe()} x {len(columns)} {'controls' if request.rig is not None else 'shapes'} "
        f"(strategy: {request.settings.strategy})")
    result = _run(request, quiet=quiet)
    if take.repeats:
        result = dataclasses.replace(result, warnings=tuple(_once(result.warnings, take.repeats)))
    outputs, extra = {}, {}
    if request.version is not None:
        extra["library"] = {"file": str(config.tuning.library), "version": request.version.name,
                            "parent": request.version.parent}
    if tune:
        extra["tuning"] = store_retune(config, result.retune)
    if take.footage is not None:
        extra["flow"] = result.info["flow"]
    if config.output_actor_basis is not None:
        write_actor_basis(config, result, outputs)
    if config.output_profile is not None:
        measured = config.video_rom is not None  # a ROM on camera or a guide followed, not a profile read back
        write_profile(config, result, outputs, response=take.response if measured else None,
                      performer=take.performer if measured else None)
    rom = result.info.get("rom")
    if rom:
        say(f"ROM: {rom['summary']}")
    statement = result.info.get("actor_model", {}).get("statement")
    if statement:
        say(f"actor: {statement}")
    if config.output_blend is not None:
        extra["output_blend"] = base.report()
    # The take's (F, M, 3) arrays are not needed for keying, whose F-curves (and Blender's copy of
    # them when it saves) are a long take's largest memory: freed before it (issue 18). A long
    # take's result lets its stabilised markers go too, unless the review page is to draw them.
    fps, settings = take.fps(), request.settings
    long_take = result.frames.size >= LONG_TAKE_FRAMES
    take.markers = request = None
    if long_take and getattr(result, "stabilise", None) is not None and config.output_html is None:
        result = dataclasses.replace(result, stabilise=result.stabilise.without_markers())
    release_freed_memory()
    outputs = key_and_write(config, obj, result, outputs=outputs, timings=timings, t0=t0, notes=take.notes, say=say,
                            report_fields={**source_info, "cleaning": take.cleaning, **extra}, fps=fps, said=said)
    if config.output_html is not None:
        outputs["html"] = str(write_take_review(config, obj, settings, result, notes=take.notes,
                                                timings=timings, truth=truth, options=review, say=say,
                                                weights_track=getattr(take.inputs, "weights", None),
                                                footage=take.footage))
    return result, outputs


@dataclasses.dataclass(frozen=True)
class Base:
    """The .blend a run opens: ``[target] blend``, or the existing output .blend it adds to."""

    path: Path  # None: the open file (or Blender's start-up scene)
    mode: str  # "new" (no output .blend yet, or none asked for), "added" (to the existing output), "replaced"

    def report(self):
        return {"mode": self.mode, "opened": None if self.path is None else str(self.path)}


def preflight(config, *, tune=False, replace=False, overwrite=False):
    """Every check that needs no solve, before any work: something will be written, the output
    policy allows every output (``solvers.io.outputs``: none is an input or another output, an existing
    one is facecap's own of its kind unless ``overwrite``, each can be written); stale temporary files
    of earlier killed runs are removed. Returns the ``Base`` to open."""
    if tune and config.video is not None:
        raise ConfigError("tuning a [source] video take is not supported yet", path=config.path, key="source.video")
    check_input_files(config)  # every missing input, each with its key, before anything is read
    if not tune and not take_outputs(config):
        raise ConfigError("nothing would be written: give [output] blend, weights, report, html, gltf or fbx",
                          path=config.path, key="output")
    check_outputs(config, library=versions_folder(config) if tune else None, overwrite=overwrite)
    for path in take_outputs(config).values():
        remove_stale_temporaries(path.parent)
    return choose_base(config, replace=replace)


def choose_base(config, *, replace=False):
    """The ``Base`` a run opens: the existing output .blend (added to), else ``[target] blend``."""
    out = config.output_blend
    if out is not None and out.is_file():
        if replace:
            return Base(config.target_blend, "replaced")
        return Base(out, "added")
    return Base(config.target_blend, "new")


#: Binding notes the solve says again in its own words (``stages.usable_markers``: no sample over the
#: neutral frames): one line per fact, so the binding's is left out.
SAID_BY_THE_SOLVE = ("have no neutral position and stay unbound",)
#: Solve notes that repeat a binding by position's own (which gives each unbound marker's distance).
REPEATS_OF_THE_BINDING = ("have no binding on the character and are not solved from",)


def _once(notes, repeats):
    """``notes`` without those that contain one of ``repeats`` (said already, with more detail)."""
    return [n for n in notes if not any(r in n for r in repeats)]


@dataclasses.dataclass
class _Take:
    """What was read of a take config's source."""

    markers: object = None  # MarkerSet
    footage: object = None  # solvers.video.Footage
    inputs: object = None  # StrategyInputs
    source: dict = None  # format, units... for the report
    notes: tuple = ()
    cleaning: tuple = ()
    repeats: tuple = ()  # solve notes that only repeat the notes above
    landmarks: object = None  # LandmarkResult of a landmark take (pixels: the gaze)
    response: object = None  # the blendshape scores' response of a landmark take (ROM on camera, profile)
    follow: object = None  # LandmarkResult of the clip that follows [calibration] guide (fitted with the character)
    performer: object = None  # the performer's clip in the fusion map (a guide followed, or [actor] profile's)

    def fps(self):
        if self.markers is not None:
            return self.markers.fps
        if self.footage is not None:
            return self.footage.info.fps
        return self.inputs.weights.fps

    def n_frames(self):
        if self.markers is not None:
            return self.markers.n_frames
        if self.footage is not None:
            return self.footage.info.n_frames
        return len(self.inputs.weights.frames)

    def describe(self):
        if self.markers is not None:
            return f"{self.markers.n_frames} frames from {self.markers.n_markers} markers"
        if self.footage is not None:
            info = self.footage.info
            return f"{info.n_frames} footage frames ({info.work_width}x{info.work_height})"
        return f"{len(self.inputs.weights.frames)} frames of {len(self.inputs.weights.names)} solved channels"


def _read_and_open(config, say, base, *, quiet=False):
    """(take, target object, read seconds, open seconds). A big marker file is read in a forked
    child while Blender starts and opens the character (measured on a 36,000-frame CSV take: 1.0-1.5 s
    of reading beside 0.8-1.0 s of start-up); a bad file is read again here, so its error is raised here."""

    def read():  # the take's checks before Blender opens the character (beside it on a large take)
        t = time.perf_counter()
        take = read_take(config, say, quiet=quiet)
        check_against_take(config, take.markers, take.inputs)
        check_take_names(config, take.markers, getattr(take.inputs, "calibration", None))
        return take, time.perf_counter() - t

    def open_character():  # Blender's start-up (the first ``import bpy``) is in here
        t = time.perf_counter()
        return open_target(config, say, base), time.perf_counter() - t

    def tell(take):  # what reading found (units, rate guessed) said at once, not after [5/5]
        for note in take.notes:
            say(f"warning: {note.removeprefix('warning: ')}")

    path = config.markers_path
    if path is not None and path.is_file() and path.stat().st_size > PARALLEL_READ_BYTES:
        (obj, t_open), (take, t_read) = run_beside(open_character, read)
        tell(take)
    else:
        take, t_read = read()
        tell(take)
        obj, t_open = open_character()
    return take, obj, t_read, t_open


def read_take(config, say, *, quiet=True):
    """Read the take's source (markers cleaned as ``[clean]`` says, footage, face landmarks, or
    solved weights) and the strategy's inputs. Landmarks show progress on stderr unless ``quiet``."""
    inputs = load_strategy_inputs(config)
    if isinstance(config.video, LandmarkTake):
        say(f"[1/5] face landmarks in {config.video.path}")
        markers, source, notes, found = read_landmarks(config.video, say, quiet=quiet)
        response, report, more = score_response(config, found, say, quiet=quiet)
        if report is not None:
            source["score_response"] = report
        return _Take(markers=markers, inputs=inputs, source=source, notes=notes + tuple(more), landmarks=found,
                     response=response, follow=follow_clip(config, found, say, quiet=quiet),
                     performer=performer_of(config, source))
    if config.video is not None:
        say(f"[1/5] reading footage {config.video.path}")
        footage = Footage(config.video.path, **config.video.footage)
        check_against_footage(config.path, config.video, footage.info)
        return _Take(footage=footage, inputs=inputs, notes=tuple(inputs.notes))
    if config.markers_path is None:
        say(f"[1/5] reading solved weights {config.weights_path}")
        return _Take(inputs=inputs)
    say(f"[1/5] reading markers {config.markers_path}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        imported = import_markers(config.markers_path, units=config.units, fps=config.fps, **config.read_options)
    notes = tuple(dict.fromkeys([*imported.notes, *(str(w.message) for w in caught)]))
    cleaned = clean(imported.markers, config.clean)
    release_freed_memory()  # the parser's blocks, before the take's copy in metres is made
    markers = cleaned.markers
    if markers.dim == 3 and markers.units in UNIT_SCALE:  # in metres, as the solve reads them: one
        markers = markers.to_units("m")  # (F, M, 3) copy of the take for the whole run (issue 18)
    # one memory layout whichever process reads the take (a pickled array comes back C-ordered,
    # and sums over another layout round differently in the last bits)
    markers = dataclasses.replace(markers, positions=np.ascontiguousarray(markers.positions))
    return _Take(markers=markers, inputs=inputs, source={"format": imported.format, "units": imported.markers.units},
                 notes=notes, cleaning=tuple(cleaned.report.summary().splitlines()))


def open_target(config, say, base=None):
    """Open the run's ``Base`` .blend (default ``[target] blend``, if given); returns ``[target] object``."""
    bpy = start_blender()

    base = base or Base(config.target_blend, "new")
    if base.path is not None and not base.path.is_file():
        raise InputFileError(base.path, "file not found (config [target] blend)")
    if base.path is not None:
        say(f"[2/5] opening {base.path}" + (" (adding to it)" if base.mode == "added" else ""))
    with console.driver_errors_to_debug():  # Blender's lines on drivers that cannot run: facecap names them once
        if base.path is not None:
            open_blend(base.path, "the existing [output] blend" if base.mode == "added" else "[target] blend")
        bpy.context.view_layer.update()  # every driver's first evaluation
    where = "the existing [output] blend (--replace starts from [target] blend)" if base.mode == "added" \
        else base.path.name if base.path is not None else "the open file"
    check_scene_names(config, *names_in_file(config.target_object), where=where)  # before anything is solved
    return bpy.data.objects[config.target_object]


def _request(config, obj, take, *, tune, characters=None, base=None, quiet=False):
    """The SolveRequest of a take config, and the report's source fields."""
    from ..scene.scene_binding import geometric_character  # loads bpy
    from ..scene.take import character_target  # loads bpy

    settings = config.settings
    if config.rig is not None:  # probing a rig: a pose at a time in Blender, with progress, Ctrl-C stops it
        return rig_request(config, obj, take, tune=tune, say=progress_line, quiet=quiet)
    binding = config.binding or BindingSettings()
    # Only geometric samples the character at bound points; the others need its shape names and ranges.
    # Vertex groups and shape names are kept across a batch worker's takes; a binding by position depends
    # on the take (its neutral): bound every run, and stored on the character for the output .blend.
    names = take.markers.names if settings.strategy in SAMPLES_CHARACTER else None

    def sample():
        if names is None:
            return character_target(obj)
        return geometric_character(obj, take.markers, settings, binding, rebind=True)

    keep = characters is not None and base is not None and not (names is not None and binding.by_position)
    made = characters.get(base.path, config.target_object, names, sample) if keep else sample()
    bound = None if names is None else made
    character = made if names is None else made.basis
    if names is None and binding.by_position:
        take.notes = tuple(take.notes) + (f"[binding] mode \"{binding.mode}\" applies to the geometric and semantic "
                                          f"strategies; '{settings.strategy}' does not sample the character",)
    if take.markers is not None and take.markers.dim == 2 and config.projection == "camera":
        import bpy  # bpy: Blender starts on first import

        from ..scene.scene_camera import projection_for  # loads bpy

        settings = dataclasses.replace(settings, projection=projection_for(bpy.context.scene, obj, "camera",
                                                                           config.camera_name))
    tuning, version, corrections = config.tuning, None, None
    if tuning is not None and tuning.library is not None:
        version = load_version(tuning.library)
    if tune:
        corrections = corrections_for(config, shape_names(character))
    request = SolveRequest(character=character, settings=settings, inputs=take.inputs, markers=take.markers,
                           footage=take.footage, flow=getattr(config.video, "flow", None), version=version,
                           corrections=corrections, mu=None if tuning is None else tuning.mu,
                           parent="" if version is None else version.name, controls=config.controls or None)
    if take.landmarks is not None:  # the eyes' look from the irises held through the solve, the scores fused
        say = (lambda _m: None) if quiet else progress_line
        request, note = landmark_request(config, request, take, shape_names(character), say)
        take.notes = tuple(take.notes) + ((note,) if note else ())
    fields = source_fields(config, take)
    if bound is not None:
        fields["binding"] = bound.report()
        said = _once([n for n in bound.notes if n.startswith("warning")], SAID_BY_THE_SOLVE)
        take.notes = tuple(take.notes) + tuple(n.removeprefix("warning: ") for n in said)
        if binding.by_position:  # the binding named its unbound markers, each with why (distance, map)
            take.repeats = REPEATS_OF_THE_BINDING
    return request, fields


def _run(request, *, quiet):
    """Run the request; footage and rig solves show progress on stderr and Ctrl-C stops them between
    two frames (steps) with ``Cancelled`` (nothing written; the CLI exits 130)."""

    job = solve_job(request)
    if request.rig is not None:  # Gauss-Newton steps (and refinement through the rig): progress, Ctrl-C stops
        with showing_progress("rig solve", quiet=quiet or console.quiet(), unit="step") as progress:
            try:
                return job.run(progress)
            except Cancelled:
                raise Cancelled(f"rig solve cancelled after {job.done} of at most {job.total} steps") from None
    if request.footage is None:
        return job.run()
    return run_showing_progress(job, f"flow ({request.flow.method})", quiet=quiet or console.quiet())


def key_and_write(config, obj, result, *, outputs, timings, t0, notes, say, report_fields, fps=None, said=0):
    """Key ``result`` as ``obj``'s solve layer and write ``[output]`` weights / .blend / report.

    ``outputs`` holds what was already written; ``report_fields`` are added to the JSON report
    (source, cleaning, tuning...); ``notes`` (reading) go before the solve's warnings, the first ``said`` of
    them in the report only (said already). The scene
    takes the take's frame range and ``fps``. Returns ``outputs`` with the action and the written paths.
    """
    import bpy  # bpy: Blender starts on first import

    from ..scene import anim  # loads bpy
    from ..scene.import_scene import fit_scene_to_take  # loads bpy
    from ..scene.take import key_weights  # loads bpy

    replaced = []

    def key_and_save():
        t3 = time.perf_counter()
        say("[4/5] keying")
        replaced.extend(remove_earlier_solve(config.action_name))
        if config.rig is not None:
            from ..rig.rig_solve import key_rig  # loads bpy

            action = key_rig(config.rig, obj, result, anim.unique_action_name(config.action_name))
        else:
            action = key_weights(obj, result, anim.unique_action_name(config.action_name))
        fit_scene_to_take(bpy.context.scene, result.frames, fps)
        timings["key"] = time.perf_counter() - t3
        say("[5/5] writing outputs")
        if config.output_blend is not None:
            stamp_target(config.target_blend)
            save_blend_atomic(config.output_blend)
        _export(config, obj, fps, result.frames)
        return action

    def write_weights():
        write_weights_csv(config.output_weights, result.frames, result.shape_names, result.weights)

    if config.output_weights is not None and result.weights.size > PARALLEL_WRITE_VALUES:
        # the weights CSV is written by a forked child while Blender keys and saves (measured on
        # 36,000 frames x 52 shapes: 0.4-0.6 s of writing beside 1.2 s); a failed child's file is
        # written again here
        action, _ = run_beside(key_and_save, write_weights, let_finish=True)
    else:
        action = key_and_save()
        if config.output_weights is not None:
            write_weights()
    outputs = {"action": action.name, **outputs}
    if replaced:
        outputs["replaced_action"] = replaced[0]
    if config.output_weights is not None:
        outputs["weights"] = str(config.output_weights)
    if config.output_blend is not None:
        outputs["blend"] = str(config.output_blend)
    for key in ("gltf", "fbx"):
        if getattr(config, f"output_{key}") is not None:
            outputs[key] = str(getattr(config, f"output_{key}"))
    timings["total"] = time.perf_counter() - t0
    if config.output_report is not None:
        report = {"facecap_report": REPORT_SCHEMA, **result.report()}
        report["config"] = str(config.path)
        report.update(report_fields)
        report["outputs"] = outputs
        report["warnings"] = list(notes) + report["warnings"]
        report["timings_s"].update({k: round(v, 6) for k, v in timings.items()})
        write_json_atomic(config.output_report, report)
        outputs["report"] = str(config.output_report)
    for note in list(notes)[said:] + list(result.warnings):
        say(f"warning: {note.removeprefix('warning: ')}")
    return outputs


def _export(config, obj, fps, frames=None):
    """[output] gltf / fbx: the character and the keyed take through Blender's exporters (a rig: its bones)."""
    from ..scene.export import export_take  # loads bpy
    from ..rig.rig_export import export_rig_take  # loads bpy

    for path in (config.output_gltf, config.output_fbx):
        if path is not None and config.rig is not None:
            export_rig_take(obj, path, frames=frames, take_name=config.action_name)
        elif path is not None:
            export_take(obj, path, head_target=config.settings.head_target, fps=fps, take_name=config.action_name)
