"""A human face model as a linear blendshape model with identity modes (the ICT-FaceKit face region).

The model is not part of facecap: it is read from a copy the user has (``python -m facecap template
convert``, see ``template.py`` beside this module) or, in tests and benchmarks, from ``shared/data/ict-facekit``.
Everything here is in facecap's character convention: metres, Z up, the face looking down -Y, +X the
subject's left, and ARKit shape names (ICT's ``browInnerUp_L``/``_R`` and ``cheekPuff_L``/``_R`` halves are
summed into ARKit's single ``browInnerUp`` and ``cheekPuff``; ICT has no ``tongueOut``).
"""

import hashlib
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FacecapError
from .ict_release import FOLDER, is_release, read_release

#: ICT (Y up, the face looking along +Z, centimetres) -> facecap (Z up, looking down -Y, metres).
ICT_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
CM = 0.01
ICT_FILE = "ict_face.npz"
ICT_KEYS = ("neutral_cm", "quads", "expression_names", "expression_deltas_cm", "identity_deltas_cm",
            "landmarks_multipie68")


def arkit_name(ict_name):
    """``browDown_L`` -> ``browDownLeft``; ``jawOpen`` stays."""
    if ict_name.endswith("_L"):
        return ict_name[:-2] + "Left"
    if ict_name.endswith("_R"):
        return ict_name[:-2] + "Right"
    return ict_name


#: ARKit shapes that ICT splits into a left and a right half.
MERGED = ("browInnerUp", "cheekPuff")


@dataclass(frozen=True, eq=False)
class FaceModel:
    """A face: neutral (V, 3), triangles (T, 3), K expression deltas (K, V, 3) named ``shape_names``,
    I identity modes (I, V, 3) (a person = neutral + sum c_i modes_i, c_i ~ N(0, 1)) and the vertex
    indices of the 68 Multi-PIE landmarks. Metres, facecap axes."""

    neutral: np.ndarray
    triangles: np.ndarray
    shape_names: tuple
    deltas: np.ndarray
    identity: np.ndarray
    landmarks68: np.ndarray
    polygons: np.ndarray = None  # (Q, 4) the source's quads (a renderer's faces), when it has them
    source: str = ""
    digest: str = ""  # SHA-256 of everything the source holds (``source_digest``)

    @property
    def n_vertices(self):
        return len(self.neutral)

    def person(self, coefficients):
        """The neutral (V, 3) of the identity with mode ``coefficients`` (I,) (fewer: the first modes)."""
        c = np.asarray(coefficients, dtype=np.float64)
        return self.neutral + np.einsum("i,ivd->vd", c, self.identity[: len(c)])


def source_digest(arrays):
    """SHA-256 of everything of an ICT face file a template keeps, in its own units: the neutral, the expression
    and identity deltas (float32), the expression names in order, the polygons and the 68 landmark vertices
    (int64); each with its key and shape, so that no two different files give the same bytes."""
    h = hashlib.sha256()
    for key, dtype in (("neutral_cm", "<f4"), ("expression_deltas_cm", "<f4"), ("identity_deltas_cm", "<f4"),
                       ("quads", "<i8"), ("landmarks_multipie68", "<i8")):
        values = np.ascontiguousarray(arrays[key], dtype=dtype)
        h.update(f"{key}{values.shape}".encode())
        h.update(values.tobytes())
    h.update("\n".join(str(n) for n in np.asarray(arrays["expression_names"]).ravel()).encode("utf-8"))
    return h.hexdigest()


def model_digest(model):
    """SHA-256 of what a template file stores of ``model`` (facecap's units and axes, ARKit names, triangles),
    as the template stores it (float32 shapes and modes; -0.0 counted as 0.0): identifies a template whoever
    converted it, with whichever NumPy."""
    h = hashlib.sha256()
    arrays = (("neutral", model.neutral, "<f4"), ("deltas", model.deltas, "<f4"), ("identity", model.identity, "<f4"),
              ("triangles", model.triangles, "<i8"), ("landmarks68", model.landmarks68, "<i8"))
    for key, values, dtype in arrays:
        values = np.ascontiguousarray(values, dtype=dtype)
        if values.dtype.kind == "f":
            values = values + values.dtype.type(0.0)  # -0.0 -> 0.0: the sign of a zero is not the model
        h.update(f"{key}{values.shape}".encode())
        h.update(values.tobytes())
    h.update("\n".join(model.shape_names).encode("utf-8"))
    return h.hexdigest()


def from_ict_arrays(arrays, *, source=""):
    """A FaceModel from the arrays of ``ict_face.npz`` (ICT units and axes, ICT expression names)."""
    missing = [k for k in ICT_KEYS if k not in arrays]
    if missing:
        raise FacecapError(f"{source}: not an ICT-FaceKit face file: missing {missing}")
    neutral = np.asarray(arrays["neutral_cm"], dtype=np.float64)
    V = len(neutral)
    names = [str(n) for n in arrays["expression_names"]]
    expr = np.asarray(arrays["expression_deltas_cm"], dtype=np.float64)
    ident = np.asarray(arrays["identity_deltas_cm"], dtype=np.float64)
    if neutral.shape != (V, 3) or expr.shape != (len(names), V, 3) or ident.ndim != 3 or ident.shape[1:] != (V, 3):
        raise FacecapError(f"{source}: inconsistent shapes: neutral {neutral.shape}, expressions {expr.shape}, "
                           f"identities {ident.shape}")
    quads = np.asarray(arrays["quads"], dtype=np.int64)
    if quads.ndim != 2 or quads.shape[1] != 4 or quads.min() < 0 or quads.max() >= V:
        raise FacecapError(f"{source}: `quads` must be (Q, 4) vertex indices below {V}")
    shapes, deltas = [], []
    for name, d in zip(names, expr):
        arkit = arkit_name(name)
        base = arkit[:-4] if arkit.endswith("Left") else arkit[:-5] if arkit.endswith("Right") else arkit
        if base in MERGED:
            if base in shapes:
                deltas[shapes.index(base)] = deltas[shapes.index(base)] + d
                continue
            arkit = base
        shapes.append(arkit)
        deltas.append(d)
    to = ICT_AXES * CM
    triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    triangles = triangles[(triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2])
                          & (triangles[:, 0] != triangles[:, 2])]
    return FaceModel(
        neutral=neutral @ to.T, triangles=triangles, shape_names=tuple(shapes),
        deltas=np.einsum("kvi,ji->kvj", np.stack(deltas), to), identity=np.einsum("kvi,ji->kvj", ident, to),
        landmarks68=np.asarray(arrays["landmarks_multipie68"], dtype=np.int64), polygons=quads, source=source,
        digest=source_digest(arrays))


def load_ict(path, *, progress=None):
    """The ICT-FaceKit face region from ``path``: the reduced face file ``ict_face.npz`` (or the folder holding
    it), or the release as its authors publish it (the GitHub zip, the repository folder or its ``FaceXModel``
    folder; ``ict_release``, ``progress(done, total)`` per OBJ file read)."""
    path = Path(path)
    if path.is_dir() and (path / ICT_FILE).is_file():
        path = path / ICT_FILE
    expected = (f"expected ICT-FaceKit's download: the zip, the repository folder or {FOLDER}/ with the OBJ "
                f"files; or a reduced {ICT_FILE}")
    if path.suffix != ".npz" and path.exists():
        if is_release(path):
            return from_ict_arrays(read_release(path, progress=progress), source=str(path))
        raise FacecapError(f"{path}: not ICT-FaceKit ({expected})")
    if not path.is_file():
        raise FacecapError(f"{path}: no ICT-FaceKit here ({expected})")
    try:
        with np.load(path, allow_pickle=False) as data:
            return from_ict_arrays({k: data[k] for k in data.files}, source=str(path))
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise FacecapError(f"{path}: not a readable {ICT_FILE} ({exc})") from None
