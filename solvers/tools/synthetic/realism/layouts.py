"""Marker layouts on the ICT face, as a studio would place them: vertex indices by marker name.

``dense``: the sample character's 68-marker layout without the two markers beside the ears (66: six
head markers on the skin of the forehead, temples and nose bridge, 60 on the moving face), so the
sample character binds by its vertex groups. ``sparse``: 34 of them (a typical optical face set).
``landmarks68``: the 68 Multi-PIE landmarks of a video face tracker (``lm00``-``lm67``), bound to a
character by position. Indices were chosen by a thin-plate warp of the sample character's markers onto
the ICT neutral through 15 landmark pairs, then the nearest vertex, and checked by which expressions move
them (upper lids move with blinks, lower lips with the jaw).
"""

from dataclasses import dataclass

DENSE_VERTICES = {
    "head_forehead_C": 1643, "head_forehead_L": 3510, "head_forehead_R": 1292, "head_temple_L": 3518,
    "head_temple_R": 1300, "head_nose_bridge_C": 978, "forehead_L": 3946, "forehead_R": 1743,
    "brow_inner_L": 3615, "brow_inner_R": 1401, "brow_mid_L": 4114, "brow_mid_R": 1914, "brow_outer_L": 2509,
    "brow_outer_R": 268, "eyelid_upper_L": 3756, "eyelid_upper_R": 1542, "eyelid_upper_outer_L": 2946,
    "eyelid_upper_outer_R": 705, "eyelid_lower_L": 3316, "eyelid_lower_R": 1096, "eye_outer_L": 3096,
    "eye_outer_R": 855, "under_eye_L": 3381, "under_eye_R": 1162, "cheekbone_L": 3419, "cheekbone_R": 1201,
    "cheek_L": 4403, "cheek_R": 2212, "cheek_lower_L": 4396, "cheek_lower_R": 2205, "nasolabial_L": 2702,
    "nasolabial_R": 461, "nose_side_L": 4462, "nose_side_R": 4457, "nostril_L": 3360, "nostril_R": 1140,
    "nose_tip_C": 4857, "philtrum_C": 2189, "mouth_above_L": 2642, "mouth_above_R": 401, "lip_upper_C": 0,
    "lip_upper_L": 6242, "lip_upper_R": 5737, "lip_upper_outer_L": 6080, "lip_upper_outer_R": 5575,
    "mouth_corner_L": 6213, "mouth_corner_R": 5708, "lip_lower_C": 5518, "lip_lower_L": 6481, "lip_lower_R": 5977,
    "lip_lower_outer_L": 6346, "lip_lower_outer_R": 5841, "dimple_L": 2709, "dimple_R": 468, "mouth_below_L": 2443,
    "mouth_below_R": 202, "chin_upper_C": 968, "chin_C": 966, "chin_L": 3656, "chin_R": 1442, "jaw_front_L": 2483,
    "jaw_front_R": 242, "jaw_L": 2477, "jaw_R": 236, "jaw_angle_L": 3667, "jaw_angle_R": 1453,
}
DENSE_HEAD = ("head_forehead_C", "head_forehead_L", "head_forehead_R", "head_temple_L", "head_temple_R",
              "head_nose_bridge_C")
SPARSE = (
    "head_forehead_L", "head_forehead_R", "head_temple_L", "head_temple_R", "head_nose_bridge_C",
    "brow_inner_L", "brow_inner_R", "brow_outer_L", "brow_outer_R", "eyelid_upper_L", "eyelid_upper_R",
    "eyelid_lower_L", "eyelid_lower_R", "cheekbone_L", "cheekbone_R", "cheek_L", "cheek_R", "nasolabial_L",
    "nasolabial_R", "nostril_L", "nostril_R", "lip_upper_C", "lip_upper_outer_L", "lip_upper_outer_R",
    "mouth_corner_L", "mouth_corner_R", "lip_lower_C", "lip_lower_outer_L", "lip_lower_outer_R", "chin_C",
    "jaw_L", "jaw_R", "mouth_below_L", "mouth_below_R",
)
#: Landmarks a video tracker's user would stabilise on: the nose bridge, the eye corners, the temples' contour.
LANDMARK_STABLE = (0, 1, 15, 16, 27, 28, 36, 39, 42, 45)
#: What a user gives when the automatic binding of the landmarks refuses: landmark -> the characters' vertex
#: group (nose tip, chin, mouth corners, inner brows).
LANDMARK_PAIRS = (("lm30", "nose_tip_C"), ("lm08", "chin_C"), ("lm48", "mouth_corner_R"), ("lm54", "mouth_corner_L"),
                  ("lm21", "brow_inner_R"), ("lm22", "brow_inner_L"))


@dataclass(frozen=True)
class Layout:
    """A marker layout on a face model: ``names`` and their ``vertices``; ``stable`` names the markers
    a user would stabilise on; ``by_position`` says a character binds it by position (no vertex groups)."""

    name: str
    names: tuple
    vertices: tuple
    stable: tuple
    by_position: bool = False
    landmarks: tuple = ()  # (marker, vertex group) pairs for a binding by position that the automatic one refused


def layout(name, landmarks68=None, dense=None):
    """The layout ``name`` ("dense", "sparse" or "landmarks68"; the last needs the model's landmark vertices) on
    the ICT face, or on another face whose ``dense`` layout ({marker: vertex}) is given."""
    dense = DENSE_VERTICES if dense is None else dense
    if name == "dense":
        names = tuple(DENSE_VERTICES)
        return Layout("dense", names, tuple(dense[n] for n in names), DENSE_HEAD)
    if name == "sparse":
        return Layout("sparse", SPARSE, tuple(dense[n] for n in SPARSE),
                      tuple(n for n in SPARSE if n.startswith("head_")))
    if name == "landmarks68":
        names = tuple(f"lm{i:02d}" for i in range(68))
        return Layout("landmarks68", names, tuple(int(v) for v in landmarks68),
                      tuple(names[i] for i in LANDMARK_STABLE), by_position=True, landmarks=LANDMARK_PAIRS)
    raise ValueError(f"unknown layout {name!r}; known: dense, sparse, landmarks68")


LAYOUTS = ("dense", "sparse", "landmarks68")
