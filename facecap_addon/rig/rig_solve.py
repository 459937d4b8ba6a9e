"""A rig as the solve's target, from the scene: its controls, evaluated, probed or posed -> ``RigTarget``.

``build_rig_target`` is shared by the command line (``headless``) and the sidebar (``scene_solve``):
the controls of ``[rig]`` (a preset and/or named controls), a ``RigEvaluator`` at the take's bound
points, then either the probed model (``solvers.rig.probe_rig``; driver-read pairs from the rig's
driver variables, and for bones every pair of controls that move a common point) or the pose
library (an action with one pose per frame, named by its pose markers, evaluated once per pose).
"""

import time

import bpy
import numpy as np

from ...solvers.config.rig import RigSettings
from ...solvers.errors import ConfigError, FacecapError
from ...solvers.pipeline.binding import from_record
from ...solvers.rig import PoseLibrary, RigTarget, probe_rig_steps, run_steps
from ...solvers.video.reading import Cancelled
from ..scene import anim, layers
from . import drivers
from .rig_eval import RigEvaluator
from .rig_proxy import remove_proxies
from .rig_keying import key_controls
from .rig_target import driver_pairs, preset_controls, spec_controls
from ..scene.scene_binding import geometric_character


def rig_settings(settings):
    """``RigSettings`` of the Solve panel's rig target (``settings``: the scene's facecap settings;
    None: the shape keys)."""
    if settings.rig_preset == "NONE":
        return None
    return RigSettings(preset=settings.rig_preset, object=settings.rig_object.name if settings.rig_object else None,
                       method=settings.rig_method, poses=settings.rig_poses.name if settings.rig_poses else None,
                       nonlinear=settings.rig_nonlinear, refine=settings.rig_refine, probes=settings.rig_probes)


def rig_controls(rig_settings, mesh):
    """The controls ``rig_settings`` (``RigSettings``) names on ``mesh``'s rig, preset's first."""
    rig = None
    if rig_settings.object:
        rig = bpy.data.objects.get(rig_settings.object)
        if rig is None:
            raise FacecapError(f"[rig] object: no object named '{rig_settings.object}'")
    controls = preset_controls(rig_settings.preset, mesh, rig) if rig_settings.preset else []
    controls += spec_controls(rig_settings.controls, mesh)
    seen = set()
    for c in controls:
        if c.name in seen:
            raise FacecapError(f"[rig]: control '{c.name}' is named twice")
        seen.add(c.name)
    if not controls:
        raise FacecapError("[rig]: no controls to solve")
    return controls


def _driver_ids(mesh, controls):
    ids = {id(c.owner): c.owner for c in controls}
    if mesh.data.shape_keys is not None:
        ids[id(mesh.data.shape_keys)] = mesh.data.shape_keys
    for c in controls:
        if isinstance(c.owner, bpy.types.Object) and c.owner.type == "ARMATURE":
            ids[id(c.owner.data)] = c.owner.data
    return list(ids.values())


def pose_library(action, controls):
    """A ``PoseLibrary`` from ``action``: each pose marker names the pose at its frame; a control
    without a curve in the action stays at rest."""
    markers = sorted(action.pose_markers, key=lambda m: m.frame)
    if not markers:
        raise FacecapError(f"[rig] poses: action '{action.name}' has no pose markers naming its poses "
                           "(Timeline > Marker in the Action Editor's pose markers, one per frame)")
    owners = {id(c.owner): c.owner for c in controls}
    curves = {}
    for owner in owners.values():
        for fc in anim.action_fcurves(action, owner):
            curves[(id(owner), fc.data_path, fc.array_index)] = fc
    poses = np.array([[c.rest for c in controls]] * len(markers), dtype=np.float64)
    used = 0
    for j, c in enumerate(controls):
        fc = curves.get((id(c.owner), c.path, max(c.index, 0)))
        if fc is None:
            continue
        used += 1
        poses[:, j] = [fc.evaluate(float(m.frame)) for m in markers]
    if not used:
        raise FacecapError(f"[rig] poses: action '{action.name}' keys none of the rig's controls")
    return PoseLibrary(tuple(m.name for m in markers), tuple(c.name for c in controls), poses,
                       np.array([c.rest for c in controls]), np.array([c.lower for c in controls]),
                       np.array([c.upper for c in controls]))


#: Rig evaluations per refinement round at most: longer takes are evaluated on every n-th frame.
REFINE_EVALUATIONS = 400


def rig_binding(mesh, markers, settings, binding):
    """{marker: (vertex indices, weights)} where the take's markers sit on ``mesh``: its vertex groups,
    or a binding by position (``[binding]`` map / nearest; the mesh needs its shape keys for it)."""
    if binding is None or not binding.by_position:
        return None
    if mesh.data.shape_keys is None:
        raise FacecapError(f"[binding] mode \"{binding.mode}\" binds on a mesh with shape keys; '{mesh.name}' has "
                           "none: name vertex groups after the markers instead")
    bound = geometric_character(mesh, markers, settings, binding, rebind=True, driven=True)
    sampling, _, _ = from_record(bound.record, len(mesh.data.vertices), markers.names)
    return {n: (np.asarray(c, dtype=np.intp), np.asarray(w, dtype=np.float64)) for n, (c, w) in sampling.items()}


#: Poses evaluated between two of the sidebar's steps (Esc is seen between two; the command line reports
#: every four).
PROBE_CHUNK = 64


def build_rig_target(mesh, marker_names, rig_settings, *, say=None, progress=None, binding=None, n_frames=None,
                     reference=False):
    """(RigTarget, controls) of ``mesh``'s rig at the markers ``marker_names``; ``say`` gets a line
    on what was probed, ``progress(done, total) -> bool`` sees the probes (False cancels:
    ``Cancelled``, with the rig's controls as they were); ``binding``: {marker: (vertices, weights)}
    (default: vertex groups named after the markers); ``n_frames``: the take's length (long takes are
    refined through the rig on every n-th frame); ``reference``: the slow path (``RigTarget``)."""
    steps = build_rig_target_steps(mesh, marker_names, rig_settings, say=say, binding=binding, n_frames=n_frames,
                                   chunk=4 * PROBE_CHUNK if progress is not None else None, reference=reference)
    target, controls = run_steps(
        steps, progress, lambda done, planned: Cancelled(f"rig probing cancelled after {done} of {planned} poses"))
    left_out = drivers.unrunnable(drivers.rig_ids(mesh, controls))  # the rig evaluated: Blender marked what failed
    if left_out:  # in the report's ``rig`` section; the solve's warning is rig_notes'
        target.info.update(drivers_left_out=[f"{owner} {what}" for owner, _, what, _ in left_out])
    return target, controls


def build_rig_target_steps(mesh, marker_names, rig_settings, *, say=None, binding=None, n_frames=None, chunk=None,
                           reference=False):
    """``build_rig_target`` as a generator: yields (poses probed, poses planned) after every
    ``chunk`` poses; returns (RigTarget, controls). Between two yields the rig's controls are as the
    user left them, so closing it there leaves the scene untouched."""
    t0 = time.perf_counter()
    controls = rig_controls(rig_settings, mesh)
    evaluator = RigEvaluator(mesh, controls, marker_names, binding=binding, reference=reference)
    names = tuple(c.name for c in controls)
    rest = evaluator.rest()
    lower = np.array([c.lower for c in controls])
    upper = np.array([c.upper for c in controls])
    info = {"controls": len(controls), "evaluation": evaluator.mode}
    if rig_settings.method == "poses":
        action = bpy.data.actions.get(rig_settings.poses or "")
        if action is None:
            raise FacecapError(f"[rig] poses: no action named '{rig_settings.poses}'")
        library = pose_library(action, controls)
        deltas = evaluator.deltas(library.poses - rest)
        evaluator.close()
        basis = library.basis(evaluator.marker_names, evaluator.neutral, deltas)
        info.update(poses=len(library.pose_names), seconds=round(time.perf_counter() - t0, 3))
        return RigTarget("poses", library=library, library_basis=basis, info=info), controls
    bones = any(isinstance(c.owner, bpy.types.Object) and c.owner.type == "ARMATURE" for c in controls)
    pairs = driver_pairs(controls, _driver_ids(mesh, controls))
    model, report = yield from probe_rig_steps(evaluator.deltas, names, evaluator.marker_names, evaluator.neutral,
                                               rest=rest, lower=lower, upper=upper, pairs=pairs, find_pairs=bones,
                                               n_random=rig_settings.probes, chunk=chunk)
    info.update(report.as_dict())
    info["seconds"] = round(time.perf_counter() - t0, 3)
    notes = rig_notes(mesh, controls, evaluator)
    if say is not None:
        say(f"rig: {len(controls)} controls probed with {report.probes} poses in {info['seconds']:.1f} s "
            f"({len(report.pairs)} pairwise terms; model error {report.holdout_rms * 1e3:.3f} mm on held-out poses)")
    evaluate = evaluator.deltas if rig_settings.refine else None
    stride = max(1, -(-int(n_frames or 0) // REFINE_EVALUATIONS))
    target = RigTarget("probed", model=model, nonlinear=rig_settings.nonlinear, evaluate=evaluate,
                       refine_stride=stride, info=info, reference=reference, notes=notes)
    return target, controls


def rig_notes(mesh, controls, evaluator):
    """Warnings on the rig's drivers once probed: those Blender could not run (named once, with how
    to trust the file), and the driven shape keys no control moved (left out of the solve)."""
    notes = []
    broken = drivers.unrunnable(drivers.rig_ids(mesh, controls))
    if broken:
        notes.append(drivers.unrunnable_note(broken))
    named = {path for _, path, _, _ in broken}
    still = [n for n in evaluator.still_driven() if layers.shape_path(n) not in named]
    if still:
        notes.append(f"{len(still)} driven shape key(s) of '{mesh.name}' do not move with the rig's controls (their "
                      f"drivers read nothing the controls move): left out of the solve: "
                      f"{', '.join(still[:8])}{'...' if len(still) > 8 else ''}")
    return tuple(notes)


def key_rig(rig_settings, mesh, result, action_name, *, take_name=""):
    """Key ``result`` (over the controls of ``rig_settings``) as the solve layer of the IDs the
    controls live on; returns the first new action (the one with the diagnostics). The solve is
    over: the proxies its evaluations used are removed first."""
    remove_proxies()
    return key_controls(rig_controls(rig_settings, mesh), result, action_name, take_name=take_name)[0]


#: The slow reference path for every rig solve of this process (``rig-bench --reference``, tests).
REFERENCE = False


def rig_target_for_take(config, mesh, markers, *, say=None, progress=None):
    """(RigTarget, report fields) of a take config's ``[rig]``: bound as ``[binding]`` says;
    ``progress(done, total) -> bool`` sees the probes (False cancels)."""
    rig = config.rig
    if markers is None or (config.settings.strategy != "geometric" and rig.method == "probed"):
        raise ConfigError("a rig's controls are solved from a marker take with the geometric strategy, or through a "
                          "pose library (method = \"poses\") with any strategy", path=config.path, key="rig.method")
    sampling = rig_binding(mesh, markers, config.settings, config.binding)
    target, controls = build_rig_target(mesh, markers.names, rig, say=say, binding=sampling, n_frames=markers.n_frames,
                                        progress=progress, reference=REFERENCE)
    fields = {"method": rig.method, "preset": rig.preset, "object": rig.object, "controls": [c.name for c in controls]}
    return target, fields
