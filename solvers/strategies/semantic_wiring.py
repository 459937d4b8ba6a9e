"""The ``semantic`` strategy built from the pipeline's settings and inputs: what is known of the actor
(calibration take or poses labelled in the take, a performer profile, the human template) and the
character's shapes carried into actor space."""

import warnings

import numpy as np

from ..capture.noise import marker_noise, shrink_pose_noise
from ..character.basis import Basis
from ..errors import FacecapError
from .actor_model import ActorKnowledge
from .calibrated import actor_basis_from_poses
from .actor_space import character_in_actor_space, fit_template
from .rom_wiring import learn_from_rom_take
from .semantic import SemanticStrategy

def poses_in_take(take, poses, neutral_frames=None):
    """Poses labelled in the take itself: the median of the take's deltas over each pose's frames (a Basis
    in the take's own actor space), each marker's noise shrunk (``shrink_pose_noise``; the neutral's
    samples counted over ``neutral_frames`` (first, last) when given)."""
    names, deltas, counts = [], [], []
    for pose, ranges in poses.items():
        sel = np.zeros(take.frames.size, dtype=bool)
        for first, last in ranges:
            sel |= (take.frames >= first) & (take.frames <= last)
        if not sel.any():
            raise FacecapError(f"[calibration.poses] pose '{pose}' frames {ranges} are outside the take "
                               f"({take.frames[0]:g}-{take.frames[-1]:g})")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a marker never seen in the pose: delta 0
            d = np.nanmedian(take.deltas[sel], axis=0)
        names.append(pose)
        deltas.append(np.nan_to_num(d))
        counts.append(np.isfinite(take.deltas[sel][:, :, 0]).sum(axis=0))
    rest = np.inf
    if neutral_frames:
        first, last = neutral_frames
        rest = np.isfinite(take.deltas[(take.frames >= first) & (take.frames <= last)][:, :, 0]).sum(axis=0)
    shrunk = shrink_pose_noise(np.stack(deltas), np.stack(counts), rest, marker_noise(take.deltas))
    return Basis(tuple(names), take.names, take.neutral, shrunk)


def fit_semantic(settings, character, inputs, take, *, priors):
    """A fitted SemanticStrategy for ``take`` (a PreparedTake) and ``character`` (a Basis, or shape names);
    returns (strategy, notes)."""
    notes = []
    cal = settings.calibration
    measured = rom = None
    char_deltas, align, bound = character_in_actor_space(character, take.names, take.neutral, settings)
    if cal.sequence:
        rom = learn_from_rom_take(settings, character, inputs, take)
        measured = rom.measured
        notes.extend(rom.notes)
    elif inputs.calibration is not None and cal.poses:
        measured, pose_notes = actor_basis_from_poses(
            inputs.calibration, poses=cal.pose_table(), neutral=tuple(cal.neutral_frames or settings.neutral_frames),
            stable_markers=tuple(cal.stable_markers or settings.stable_markers), split=tuple(cal.split))
        notes.extend(pose_notes)
    elif cal.poses:
        # the neutral's own samples count only where it is that frame range (not detected, ranges, a file)
        plain = not (settings.neutral_detect or settings.neutral_ranges or settings.neutral_file is not None
                     or settings.master is not None)
        measured = poses_in_take(take, cal.pose_table(), settings.neutral_frames if plain else None)
    profile = inputs.profile if inputs.profile is not None else inputs.actor_basis
    template = None
    if inputs.template is not None:
        template = fit_template(inputs.template, take.names, take.neutral, align)
    a = settings.actor
    knowledge = ActorKnowledge(measured=measured, profile=profile, template=template, unseen=a.unseen_shapes,
                               normalise=a.normalise)
    if char_deltas is None and measured is None and profile is None and template is None:
        raise FacecapError("strategy 'semantic' has nothing to solve against: the character has no markers bound "
                           "(vertex groups or [binding]) and nothing is known of the actor ([calibration] poses, "
                           "[actor] profile or [actor] template)")
    s = SemanticStrategy(**priors, exclusive=a.exclusive)
    s.fit(character, names=take.names, neutral=take.neutral, knowledge=knowledge, character_deltas=char_deltas,
          deltas=take.deltas, noise=marker_noise(take.deltas), alignment=align, alignment_names=bound,
          bounds=settings.bounds, locks=settings.locks, regions=settings.regions)
    s.rom = rom
    return s, notes
