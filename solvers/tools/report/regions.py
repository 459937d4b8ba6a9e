"""Markers grouped by face region, for the review page's heat map: an animator reads "the mouth is off",
not "marker 41 is off".

A marker's region comes from its name when the name says it (``brow_inner_L``, ``lip_upper_C``,
``LeftCheek``...), otherwise from its height on the character's face (``section7-2``, ``BL2``): the
bound points' vertical extent is cut into an upper, middle and lower face. Stable markers form their
own group (they carry the head, not the expression).
"""

import re

import numpy as np

#: Regions by name, in face order (top to bottom), each with the words that put a marker in it. The
#: first region whose word starts a word of the name (split at _ - . space and camelCase) wins.
NAMED = (
    ("forehead and brows", ("forehead", "brow", "glabella", "frown", "corrugator")),
    ("eyes", ("eye", "lid", "eyelid", "lash", "orbit", "squint", "canthus", "lacrimal")),
    ("nose", ("nose", "nasal", "nostril", "alar", "ala", "sneer", "bridge")),
    ("cheeks", ("cheek", "cheekbone", "zyg", "malar", "puff", "nasolabial", "dimple", "under")),
    ("mouth", ("mouth", "lip", "lips", "corner", "philtrum", "smile", "oral")),
    ("jaw and chin", ("jaw", "chin", "mentalis", "mandible", "menton")),
)
#: Regions by height, for names that say nothing (top to bottom).
BY_HEIGHT = ("upper face", "middle face", "lower face")
STABLE = "head (stable)"
OTHER = "other"
ORDER = (STABLE,) + tuple(r for r, _ in NAMED) + BY_HEIGHT + (OTHER,)


def _words(name):
    spaced = re.sub(r"([a-z])([A-Z])", r"\1 \2", name)
    return [w for w in re.split(r"[\s_.\-]+|\d+", spaced.lower()) if w]


def region_by_name(name):
    """The region a marker's name says, or None."""
    words = _words(name)
    for region, keys in NAMED:
        if any(w.startswith(k) for w in words for k in keys):
            return region
    return None


def face_regions(names, *, stable=(), points=None, up=(0.0, 0.0, 1.0)):
    """``[(region, [names])]`` in face order, top to bottom; within a region the markers top to bottom
    (by ``points`` (M, 3) when given: their heights along ``up``) then by name.

    ``stable``: the stable markers (their own group first). ``points``: each marker's position on the
    character (NaN rows: unknown), for markers whose names say nothing.
    """
    names = list(names)
    height = np.full(len(names), np.nan) if points is None else np.asarray(points, dtype=np.float64) @ np.asarray(up)
    known = np.isfinite(height)
    lo, hi = (float(height[known].min()), float(height[known].max())) if known.any() else (0.0, 1.0)
    stable = set(stable)
    groups = {}
    for i, name in enumerate(names):
        if name in stable:
            region = STABLE
        else:
            region = region_by_name(name)
        if region is None and known[i] and hi > lo:
            band = min(2, int(3 * (hi - height[i]) / (hi - lo)))  # top third first
            region = BY_HEIGHT[band]
        groups.setdefault(region or OTHER, []).append(i)
    out = []
    for region in ORDER:
        members = groups.get(region)
        if members:
            members.sort(key=lambda i: (-height[i] if known[i] else np.inf, names[i]))
            out.append((region, [names[i] for i in members]))
    return out
