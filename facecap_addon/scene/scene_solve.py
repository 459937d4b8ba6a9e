"""The sidebar's side of the one solve path (``solvers.solve``): a ``SolveRequest`` from the scene
and the solve layer it keys.

*Solve and Key*, *Retune*, *Fit Gain and Offset* and *Solve from Clip Flow* all build their request
here (``request_from_scene``): the take and the character read from the scene, the active library
version, the animator's locks and the per-shape controls. *Solve and Key*, *Retune* and *Fit Gain and
Offset* solve on a worker thread (``SolveInBackground``) so the sidebar shows their progress and Esc
cancels them; onto a rig they run in short steps on the main thread instead (``RigSolveSession``:
Blender evaluates the rig).
"""

import glob
import threading
import time
from dataclasses import replace

import numpy as np

from ...solvers.errors import FacecapError
from ...solvers.pipeline import SAMPLES_CHARACTER
from ...solvers.solve import SolveRequest, solve, solve_job
from ...solvers.video.fusion import FaceScores
from ...solvers.video.response import profile_contents, profile_performer
from ...solvers.video.reading import Cancelled
from ..headless.landmark_take import neutral_indices
from ..headless.take_request import rig_weights_note, shape_names
from . import anim, layers, take
from ..rig.drivers import left_out_note
from ..rig.rig_proxy import remove_proxies
from ..rig.rig_solve import PROBE_CHUNK, build_rig_target, build_rig_target_steps, key_rig, rig_binding, rig_settings
from .landmark_scores import eye_locks, keeps_landmark_extras, landmark_eyes_kept, scores_from_collection
from .scene_camera import projection_from_sidebar
from .scene_binding import binding_from_sidebar, geometric_character, show_markers
from .tuning_scene import load_version, shape_controls


def request_from_scene(settings, scene, *, footage=None, flow=None, corrections=None, mu=None, controls=None):
    """A SolveRequest for the sidebar's take and strategy.

    ``footage`` (with ``flow``): a video take solved from flow features instead of the imported
    markers; ``corrections`` ({frame: {shape: value}}) and ``mu``: retune from them and re-solve;
    ``controls``: per-shape controls instead of the shape list's (a gain/offset fit not yet written).
    """
    controls = shape_controls(settings) if controls is None else controls

    strategy = settings.strategy if footage is None else settings.video.flow_strategy
    markers = None if strategy == "parallel" or footage is not None else take.markers_from_collection(settings)
    rsettings = replace(take.retarget_settings(settings), strategy=strategy)
    if settings.rig_preset != "NONE" and footage is None:
        return _rig_request(settings, markers, rsettings, corrections=corrections, mu=mu, controls=controls)
    driven = left_out_note(settings.target)
    notes = (driven,) if driven else ()
    if markers is not None and not landmark_eyes_kept(settings.marker_collection):
        notes += ("this landmark take was tracked before facecap kept its eyes' points: its blinks and gaze are "
                  "solved from the skin alone (weaker); run Track Face Landmarks again to hold them",)
    if strategy in SAMPLES_CHARACTER:  # a stored binding by position is used as it is; none yet: bound and stored
        bound = geometric_character(settings.target, markers, rsettings, binding_from_sidebar(settings))
        show_markers(settings, bound)
        character = bound.basis
    else:
        character = take.character_target(settings.target)
    inputs = take.strategy_inputs(settings, strategy)
    eyes, scores = landmark_extras(settings, markers, rsettings, shape_names(character))
    if markers is not None:  # the animator's locks first: they win over the eyes' where both hold a shape
        rsettings = replace(rsettings, locks=animator_locks(settings, markers.frames) + eyes)
        if markers.dim == 2:
            rsettings = replace(rsettings, projection=projection_from_sidebar(scene, settings.target))
    # library versions are learned from the marker take: a footage solve does not use them
    version = load_version(scene, settings.library_active) if settings.library_active and footage is None else None
    return SolveRequest(character=character, settings=rsettings, inputs=inputs, markers=markers, footage=footage,
                        flow=flow, version=version, corrections=corrections, mu=mu,
                        parent=settings.library_active or "", controls=controls, fps=settings.fps,
                        scores=scores, notes=notes)


def landmark_extras(settings, markers, rsettings, names):
    """(eye locks, FaceScores or None) a landmark take keeps for the shapes or rig controls ``names``: its eyes held
    through the solve as the headless take holds them (``hold_gaze``) and its scores to fuse, both from the take's
    neutral frames, found once; ((), None) for other takes."""
    neutral = landmark_neutral(settings, markers, rsettings)
    if neutral is None:
        return (), None
    return (eye_locks(settings.marker_collection, markers.frames, neutral, names),
            landmark_scores(settings, markers, rsettings, neutral))


def landmark_neutral(settings, markers, rsettings):
    """The neutral frames (indices) of a landmark take keeping scores or eye points, given or detected as the solve
    detects them; None for other takes (nothing detected for them) or when it has none. Its eyes are then held
    through the solve as the headless take holds them (``hold_gaze``) and its scores fused."""
    if markers is None or not keeps_landmark_extras(settings.marker_collection):
        return None
    neutral = neutral_indices(rsettings, markers)
    return neutral if neutral is not None and len(neutral) else None


def landmark_scores(settings, markers, rsettings, neutral=None):
    """The Face Landmarker's blendshape scores a landmark take keeps on its collection (``store_scores``), with
    the take's ``neutral`` frames (None: given or detected as the solve detects them) and the response of the Solve
    panel's performer profile, if it holds one (a ROM on camera), and its clip in the fusion map (a guide
    followed): FaceScores, or None."""
    found = scores_from_collection(settings.marker_collection, markers.frames)
    if found is None:
        return None
    if neutral is None:
        neutral = landmark_neutral(settings, markers, rsettings)
    if neutral is None:
        return None
    response = performer = None  # the performer on this camera, when the Solve panel's profile measured them
    if settings.actor_profile:
        import bpy  # bpy: the sidebar's paths are relative to the .blend

        path = bpy.path.abspath(settings.actor_profile)
        response, performer = profile_contents(path)[1], profile_performer(path)
    # the Video panel's Smoothing filters the fused weights' jitter as it does the landmarks'
    return FaceScores(found[0], found[1], neutral, response=response, fps=markers.fps,
                      smoothing=bool(settings.video.landmark_smoothing), performer=performer)



def _rig_inputs(settings, markers, rsettings):
    """(RigSettings, settings, binding) of the sidebar's rig target, checked."""
    if markers is None:
        raise FacecapError("a rig's controls are solved from a marker take")
    if settings.rig_method == "probed":  # its model stands for the character's shapes: the geometric solve
        if rsettings.strategy not in SAMPLES_CHARACTER:
            raise FacecapError("a probed rig is solved with the geometric strategy; use a pose library for the others")
        rsettings = replace(rsettings, strategy="geometric")
    sampling = rig_binding(settings.target, markers, rsettings, binding_from_sidebar(settings))
    return rig_settings(settings), rsettings, sampling


def _rig_solve_request(settings, markers, rsettings, target, *, corrections=None, mu=None, controls=None):
    # a landmark take: its eyes and scores reach the controls that read as shape weights (``solve`` fuses only those)
    eyes, scores = landmark_extras(settings, markers, rsettings, target.weight_controls)
    rsettings = replace(rsettings, locks=tuple(rsettings.locks) + eyes)
    notes = rig_weights_note(target, target.weight_controls) if eyes or scores is not None else ()
    return SolveRequest(character=None, settings=rsettings, markers=markers, corrections=corrections, mu=mu,
                        controls=shape_controls(settings) if controls is None else controls, fps=settings.fps,
                        rig=target, scores=scores, notes=notes)


def _rig_request(settings, markers, rsettings, *, corrections, mu, controls):
    rig, rsettings, sampling = _rig_inputs(settings, markers, rsettings)
    target, _ = build_rig_target(settings.target, markers.names, rig, binding=sampling, n_frames=markers.n_frames)
    return _rig_solve_request(settings, markers, rsettings, target, corrections=corrections, mu=mu, controls=controls)


def solve_take(settings, scene, **kwargs):
    """Solve the sidebar's take (controls applied); returns RetargetResult."""
    return solve(request_from_scene(settings, scene, **kwargs))


def _layered_locks(settings, frames):
    """{shape: (F,) value the animator sees} for locked shapes that have a solve layer or keys."""
    key = settings.target.data.shape_keys
    if key is None or key.animation_data is None:
        return {}
    locked = [s.name for s in settings.shapes if s.lock and s.name in key.key_blocks]
    has_solve = layers.solved_action(key) is not None
    keyed = {n for n in locked if layers.edit_key_frames(key, [n]).size}
    names = [n for n in locked if has_solve or n in keyed]
    if not names:
        return {}
    _, final = layers.layer_values(key, names, frames)
    return dict(zip(names, final.T))


def animator_locks(settings, frames):
    """Solve locks: a locked shape is held at what the animator sees on every frame (the solve
    layer plus their keys) when there is such a layer, else at its lock value."""
    layered = _layered_locks(settings, np.asarray(frames, dtype=np.float64))
    return tuple((glob.escape(s.name), layered.get(s.name, s.lock_value)) for s in settings.shapes if s.lock)


def key_solve(settings, result):
    """Key ``result`` as the target's new solve layer; returns the action.

    A locked shape keeps its previous solve-layer curve: the solve held it at what the animator saw
    (solve layer + their keys), so re-keying that value under their keys would count them twice.
    """
    actor = result.info.get("actor_model")  # what a semantic solve knew of the actor: shown in the Solve panel
    advice = (result.info.get("plausibility") or {}).get("prior_advice")  # the expressions are not the actor's
    settings.actor_tier = (f"{actor['tier']}: {actor['statement']}" + (f". {advice[0].upper()}{advice[1:]}" if advice
                                                                        else "")) if actor else ""
    name = settings.take_name or "FaceCap"
    rig = rig_settings(settings)
    if rig is not None:
        action = key_rig(rig, settings.target, result, anim.unique_action_name(name), take_name=name)
        settings.last_action = action.name
        return action
    key = settings.target.data.shape_keys
    locked = [n for n in result.shape_names if n in {s.name for s in settings.shapes if s.lock}]
    if locked and key is not None and layers.solved_action(key) is not None:
        previous, _ = layers.layer_values(key, locked, result.frames)
        weights = result.weights.copy()
        for j, n in enumerate(locked):
            if not np.isnan(previous[:, j]).all():
                weights[:, result.shape_names.index(n)] = previous[:, j]
        result = replace(result, weights=weights)
    action = take.key_weights(settings.target, result, anim.unique_action_name(name), take_name=name)
    settings.last_action = action.name
    return action


class SolveInBackground:
    """*Solve and Key* (or *Retune*, *Fit Gain and Offset*: ``what``, with their ``request_from_scene``
    keywords) in the sidebar: the request is built here (it reads the scene), the solve runs on a
    worker thread (numpy and scipy only: no Blender data is touched there) so the interface stays live
    and Esc answers at once; nothing in the scene changes until the operator keys the finished result.
    A cancelled solve cannot be stopped inside numpy: it finishes on its thread and is dropped."""

    what = "Solve and Key"

    def __init__(self, settings, scene, *, what=None, **request):
        self.settings = settings
        self.what = what or self.what
        self.request = request_from_scene(settings, scene, **request)
        self.size = _describe(self.request)
        self._begin()

    def _begin(self):
        """Start the work (``_compute`` of the request built) on its worker thread."""
        self.result = self.error = None
        self.cancelled = False
        self.started = time.monotonic()
        self.thread = threading.Thread(target=self._run, name=f"facecap {self.what}", daemon=True)
        self.thread.start()

    def _compute(self, request):
        return solve(request)

    def _run(self):
        try:
            self.result = self._compute(self.request)
        except Exception as exc:  # handed to the main thread: FacecapError reported, anything else raised
            self.error = exc
        finally:
            self.request = None  # the take's arrays are not kept once solved

    @property
    def finished(self):
        return not self.thread.is_alive()

    def seconds(self):
        return time.monotonic() - self.started

    def status(self):
        return f"{self.what}: solving {self.size} ({self.settings.strategy}), {self.seconds():.0f} s; Esc cancels"

    def wait(self):
        """The result (scripts and tests: as the modal operator would get it); FacecapError as raised."""
        self.thread.join()
        if self.error is not None:
            raise self.error
        return self.result

    def cancel(self):
        self.cancelled = True


class RigSolveSession:
    """*Solve and Key* onto a rig in the sidebar. Blender evaluates the rig (probing, refinement), so
    the work runs on the main thread in short steps that the modal operator drives from its timer
    (``step``): the rig probed ``PROBE_CHUNK`` poses at a time, then the solve a Gauss-Newton
    iteration at a time. The status bar says which and how far; Esc (``cancel``) stops between two
    steps, where the rig's controls are as the user left them and nothing is keyed yet."""

    what = "Solve and Key"

    def __init__(self, settings, scene, *, what=None, **request):
        self.settings = settings
        self.what = what or self.what
        markers = take.markers_from_collection(settings)
        rsettings = replace(take.retarget_settings(settings), strategy=settings.strategy)
        rig, rsettings, sampling = _rig_inputs(settings, markers, rsettings)
        self.frames = markers.n_frames
        self.stage, self.done, self.total = "probing the rig", 0, 1
        self.result = self.error = None
        self.cancelled = False
        self.started = time.monotonic()
        self._steps = self._run(settings, markers, rsettings, rig, sampling, request)

    def _run(self, settings, markers, rsettings, rig, sampling, request):
        job = None
        try:
            target, _ = yield from build_rig_target_steps(settings.target, markers.names, rig, binding=sampling,
                                                          n_frames=markers.n_frames, chunk=PROBE_CHUNK)
            job = solve_job(_rig_solve_request(settings, markers, rsettings, target, **request))
            self.stage = "solving"
            while not job.step():
                yield job.done, job.total
        finally:
            if job is not None and job.result is None:
                job.cancel()
            remove_proxies()  # the rig's evaluations are over (or stopped)
        return job.result

    @property
    def finished(self):
        return self.result is not None or self.error is not None

    @property
    def fraction(self):
        """Of the whole solve: probing counts for the first half."""
        part = min(self.done / max(self.total, 1), 1.0)
        return 0.5 * part if self.stage == "probing the rig" else 0.5 + 0.5 * part

    def step(self, seconds=0.1):
        """Work for about ``seconds``; True when finished (FacecapError of the solve raised here)."""
        if self.finished:
            return True
        if self.cancelled:
            raise Cancelled(f"{self.what} cancelled")
        end = time.perf_counter() + seconds
        while not self.finished:
            try:
                self.done, self.total = next(self._steps)
            except StopIteration as stop:
                self.result = stop.value
            except Exception as exc:
                self.error = exc
                raise
            if time.perf_counter() >= end:
                break
        return self.finished

    def run(self, progress=None):
        """To the end; ``progress(fraction) -> bool`` returning False cancels (``Cancelled``)."""
        while not self.step(0.0):
            if progress is not None and progress(self.fraction) is False:
                self.cancel()
                raise Cancelled(f"{self.what} cancelled while {self.stage}")
        return self.result

    def wait(self):
        if self.error is not None:
            raise self.error
        return self.run()

    def seconds(self):
        return time.monotonic() - self.started

    def status(self):
        unit = "poses" if self.stage == "probing the rig" else "steps"
        return (f"{self.what}: {self.stage} ({self.done}/{self.total} {unit}) for {self.frames} frames, "
                f"{self.seconds():.0f} s; Esc cancels")

    def cancel(self):
        """Stop between two steps: the generator is closed (the rig's controls are put back by each
        evaluation already); nothing was keyed. Safe to call twice."""
        if not self.cancelled and not self.finished:
            self.cancelled = True
            self._steps.close()


def start_session(settings, scene, *, what=None, **request):
    """The session of a sidebar solve (*Solve and Key*, or ``what`` with its ``request_from_scene`` keywords:
    corrections, mu, controls) for the sidebar's target: on a thread, or in steps onto a rig."""
    if settings.rig_preset != "NONE":
        return RigSolveSession(settings, scene, what=what, **request)
    return SolveInBackground(settings, scene, what=what, **request)


def _describe(request):
    shapes = getattr(request.character, "shape_names", None) or getattr(request.character, "names", ())
    if request.markers is not None:
        return f"{request.markers.n_frames} frames from {request.markers.n_markers} markers x {len(shapes)} shapes"
    weights = getattr(request.inputs, "weights", None)
    frames = len(weights.frames) if weights is not None else 0
    return f"{frames} frames of solved weights x {len(shapes)} shapes"
