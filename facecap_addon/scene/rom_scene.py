"""The sidebar's range-of-motion session: the ROM take (the Solve panel's calibration take) measured against its
sheet as a semantic solve would measure it (``solvers.strategies.rom_wiring.learn_from_rom_take``), for *Find
Poses* (the holds found anew, marked on the timeline: ``rom_markers``) and *Save Performer Profile* (the holds of
the ``ROM: `` markers when there are any; the actor's measured shapes written as an .npz the semantic solve reads
as ``[actor] profile``). A ROM take that keeps the Face Landmarker's blendshape scores (*Track Face Landmarks* on
the ROM clip) is the performer's ROM on camera instead: its holds are found in the scores (or taken at the ``ROM: ``
markers, as for markers) and the profile stores their response (``solvers.video.response``), which every later
landmark take of that performer and camera uses. With a **Guide** (the weights the performer followed in that
take), *Save Performer Profile* solves the take onto the character and adds it to the fusion map instead
(``solvers.video.follow``)."""

import os
from dataclasses import dataclass, replace
from pathlib import Path

import bpy
import numpy as np

from ...solvers.capture.stable_markers import suggest_stable_markers
from ...solvers.errors import FacecapError
from ...solvers.io.outputs import Output, OutputError, check_outputs, is_kind
from ...solvers.io.weights import read_weights
from ...solvers.pipeline import SAMPLES_CHARACTER
from ...solvers.solve import SolveRequest, solve_job
from ...solvers.strategies.options import StrategyInputs
from ...solvers.strategies.rom_wiring import learn_from_rom_take
from ...solvers.video.follow import FollowFit, fit_follow
from ...solvers.video.fusion import FaceScores, FusionTable
from ...solvers.video.landmarks import RIGID
from ...solvers.video.response import ResponseFit, fit_response
from ...solvers.video.response import save_profile as save_response_profile
from ..headless.landmark_take import given_indices, metric_neutral
from ..headless.take_request import shape_names
from . import rom_markers, take
from .landmark_scores import eye_locks, scores_from_collection
from .scene_binding import binding_from_sidebar, geometric_character
from .scene_solve import SolveInBackground

NO_ROM_TAKE = ("choose the ROM take under Actor calibration: the collection of its marker empties (import it with "
               "File > Import) or its capture file; a ROM filmed: the landmark take Track Face Landmarks made of it")


def rom_request(settings, *, use_markers):
    """(RetargetSettings, character, StrategyInputs) that ``learn_from_rom_take`` measures the ROM take with, as
    the Solve panel's semantic solve would: the character's shapes at the markers (bound as the solve binds them)
    and the human template when it resolves. ``use_markers``: the holds of the ``ROM: `` markers (else found)."""
    if not rom_markers.sheet_poses(settings):
        raise FacecapError("choose a ROM sheet first (Actor calibration > ROM Sheet)")
    notes = []
    rom = take.calibration_markers(settings, notes)
    if rom is None:
        raise FacecapError(NO_ROM_TAKE)
    if use_markers:
        rom_markers.check_rom(settings)
    rsettings = replace(take.retarget_settings(settings), strategy="semantic")
    if not use_markers:
        rsettings = replace(rsettings, calibration=replace(rsettings.calibration, holds=None))
    if rsettings.auto_stable and not rsettings.calibration.stable_markers:
        suggestion = suggest_stable_markers(rom.to_units("m"))
        if not suggestion.ok:
            raise FacecapError(f"the ROM take's stable markers: {suggestion.message()}; tick them in the marker list")
        rsettings = replace(rsettings, calibration=replace(rsettings.calibration, stable_markers=suggestion.names))
    elif len(rsettings.calibration.stable_markers or rsettings.stable_markers) < 3:
        raise FacecapError("the ROM take is stabilised on the take's stable markers: tick at least 3 in the Take "
                           "panel's marker list (or Auto Stable Set)")
    inputs = StrategyInputs(calibration=rom, template=take.human_template(settings, notes), notes=tuple(notes))
    return rsettings, _character(settings, rsettings, rom), inputs


def _character(settings, rsettings, rom):
    """The character's shapes where the markers sit (the prior that names the poses when no template is
    installed), bound as the solve binds them (on the take's markers when one is imported); None for a rig."""
    if settings.target is None or settings.rig_preset != "NONE":
        return None
    markers = take.markers_from_collection(settings) if settings.marker_collection is not None else None
    if markers is None or markers.dim != 3:
        markers = rom
    bound = geometric_character(settings.target, markers, rsettings, binding_from_sidebar(settings), store=False)
    return bound.basis


@dataclass(frozen=True)
class ScoreRom:
    """A ROM on camera as the sidebar has it: the ROM take's blendshape ``scores`` (F, S) named ``names`` at its
    ``frames``, its ``neutral`` frame indices (detected), the sheet's ``poses`` and name, the take's ``fps``, and
    ``given``: {pose label: frame index} of the ``ROM: `` markers (None: the holds are found in the scores)."""

    scores: np.ndarray
    names: tuple
    frames: np.ndarray
    neutral: np.ndarray
    poses: tuple
    sheet: str
    fps: float
    given: dict | None = None

    def fit(self):
        """The performer's ResponseFit, read against the fusion table's reference faces."""
        return fit_response(self.scores, self.names, self.neutral, self.poses, fps=self.fps,
                            reference=FusionTable.load().reference, sheet=self.sheet, given=self.given)


def score_rom(settings, *, use_markers=False):
    """The Solve panel's ROM take as a ROM on camera (ScoreRom) when it is a landmark take keeping blendshape scores
    (a collection made by *Track Face Landmarks*), else None (a marker ROM: ``rom_request``). ``use_markers``: the
    poses are measured at the ``ROM: `` markers when there are any (else found)."""
    coll = settings.calib_collection if settings.calib_source == "COLLECTION" else None
    if coll is None or "facecap_blendshapes" not in coll:
        return None
    poses = rom_markers.sheet_poses(settings)
    if not poses:
        raise FacecapError("choose a ROM sheet first (Actor calibration > ROM Sheet)")
    rom = take.calibration_markers(settings, [])
    scores, names = scores_from_collection(coll, rom.frames)
    neutral = metric_neutral(rom)
    if not len(neutral):
        raise FacecapError(f"the ROM take '{coll.name}' has no neutral frames to read its scores from: the clip "
                           "should rest between the poses")
    given = None
    if use_markers:
        rom_markers.check_rom(settings)
        holds = rom_markers.marker_holds(settings.id_data, poses)
        given = None if holds is None else given_indices(holds, rom.frames)
    return ScoreRom(scores, names, rom.frames, neutral, poses, settings.calib_sheet, settings.fps or 30.0, given)


@dataclass(frozen=True)
class GuideRom:
    """A take that followed a guide, as the sidebar has it: the SolveRequest of the take onto the character (no
    scores: the solve the fusion reads), its blendshape ``scores`` (FaceScores), the ``guide`` (a WeightTrack) and
    its file name."""

    request: object
    scores: object
    guide: object
    label: str

    def fit(self):
        """The FollowFit: the take solved (numpy and scipy only), the guide placed in it, its map measured."""
        solved = solve_job(self.request).run()
        return fit_follow(self.guide.values, self.guide.names, self.guide.fps, solved.weights, solved.shape_names,
                          self.scores, guide_label=self.label)


def guide_rom(settings):
    """The Solve panel's calibration take as a guide followed (GuideRom) when a **Guide** is given and the take is a
    landmark take keeping blendshape scores, else None. The take is solved as the Solve panel solves a landmark take
    (its strategy and binding, held on its head-rigid landmarks, its neutral detected, the human template), without
    the panel's calibration poses."""
    path = settings.calib_guide.strip()
    coll = settings.calib_collection if settings.calib_source == "COLLECTION" else None
    if not path:
        return None
    if coll is None or "facecap_blendshapes" not in coll:
        raise FacecapError("a guide followed calibrates a landmark take's blendshape scores: choose the take Track "
                           "Face Landmarks made of the clip under Actor calibration (the Face Landmarker bundle keeps "
                           "its scores)")
    if settings.target is None:
        raise FacecapError("choose the character first: the take is solved onto it as a take is, to be fused")
    guide = read_weights(bpy.path.abspath(path))
    notes = []
    markers = take.calibration_markers(settings, notes)
    scores, names = scores_from_collection(coll, markers.frames)
    rsettings = take.retarget_settings(settings)
    rsettings = replace(rsettings, calibration=type(rsettings.calibration)(), neutral_ranges=(), neutral_detect=True,
                        neutral_file=None, auto_stable=False,  # held on its head-rigid landmarks, as a landmark take
                        stable_markers=tuple(n for n in RIGID if n in markers.names))
    if rsettings.strategy in SAMPLES_CHARACTER:  # bound as the Solve panel binds (not stored: the take is not solved)
        character = geometric_character(settings.target, markers, rsettings, binding_from_sidebar(settings),
                                        store=False).basis
    else:
        character = take.character_target(settings.target)
    neutral = metric_neutral(markers)
    rsettings = replace(rsettings, locks=tuple(rsettings.locks)  # the eyes held as the take's solve holds them
                        + eye_locks(coll, markers.frames, neutral, shape_names(character)))
    request = SolveRequest(character=character, settings=rsettings, markers=markers,
                           inputs=StrategyInputs(template=take.human_template(settings, notes), notes=tuple(notes)))
    fps = markers.fps or settings.fps or 30.0
    return GuideRom(request, FaceScores(scores, names, neutral, fps=fps,
                                        smoothing=bool(settings.video.landmark_smoothing)), guide, Path(path).name)


class RomInBackground(SolveInBackground):
    """*Find Poses* or *Save Performer Profile* (``what``) beside the interface: the scene is read here, the ROM
    take measured on a worker thread (numpy and scipy only), the scene changed only by the operator once it is
    done (``wait`` gives the RomResult)."""

    def __init__(self, settings, *, what, use_markers):
        self.settings, self.what = settings, what
        guide = guide_rom(settings) if use_markers else None  # Save Performer Profile (Find Poses finds a sheet's)
        scores = None if guide is not None else score_rom(settings, use_markers=use_markers)
        if guide is not None:
            self.request, self.frames = guide, guide.request.markers.frames
            self.size = f"the guide {guide.label} in {len(self.frames)} frames (solved, then placed)"
        elif scores is not None:  # a ROM on camera: its holds are found in the scores, or placed by the markers
            self.request, self.frames = scores, scores.frames  # the frames: where the holds found are on the timeline
            self.size = f"{len(scores.poses)} poses of {settings.calib_sheet} in the blendshape scores of " \
                        f"{len(scores.frames)} frames"
        else:
            self.request = rom_request(settings, use_markers=use_markers)
            rom = self.request[2].calibration
            self.size = f"{len(self.request[0].calibration.sequence)} poses of {settings.calib_sheet} in " \
                        f"{rom.n_frames} frames x {rom.n_markers} markers"
        self._begin()

    def _compute(self, request):
        """A ResponseFit for a ROM on camera, a FollowFit for a guide followed, else the RomResult of the marker
        ROM."""
        return request.fit() if isinstance(request, (ScoreRom, GuideRom)) else learn_from_rom_take(*request)

    def status(self):
        return f"{self.what}: measuring {self.size}, {self.seconds():.0f} s; Esc cancels"


def profile_path(filepath):
    """The absolute .npz path of the file browser's ``filepath`` (the suffix added when missing)."""
    path = Path(bpy.path.abspath(filepath))
    return path if path.suffix.lower() == ".npz" else path.with_name(path.name + ".npz")


def check_profile_output(settings, path, *, overwrite):
    """The output policy for the profile (before any work): never the ROM take, the open .blend or the template;
    an existing file only when facecap wrote it (a stored library), or with ``overwrite`` (the user's choice)."""
    if not overwrite and path.is_file() and not is_kind(path, "npz"):
        raise OutputError(f"{path}: exists and is not a performer profile or library facecap wrote; choose another "
                          "name, or tick Overwrite in the file browser to replace it")
    inputs = {"the open .blend": bpy.data.filepath or None}
    if settings.calib_source == "FILE" and settings.calib_path:
        inputs["the ROM take"] = bpy.path.abspath(settings.calib_path)
    template = settings.actor_template.strip()
    if template not in ("", "auto", "none"):
        inputs["the human template"] = bpy.path.abspath(template)
    check_outputs([Output("the performer profile", path, "npz")], {k: v for k, v in inputs.items() if v},
                  overwrite=True)  # the file's kind is judged above, with the sidebar's words


def save_profile(settings, result, path):
    """Write ``result.measured`` (a RomResult's), the score response (a ResponseFit's) or the performer's map (a
    FollowFit's) to ``path`` atomically and make it the Solve panel's performer profile (relative to the .blend,
    ``//...``, when it lies in the .blend's folder)."""
    if isinstance(result, ResponseFit):
        save_response_profile(path, response=result.response)
    elif isinstance(result, FollowFit):
        save_response_profile(path, performer=result.performer)
    else:
        result.measured.save_npz(path)
    settings.actor_profile = bpy.path.relpath(str(path)) if bpy.data.filepath and _below(path) else str(path)


def _below(path):
    """Whether ``path`` lies in the open .blend's folder (a relative path then survives moving both)."""
    folder = os.path.dirname(bpy.path.abspath("//"))
    return bool(folder) and os.path.commonpath([folder, os.path.abspath(path)]) == folder
