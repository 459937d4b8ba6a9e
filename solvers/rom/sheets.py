"""Range-of-motion sheets: the expressions a performer records once, in order, each held from the neutral.

A pose is a label and what it asks of the face as ARKit shape weights (one shape, or a natural expression
that moves several). Two sheets are built in:

* ``facecap-24``: 24 natural expressions (2-3 minutes): the ones anybody can make (a smile, surprise, eyes
  shut, a kiss), each shape of ARKit's 51 asked by at least one, left and right together where people move
  them together.
* ``arkit-51``: a pose per ARKit shape, in ARKit's order (trained performers; about 5 minutes).

A config names one of them or writes its own (``[calibration] sequence``): a list whose items are an ARKit
name (that shape at 1) or a table of shape = weight, with an optional ``label``.
"""

from dataclasses import dataclass

from ..errors import FacecapError

#: ARKit's 51 face shapes (``tongueOut`` aside: no marker sees the tongue), in Apple's documented order.
ARKIT_51 = (
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeSquintLeft",
    "eyeWideLeft", "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
    "eyeSquintRight", "eyeWideRight", "jawForward", "jawLeft", "jawRight", "jawOpen", "mouthClose", "mouthFunnel",
    "mouthPucker", "mouthLeft", "mouthRight", "mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft",
    "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "mouthPressLeft", "mouthPressRight",
    "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft", "mouthUpperUpRight", "browDownLeft",
    "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight", "cheekPuff", "cheekSquintLeft",
    "cheekSquintRight", "noseSneerLeft", "noseSneerRight",
)


@dataclass(frozen=True)
class Pose:
    """One item of a sheet: ``label`` and ``weights`` ((shape, weight), ...) it asks for; ``how`` tells the
    performer what to do (the docs' picture captions)."""

    label: str
    weights: tuple
    how: str = ""

    @property
    def shapes(self):
        return tuple(s for s, _ in self.weights)

    def weight_of(self, shape):
        return dict(self.weights).get(shape, 0.0)


def _both(stem, value=1.0):
    return ((f"{stem}Left", value), (f"{stem}Right", value))


FACECAP_24 = (
    Pose("jaw open", (("jawOpen", 1.0),), "mouth wide open, jaw dropped as far as it goes"),
    Pose("smile", _both("mouthSmile") + _both("cheekSquint", 0.4), "a broad smile, cheeks lifting"),
    Pose("sad", _both("mouthFrown") + (("browInnerUp", 0.6),), "mouth corners down, inner brows up"),
    Pose("surprise", (("browInnerUp", 1.0),) + _both("browOuterUp") + _both("eyeWide"),
         "brows up as high as they go, eyes wide open, mouth relaxed"),
    Pose("angry", _both("browDown") + _both("eyeSquint") + _both("noseSneer", 0.3),
         "brows down and together, lower lids up"),
    Pose("eyes shut", _both("eyeBlink"), "eyes closed gently, the rest relaxed"),
    Pose("look up", _both("eyeLookUp"), "eyes up, head still"),
    Pose("look down", _both("eyeLookDown"), "eyes down, head still"),
    Pose("look left", (("eyeLookOutLeft", 1.0), ("eyeLookInRight", 1.0)), "eyes to your left, head still"),
    Pose("look right", (("eyeLookInLeft", 1.0), ("eyeLookOutRight", 1.0)), "eyes to your right, head still"),
    Pose("sneer", _both("noseSneer") + _both("mouthUpperUp", 0.5), "nose wrinkled, upper lip raised"),
    Pose("kiss", (("mouthPucker", 1.0),), "lips pushed forward in a kiss, mouth closed"),
    Pose("oo", (("mouthFunnel", 1.0), ("jawOpen", 0.2)), "an 'oo': lips rounded and open"),
    Pose("puff", (("cheekPuff", 1.0),), "cheeks blown out, lips sealed"),
    Pose("jaw left", (("jawLeft", 1.0),), "lower jaw to your left"),
    Pose("jaw right", (("jawRight", 1.0),), "lower jaw to your right"),
    Pose("jaw forward", (("jawForward", 1.0),), "lower jaw pushed forward"),
    Pose("mouth left", (("mouthLeft", 1.0),), "closed mouth pulled to your left"),
    Pose("mouth right", (("mouthRight", 1.0),), "closed mouth pulled to your right"),
    Pose("lips in", (("mouthRollUpper", 1.0), ("mouthRollLower", 1.0)), "both lips rolled in over the teeth"),
    Pose("pout", (("mouthShrugLower", 1.0), ("mouthShrugUpper", 0.6)), "chin raised, lower lip pushed up"),
    Pose("press", _both("mouthPress") + _both("mouthDimple", 0.5), "lips pressed together, corners in"),
    Pose("grimace", _both("mouthStretch") + _both("mouthLowerDown", 0.5),
         "teeth shown, mouth stretched wide and down"),
    Pose("closed lips, jaw open", (("jawOpen", 0.5), ("mouthClose", 0.5)), "jaw half open, lips kept together"),
)

ARKIT_SHEET = tuple(Pose(name, ((name, 1.0),), f"{name} alone, as far as it goes") for name in ARKIT_51)

SHEETS = {"facecap-24": FACECAP_24, "arkit-51": ARKIT_SHEET}


def pose_from(item, index, *, where="[calibration] sequence"):
    """A Pose from a config's sequence item ``index`` (0-based): an ARKit name, or a table of shape = weight with
    an optional ``label``."""
    at = f"{where} item {index + 1}"
    if isinstance(item, str):
        if not item.strip():
            raise FacecapError(f"{at}: an empty shape name")
        return Pose(item, ((item, 1.0),))
    if not isinstance(item, dict) or not item:
        raise FacecapError(f"{at}: expected a shape name or a table of shape = weight; got {item!r}")
    label = item.get("label")
    if label is not None and not (isinstance(label, str) and label.strip()):
        raise FacecapError(f"{at}: `label` must be a name; got {label!r}")
    weights = []
    for shape, weight in item.items():
        if shape == "label":
            continue
        if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not 0.0 < weight <= 1.0:
            raise FacecapError(f"{at}: the weight of '{shape}' must be a number in (0, 1]; got {weight!r}")
        weights.append((str(shape), float(weight)))
    if not weights:
        raise FacecapError(f"{at}: names no shape")
    if label is None:
        label = "+".join(s for s, w in sorted(weights, key=lambda sw: -sw[1])[:2])
    return Pose(label, tuple(weights))


def sequence_poses(sequence, *, where="[calibration] sequence"):
    """The poses of ``sequence``: a built-in sheet's name (``SHEETS``) or a list of items (``pose_from``).
    Labels must be unique (they name the holds found)."""
    if isinstance(sequence, str):
        if sequence not in SHEETS:
            raise FacecapError(f"{where}: unknown sheet '{sequence}'; built in: {', '.join(SHEETS)} "
                               "(or a list of poses: shape names or tables of shape = weight)")
        return SHEETS[sequence]
    if not isinstance(sequence, (list, tuple)) or not sequence:
        raise FacecapError(f"{where}: expected a sheet name ({', '.join(SHEETS)}) or a list of poses")
    poses = tuple(pose_from(item, i, where=where) for i, item in enumerate(sequence))
    seen = {}
    for i, p in enumerate(poses):
        if p.label in seen:
            raise FacecapError(f"{where}: items {seen[p.label] + 1} and {i + 1} are both '{p.label}'; give each a "
                               "different `label`")
        seen[p.label] = i
    return poses


def sheet_shapes(poses):
    """Every shape the poses ask for, in first-asked order."""
    out = []
    for p in poses:
        out += [s for s in p.shapes if s not in out]
    return tuple(out)
