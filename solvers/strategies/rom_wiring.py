"""What the semantic solve learns from a range-of-motion session ([calibration] sequence): the ROM take (the
calibration take, or the take itself) stabilised and its neutral found, its poses found and named by the sheet
against a prior (the human template fitted to its neutral, else the character's shapes carried to it), and the
actor's shapes estimated from them (``rom``)."""

from dataclasses import dataclass, replace

import numpy as np

from ..capture.neutral import neutral_from_frames
from ..capture.normalise import detect_neutral_frames
from ..capture.stabilise import stabilise_rigid
from ..errors import FacecapError
from ..rom import find_poses, fit_rom, prior_for, sheet_shapes
from .actor_space import character_in_actor_space, fit_template
from .base import PreparedTake, as_target

#: Frames at most that the ROM's neutral is detected from.
DETECT_FRAMES = 2000


@dataclass(frozen=True, eq=False)
class RomResult:
    """The actor's ``measured`` shapes (a Basis, the ROM take's actor space), the poses ``found`` (RomPoses),
    the joint ``fit``, ``notes`` (warnings: poses not found, expressions left out) and a one-line ``summary``;
    ``prior`` says what named the poses."""

    measured: object
    found: object
    fit: object
    prior: str
    notes: tuple
    summary: str = ""

    def report(self):
        out = self.found.report()
        out["summary"] = self.summary
        out["prior"] = self.prior
        out["measured_shapes"] = len(self.measured.shape_names)
        out["completed_from_prior"] = [n for n in sheet_shapes(self.found.poses) if n not in self.measured.shape_names]
        out["gains"] = {n: round(float(g), 3) for n, g in zip(sheet_shapes(self.found.poses), self.fit.gains)}
        return out


def prepare_rom(markers, stable, neutral_frames):
    """The ROM take (a MarkerSet, 3D) as a PreparedTake: stabilised on ``stable`` markers, its neutral the
    ``neutral_frames`` (first, last) or, when None, the pose it returns to between the expressions; and where the
    neutral came from (words)."""
    if markers.dim != 3:
        raise FacecapError("[calibration] sequence: a ROM take must be 3D markers (a filmed ROM calibrates video "
                           "takes through the video path)")
    if len(stable) < 3:
        raise FacecapError("[calibration] sequence: the ROM take is stabilised on at least 3 stable markers "
                           "([calibration] stable_markers or [stabilise] markers)")
    markers = markers.to_units("m")
    stab = stabilise_rigid(markers, tuple(stable), reference_frames=neutral_frames)
    sm = stab.markers
    if neutral_frames is None:  # every few frames: a long session's rests are long (the whole take: seconds)
        step = max(1, sm.n_frames // DETECT_FRAMES)
        frames, _ = detect_neutral_frames(replace(sm, frames=sm.frames[::step], positions=sm.positions[::step]))
        sel = np.isin(sm.frames, frames)
        with np.errstate(invalid="ignore"):
            neutral = np.nanmedian(sm.positions[sel], axis=0)
        where = f"the neutral detected from {len(frames)} frames (the face at rest between the poses)"
    else:
        neutral = neutral_from_frames(sm, *neutral_frames)
        where = f"the neutral of frames {neutral_frames[0]}-{neutral_frames[1]}"
    return PreparedTake(sm.positions - neutral[None], neutral, sm.names, sm.frames, stab, fps=sm.fps), where


def rom_prior(shapes, rom, character_deltas, template_fit):
    """(K, M, 3) the prior for ``shapes`` at the ROM's markers and what it is: the template's shapes where it has
    them, else the character's."""
    sources = []
    if template_fit is not None:
        sources.append((template_fit.shape_names, template_fit.deltas))
    if character_deltas is not None:
        sources.append(character_deltas)
    prior, have = prior_for(shapes, rom.names, sources)
    what = ("the human template" if template_fit is not None else "the character's shapes") if have.any() else "none"
    return prior, what


def learn_from_rom(settings, rom, character_deltas, template_fit):
    """A RomResult for the PreparedTake ``rom``; ``character_deltas``: (shape names, (K, M, 3)) the
    character's shapes carried to the ROM's markers or None; ``template_fit``: the template fitted to it or None."""
    cal = settings.calibration
    shapes = sheet_shapes(cal.sequence)
    prior, what = rom_prior(shapes, rom, character_deltas, template_fit)
    given = None if cal.holds is None else dict(cal.holds)
    found = find_poses(rom, cal.sequence, prior, fps=rom.fps or 60.0, given=given)
    measured, fit = fit_rom(found, prior)
    summary = (f"{int(found.found.sum())} of {len(cal.sequence)} poses {'placed' if given else 'found'} "
               f"({len(found.holds)} holds in the take), named against {what}; {len(measured.shape_names)} shapes "
               "measured")
    return RomResult(measured, found, fit, what, found.notes, summary)


def rom_settings_for_take(settings, take=None):
    """The ROM's stable markers and neutral frames: [calibration]'s, else the take's (or [stabilise]'s)."""
    cal = settings.calibration
    stable = tuple(cal.stable_markers) or (take.stabilise.stable_names if take is not None and take.stabilise
                                           is not None else tuple(settings.stable_markers))
    neutral = tuple(cal.neutral_frames) if cal.neutral_frames else None
    return stable, neutral


def learn_from_rom_take(settings, character, inputs, take=None):
    """A RomResult from the [calibration] markers take (``inputs.calibration``), or from ``take`` itself (a
    PreparedTake with its own neutral) when there is none; the prior is the template (``inputs.template``) fitted
    to the ROM's neutral where given, else ``character``'s shapes (a Basis with markers bound) carried to it.
    What a performer profile is made of (``RomResult.measured``), here or in a take's semantic solve."""
    if inputs.calibration is not None:
        stable, neutral = rom_settings_for_take(settings, take)
        rom, where = prepare_rom(inputs.calibration, stable, neutral)
    elif take is not None:
        rom, where = take, "the take's own neutral"
    else:
        raise FacecapError("[calibration] sequence: no ROM take ([calibration] markers)")
    char_deltas, align, _ = character_in_actor_space(character, rom.names, rom.neutral, settings)
    template = None if inputs.template is None else fit_template(inputs.template, rom.names, rom.neutral, align)
    character_shapes = None if char_deltas is None else (as_target(character).names, char_deltas)
    result = learn_from_rom(settings, rom, character_shapes, template)
    return replace(result, summary=f"{result.summary}; {where}")

