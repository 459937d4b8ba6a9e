"""The actor families of the realism benchmark: the face each draw's actor is made from, and where the
marker layouts sit on it.

* ``ict``: the ICT-FaceKit face model (identity modes and 51 ARKit expressions): the human template's own
  family, so the template is a best case there.
* ``facecap``: the Face Cap head of three.js's examples (``shared/data/facecap-head``), a scanned human with
  its own 51 ARKit shapes and no identity modes: a human NOT of the template's family, the fair test of
  anything that leans on the template.

The layouts were chosen on the ICT face (``layouts.DENSE_VERTICES``); on the Face Cap head each marker is the
vertex nearest its ICT vertex carried over by a thin-plate warp through landmarks both faces define the same
way: where their own expressions move them most (upper lids for blinks, mouth corners for smiles, brows,
nose wings, cheeks, upper lip) and the nose tip. Checked by which expressions move each marker (per-shape
motion at the marker correlates 0.8-0.98 between the faces on the moving face; the head markers move
0.2 mm at most).
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ....character.face_model import CM, ICT_AXES, FaceModel
from ....errors import FacecapError
from .layouts import DENSE_VERTICES

FAMILIES = ("ict", "facecap")
FACECAP_FILE = Path("data") / "facecap-head" / "facecap_head.npz"
#: Landmarks both faces define by their own expressions: (shape, side) -> the motion-weighted centre of the
#: vertices it moves most (side +1 / -1: only that half of the face; 0: the shape is one-sided itself).
MOTION_LANDMARKS = (
    ("eyeBlinkLeft", 0), ("eyeBlinkRight", 0), ("mouthSmileLeft", 0), ("mouthSmileRight", 0),
    ("browOuterUpLeft", 0), ("browOuterUpRight", 0), ("browInnerUp", 1), ("browInnerUp", -1),
    ("noseSneerLeft", 0), ("noseSneerRight", 0), ("cheekPuff", 1), ("cheekPuff", -1), ("mouthRollUpper", 0),
)
#: Vertices whose motion makes up a landmark, and the distance from the midline that counts as a side (m).
LANDMARK_VERTICES, MIDLINE = 10, 0.005


@dataclass(frozen=True, eq=False)
class ActorFamily:
    """A face actors are made from: ``model`` (a FaceModel; its identity modes may be empty), the dense
    layout's vertex per marker name (``dense``) and the 68 landmarks' vertices (``landmarks68``)."""

    name: str
    model: FaceModel
    dense: dict
    landmarks68: np.ndarray


def ict_family(model):
    """The ICT face model's family (the layouts' own vertices)."""
    return ActorFamily("ict", model, dict(DENSE_VERTICES), np.asarray(model.landmarks68))


def load_facecap_head(shared):
    """The Face Cap head as a FaceModel (facecap axes, metres; ``tongueOut``, all zeros there, left out)."""
    path = Path(shared) / FACECAP_FILE
    if not path.is_file():
        raise FacecapError(f"{path}: the Face Cap head is not here (shared/data/facecap-head)")
    with np.load(path, allow_pickle=False) as z:
        neutral, faces = z["neutral"].astype(np.float64), z["faces"].astype(np.int64)
        names, deltas = [str(n) for n in z["names"]], z["deltas"].astype(np.float64)
    keep = [k for k, d in enumerate(deltas) if np.abs(d).max() > 0]
    to = ICT_AXES * CM  # the same axes and units as ICT's face file
    return FaceModel(neutral=neutral @ to.T, triangles=faces, shape_names=tuple(names[k] for k in keep),
                     deltas=np.einsum("kvi,ji->kvj", deltas[keep], to), identity=np.zeros((0, len(neutral), 3)),
                     landmarks68=np.zeros(0, dtype=np.int64), source=str(path))


def motion_landmarks(model):
    """(L, 3) landmark positions on ``model``'s neutral (``MOTION_LANDMARKS``, then the nose tip)."""
    names = list(model.shape_names)
    out = []
    for shape, side in MOTION_LANDMARKS:
        size = np.linalg.norm(model.deltas[names.index(shape)], axis=1)
        if side:
            size = size * (side * model.neutral[:, 0] > MIDLINE)
        top = np.argsort(size, kind="stable")[-LANDMARK_VERTICES:]  # stable: ties the same in every NumPy
        out.append((model.neutral[top] * size[top, None]).sum(axis=0) / size[top].sum())
    mid = np.flatnonzero(np.abs(model.neutral[:, 0]) < MIDLINE)
    out.append(model.neutral[mid[np.argmin(model.neutral[mid, 1])]])  # the nose tip: the face looks down -Y
    return np.array(out)


def carried_vertices(source, target, vertices):
    """The ``target`` vertex nearest each of ``source``'s ``vertices`` (N,) carried over by the thin-plate warp
    through both faces' ``motion_landmarks``."""
    from scipy.interpolate import RBFInterpolator  # scipy: the benchmark's own dependency
    from scipy.spatial import cKDTree  # scipy: as above

    warp = RBFInterpolator(motion_landmarks(source), motion_landmarks(target), kernel="thin_plate_spline")
    return cKDTree(target.neutral).query(warp(source.neutral[np.asarray(vertices)]))[1].astype(np.int64)


def facecap_family(shared, ict_model):
    """The Face Cap head's family, its layouts carried over from ``ict_model``'s."""
    head = load_facecap_head(shared)
    names = tuple(DENSE_VERTICES)
    dense = carried_vertices(ict_model, head, [DENSE_VERTICES[n] for n in names])
    landmarks = carried_vertices(ict_model, head, ict_model.landmarks68)
    return ActorFamily("facecap", head, dict(zip(names, (int(v) for v in dense))), landmarks)


def load_family(name, shared, ict_model):
    """The family ``name`` (one of ``FAMILIES``)."""
    if name == "ict":
        return ict_family(ict_model)
    if name == "facecap":
        return facecap_family(shared, ict_model)
    raise ValueError(f"unknown actor family {name!r}; known: {', '.join(FAMILIES)}")
