"""The one solve path. Every front end describes its take as a ``SolveRequest`` and runs it here:
the sidebar's *Solve and Key*, *Retune* and *Solve from Clip Flow* (``facecap_addon.scene.scene_solve``)
and the command line's ``retarget``, ``tune`` and video retarget (``facecap_addon.headless.headless``).

A request carries the take (markers, or footage for flow features; solved weights ride in
``inputs.weights`` for ``parallel``), the character, the settings and inputs, and optionally a
stored library version to solve with, the animator's corrections to retune from, and per-shape
controls applied to the weights. The result is always a ``RetargetResult`` (``pipeline.result``).
"""

from dataclasses import dataclass, replace

import numpy as np

from .character.shape_controls import apply_controls, locks_from_controls
from .errors import FacecapError
from .pipeline import retarget
from .strategies.options import StrategyInputs
from .tuning.take import apply_version, retune_take
from .video.flow_solve import retarget_flow_job
from .video.fusion import SMOOTHING_S, FusionTable, fuse
from .video.reading import Job


@dataclass(frozen=True, eq=False)
class SolveRequest:
    """What one solve needs, whichever front end built it.

    character : Basis (geometric: the shapes at the bound points) or Target / shape names
    settings : RetargetSettings
    inputs : StrategyInputs (calibration, examples, training take, or the solved weights of ``parallel``)
    markers : MarkerSet of a marker take (None for ``parallel`` and video takes)
    footage : solvers.video.Footage of a video take (flow features; with ``flow``, FlowSolveSettings)
    version : tuning.take.LibraryVersion to solve with instead of what the inputs give
    corrections : {frame: {shape: value}} the animator set: retune from them, then re-solve
    mu, parent : the retune's prior (None: automatic) and the name of the version solved with
    controls : {shape or glob: ShapeControl} applied to the solved weights; their locks hold shapes
        in the solve
    fps : frame rate for the controls' smoothing (default: the take's)
    rig : solvers.rig.RigTarget when the character is a rig: its basis is solved, then its controls
        (shape names are then control names: corrections, controls and locks name controls)
    scores : video.fusion.FaceScores of a landmark take: the Face Landmarker's blendshape scores, combined
        with the solve (``video.fusion.fuse``) before the controls
    notes : warnings of building the request (shape keys left out...), put before the solve's
    """

    character: object
    settings: object
    inputs: StrategyInputs = StrategyInputs()
    markers: object = None
    footage: object = None
    flow: object = None
    version: object = None
    corrections: dict = None
    mu: float = None
    parent: str = ""
    controls: dict = None
    fps: float = None
    rig: object = None
    scores: object = None
    notes: tuple = ()


def solve(request, progress=None):
    """Run ``request`` to the end; ``progress(done, total) -> bool`` (False cancels) sees footage
    frames. Returns a RetargetResult (``result.retune`` holds the retune when corrections were given)."""
    return solve_job(request).run(progress)


def solve_job(request):
    """``solve`` as a ``Job`` that advances a footage frame per step (the modal operators and the
    CLI's Ctrl-C); a marker take is one step. Everything is validated before the first step."""
    character, inputs, settings = request.character, request.inputs, request.settings
    rig, corrections = request.rig, request.corrections
    if rig is not None:
        character, corrections = rig.character, rig.offsets_of(corrections)
    if request.version is not None:
        character, inputs, settings = apply_version(request.version, character, inputs, settings)
    if request.controls:
        names = character.shape_names if hasattr(character, "shape_names") else _names(character)
        settings = replace(settings, locks=tuple(settings.locks) + locks_from_controls(request.controls, names))
    if rig is not None and request.markers is not None:  # locks and bounds in control values -> the columns'
        settings = rig.column_settings(settings, request.markers.n_frames)
    if request.footage is not None:
        if request.corrections is not None:
            raise FacecapError("tuning a video take from corrections is not supported yet; use the shape controls")

        job = retarget_flow_job(request.footage, character, inputs.examples, settings=settings, flow=request.flow)
        fps = request.footage.info.fps
        return job.then(lambda result: _with_controls(result, request, fps))

    # a nonlinear rig solve refits the head against the rig itself (solvers.rig.head), not against the
    # linear solve, and starts from frames solved alone with the ridge only (its Gauss-Newton steps
    # carry the temporal term and the sparsity; a retune keeps the priors it learns with)
    linear_settings = settings
    if rig is not None and rig.defers_head_refits:
        linear_settings = replace(settings, fine_iterations=0)
        if corrections is None:
            linear_settings = replace(linear_settings, smoothing=(0.0, 0.0), sparsity=0.0)

    def steps():
        result = retarget(request.markers, character, linear_settings, inputs=inputs)
        solved_with = character
        if corrections is not None:
            tuned = retune_take(request.markers, character, linear_settings, inputs, corrections, mu=request.mu,
                                base=result, parent=request.parent)
            result = replace(tuned.result, retune=tuned)
            if tuned.changed:
                solved_with = apply_version(tuned.version, character, inputs, linear_settings)[0]
        yield None
        if rig is not None:  # a library version (chosen, or the retune's) moves the rig model too
            result = yield from rig.with_columns(solved_with).finish_steps(result, request.markers, settings)
        if request.scores is not None:  # a rig: its controls that read as shape weights alone
            result = _fused(result, request.scores, None if rig is None else rig.weight_controls)
        return _with_controls(result, request, _take_fps(request))

    return Job(steps(), 1 + (rig.steps_for(settings) if rig is not None else 0), what="solve")


def _names(character):
    return tuple(getattr(character, "names", character))


def _take_fps(request):
    if request.markers is not None:
        return request.markers.fps
    return getattr(request.inputs.weights, "fps", None)


def _fused(result, scores, only=None):
    """``result`` with the blendshape scores combined into its weights (``video.fusion``): every shape, or the
    shapes named in ``only``."""
    table = FusionTable.load()
    shapes = list(result.shape_names)
    columns = [k for k, n in enumerate(shapes) if only is None or n in only]
    if not columns:
        return result
    weights = np.array(result.weights, dtype=np.float64)
    weights[:, columns], names = fuse(weights[:, columns], tuple(shapes[k] for k in columns), scores, table=table)
    if not names:
        return result
    fusion = {"shapes": list(names), "neutral_frames": int(len(scores.neutral)),
              "smoothing_s": round(SMOOTHING_S, 4) if scores.smoothing and scores.fps else 0.0,
              "lids_against_gaze": round(table.lid_gaze, 4),
              "what": "the Face Landmarker's blendshape scores combined with the landmark solve (docs/video.md)"}
    return replace(result, weights=weights, info={**result.info, "fusion": fusion})


def _with_controls(result, request, fps):
    if request.notes:
        result = replace(result, warnings=tuple(dict.fromkeys(tuple(request.notes) + tuple(result.warnings))))
    if not request.controls:
        return result
    fps = request.fps or fps
    return replace(result, weights=apply_controls(result.weights, result.shape_names, request.controls, fps))
