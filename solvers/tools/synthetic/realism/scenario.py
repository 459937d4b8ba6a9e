"""One draw of the realism benchmark: a perturbed actor of a face family, a layout, a real performance
captured with head motion, noise and gaps, and the actor's calibration sessions."""

from dataclasses import dataclass

import numpy as np

from ....rom.sheets import SHEETS
from .actors import Perturbation, make_actor
from .families import ActorFamily, ict_family
from .layouts import layout as make_layout
from .rom import rom_session
from .takes import REST, CaptureSettings, calibration_weights, capture, performance_segment

#: The short calibration a user can afford: 12 poses (jaw, smiles, funnel, pucker, blinks, brows, close, puff).
FEW_POSES = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "mouthFunnel", "mouthPucker", "eyeBlinkLeft",
             "eyeBlinkRight", "browInnerUp", "browDownLeft", "browDownRight", "mouthClose", "cheekPuff")


#: The ROM sheets every draw's actor performs.
ROM_SHEETS = ("facecap-24", "arkit-51")


@dataclass(frozen=True, eq=False)
class Draw:
    """A take with its truth, and what a user could know about the actor."""

    seed: int
    layout: object  # Layout
    actor: object  # ActorFace
    markers: object  # MarkerSet (mm)
    truth: np.ndarray  # (F, K) weights on ``shape_names``
    shape_names: tuple
    description: str
    calibration: object  # MarkerSet: one pose per shape
    calibration_poses: dict
    few: object  # MarkerSet: the 12 poses of FEW_POSES
    few_poses: dict
    roms: dict = None  # {sheet name: RomSession}, performed imperfectly (``rom``)

    @property
    def performance_frames(self):
        """(F,) bool: the frames after the neutral hold (where the metrics are taken)."""
        return np.arange(len(self.truth)) >= REST


def make_draw(family, performances, seed, *, layout="dense", frames=1200, perturbation=Perturbation(),
              capture_settings=CaptureSettings()):
    """Draw number ``seed`` of an actor of ``family`` (an ActorFamily, or the ICT FaceModel for its own) in
    ``layout`` (a name of ``layouts.LAYOUTS``) with ``frames`` at 60 fps; ``performances`` on the family's shapes."""
    family = family if isinstance(family, ActorFamily) else ict_family(family)
    model = family.model
    rng = np.random.default_rng(seed)
    lay = make_layout(layout, family.landmarks68, family.dense)
    actor = make_actor(model, lay.vertices, lay.names, seed=int(rng.integers(1 << 31)), perturbation=perturbation)
    weights, description = performance_segment(performances, frames, rng)
    markers = capture(actor, weights, rng, settings=capture_settings, stable=lay.stable,
                      source=f"realism draw {seed} ({layout})")
    calib_w, calib_poses = calibration_weights(model.shape_names, model.shape_names, rng)
    quiet = CaptureSettings(max_deg=capture_settings.max_deg, max_offset=capture_settings.max_offset,
                            noise=capture_settings.noise, gaps=capture_settings.gaps / 4)
    calibration = capture(actor, calib_w, rng, settings=quiet, stable=lay.stable, source=f"calibration {seed}")
    few_w, few_poses = calibration_weights(model.shape_names, FEW_POSES, rng)
    few = capture(actor, few_w, rng, settings=quiet, stable=lay.stable, source=f"short calibration {seed}")
    roms = {}
    for i, sheet in enumerate(ROM_SHEETS):  # streams of their own: the draws above stay as they were
        roms[sheet] = rom_session(actor, SHEETS[sheet], np.random.default_rng([seed, 37, i]), stable=lay.stable,
                                  capture_settings=capture_settings, source=f"ROM {sheet} {seed}")
    return Draw(seed, lay, actor, markers, weights, model.shape_names, description, calibration, calib_poses,
                few, few_poses, roms)
