"""Shape-name aliases: ARKit camelCase is the canonical vocabulary.

Every name a capture tool writes is reduced to zero or more canonical ARKit names:

- ARKit camelCase (``eyeBlinkLeft``), Live Link Face / Unreal capitalised names (``EyeBlinkLeft``),
  MediaPipe face-landmarker categories (``eyeBlinkLeft``; ``_neutral`` maps to nothing),
  ARKit's raw location strings and rig conventions (``eyeBlink_L``, ``eye_blink_left``,
  ``EyeBlink.L``, ``eyeBlinkL``) — all by a case- and separator-insensitive key;
- FACS action units (``AU45``, ``au12_L``, ``AU12L``, ``L12``, ``R12``): an action unit without a
  side drives both sides (``AU45 -> eyeBlinkLeft, eyeBlinkRight``), one with a side drives that
  side only; ``AU26`` (jaw drop) and ``AU27`` (mouth stretch) both mean ``jawOpen``.

Names that are neither (a character's own shapes, ``smile_big``) match only themselves, by the
same case- and separator-insensitive key. ``match_names`` builds the source -> target pairs that
the ``calibrated`` and ``parallel`` strategies turn into a mapping matrix.
"""

import re

from ..io.arkit import ARKIT_52

#: FACS action unit -> ARKit shapes (base names; "Left"/"Right" are appended for sided entries).
#: Sided entries end in "*"; the action unit without a side drives both.
FACS_TO_ARKIT = {
    1: ("browInnerUp",),
    2: ("browOuterUp*",),
    4: ("browDown*",),
    5: ("eyeWide*",),
    6: ("cheekSquint*",),
    7: ("eyeSquint*",),
    9: ("noseSneer*",),
    10: ("mouthUpperUp*",),
    12: ("mouthSmile*",),
    14: ("mouthDimple*",),
    15: ("mouthFrown*",),
    16: ("mouthLowerDown*",),
    17: ("mouthShrugLower",),
    18: ("mouthPucker",),
    19: ("tongueOut",),
    20: ("mouthStretch*",),
    22: ("mouthFunnel",),
    24: ("mouthPress*",),
    26: ("jawOpen",),
    27: ("jawOpen",),
    28: ("mouthRollLower", "mouthRollUpper"),
    29: ("jawForward",),
    34: ("cheekPuff",),
    43: ("eyeBlink*",),
    45: ("eyeBlink*",),
    46: ("eyeBlink*",),
    61: ("eyeLookOutLeft", "eyeLookInRight"),  # eyes turn left (subject's left)
    62: ("eyeLookInLeft", "eyeLookOutRight"),  # eyes turn right
    63: ("eyeLookUp*",),
    64: ("eyeLookDown*",),
}

_SIDES = {"left": "Left", "l": "Left", "right": "Right", "r": "Right"}
_AU = re.compile(r"^(?:au)?(\d{1,2})(l|r|left|right)?$")
_SIDE_FIRST_AU = re.compile(r"^(l|r)(\d{1,2})$")
_IGNORED = {"neutral", "basis", "timecode", "blendshapecount"}


def name_key(name):
    """Case- and separator-insensitive key: ``"Eye_Blink.L" -> "eyeblinkl"``."""
    return re.sub(r"[^0-9a-z]", "", str(name).lower())


def _arkit_key_table():
    table = {}
    for name in ARKIT_52:
        table[name_key(name)] = name
        for side, short in (("Left", "l"), ("Right", "r")):
            if name.endswith(side):
                table[name_key(name[: -len(side)]) + short] = name  # eyeBlink_L, eyeBlinkL
                table[short + name_key(name[: -len(side)])] = name  # L_eyeBlink
    return table


_ARKIT_KEYS = _arkit_key_table()


def _expand_facs(unit, side):
    entries = FACS_TO_ARKIT.get(unit)
    if entries is None:
        return ()
    out = []
    for entry in entries:
        if entry.endswith("*"):
            base = entry[:-1]
            sides = ("Left", "Right") if side is None else (side,)
            out.extend(base + s for s in sides)
        elif side is None or entry.endswith(side) or not entry.endswith(("Left", "Right")):
            out.append(entry)
    return tuple(out)


def canonical_names(name):
    """The ARKit names a source name stands for (empty tuple if none).

    >>> canonical_names("EyeBlinkLeft")
    ('eyeBlinkLeft',)
    >>> canonical_names("AU45")
    ('eyeBlinkLeft', 'eyeBlinkRight')
    """
    key = name_key(name)
    if key in _ARKIT_KEYS:
        return (_ARKIT_KEYS[key],)
    sep = re.sub(r"[\s.\-]", "_", str(name).lower())  # keep "_" to split AU12_L
    parts = [p for p in sep.split("_") if p]
    compact = "".join(parts)
    m = _AU.match(compact) if compact.startswith("au") or compact[:1].isdigit() else None
    if m:
        return _expand_facs(int(m.group(1)), _SIDES.get(m.group(2)) if m.group(2) else None)
    m = _SIDE_FIRST_AU.match(compact)
    if m:
        return _expand_facs(int(m.group(2)), _SIDES[m.group(1)])
    return ()


def is_ignored(name):
    """Channels that never drive a shape (``_neutral``, ``Timecode``, ``BlendShapeCount``)."""
    return name_key(name) in _IGNORED


def match_names(source_names, target_names, *, aliases=True):
    """Source -> target correspondences by name.

    Parameters
    ----------
    source_names, target_names : sequence of str
    aliases : bool
        If False, only identical keys (``name_key``) match.

    Returns
    -------
    pairs : list of (i, j)
        Source channel i drives target shape j (gain 1). A source may drive several targets
        (FACS units without a side); several sources may drive one target.
    unmatched_sources : list of str
        Source names that drive nothing (ignored channels such as ``_neutral`` are left out).
    unmatched_targets : list of str
        Target shapes that nothing drives.
    """
    target_by_key = {}
    target_by_arkit = {}
    for j, name in enumerate(target_names):
        target_by_key.setdefault(name_key(name), j)
        canon = canonical_names(name) if aliases else ()
        if len(canon) == 1:  # a target shape stands for one ARKit shape (never a two-sided AU)
            target_by_arkit.setdefault(canon[0], j)
    pairs = []
    unmatched = []
    for i, name in enumerate(source_names):
        hits = []
        if name_key(name) in target_by_key:
            hits = [target_by_key[name_key(name)]]
        elif aliases:
            hits = [target_by_arkit[c] for c in canonical_names(name) if c in target_by_arkit]
        if hits:
            pairs.extend((i, j) for j in dict.fromkeys(hits))
        elif not is_ignored(name):
            unmatched.append(name)
    driven = {j for _, j in pairs}
    unmatched_targets = [n for j, n in enumerate(target_names) if j not in driven]
    return pairs, unmatched, unmatched_targets


def mirror_name(name):
    """The other side's name (``eyeBlinkLeft <-> eyeBlinkRight``, ``jawLeft <-> jawRight``,
    ``brow_L <-> brow_R``); unchanged if the name has no side."""
    for a, b in (("Left", "Right"), ("left", "right"), ("LEFT", "RIGHT")):
        if name.endswith(a):
            return name[: -len(a)] + b
        if name.endswith(b):
            return name[: -len(b)] + a
    for a, b in (("_L", "_R"), (".L", ".R"), ("_l", "_r"), (".l", ".r")):
        if name.endswith(a):
            return name[: -len(a)] + b
        if name.endswith(b):
            return name[: -len(b)] + a
    return name
