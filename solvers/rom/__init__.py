"""Range-of-motion sessions: the sheets a performer follows (``sheets``), the holds found in the take
(``holds``), named by the sheet (``matching``), and the actor's shapes estimated from them together with what
each pose really gave (``joint``); ``session`` ties them together."""

from .holds import Hold, find_holds
from .joint import JointFit, fit_examples
from .matching import Alignment, align_holds
from .session import RomPoses, asked_weights, find_poses, fit_rom, prior_for
from .sheets import ARKIT_51, SHEETS, Pose, sequence_poses, sheet_shapes

__all__ = ["ARKIT_51", "SHEETS", "Alignment", "Hold", "JointFit", "Pose", "RomPoses", "align_holds",
           "asked_weights", "find_holds", "find_poses", "fit_examples", "fit_rom", "prior_for", "sequence_poses",
           "sheet_shapes"]
