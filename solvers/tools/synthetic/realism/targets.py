"""The characters of the realism benchmark, as ``CharacterMesh``es with vertex groups named after the
dense layout's markers (the landmark layout binds by position):

* ``sample``: the bundled sample character (stylised; ``sample_blends/``), built by its numpy generator;
* ``ict``: another person of the face model (a different identity, the model's exact expressions): a
  target of the actor's own shape family;
* ``toon``: a cartoon built here from the model's topology: big eyes and brow, small chin, a muzzle, and
  shapes re-authored in a cartoon's style (broad and smooth, exaggerated mouth and brows, the jaw a
  hinge), so neither the human's nor the sample's motion patterns.
"""

import importlib.util
import sys
from pathlib import Path

import numpy as np

from ....character.mesh import CharacterMesh
from ....character.surface import triangulate
from .layouts import DENSE_VERTICES

SAMPLE_DIR = Path(__file__).resolve().parents[4] / "sample_blends"
TARGETS = ("sample", "ict", "toon")


def sample_character():
    """The sample character's mesh, 52 ARKit shape keys and 68 marker vertex groups."""
    spec = importlib.util.spec_from_file_location("facecap_sample_geometry", SAMPLE_DIR / "character_geometry.py")
    geometry = sys.modules.setdefault(spec.name, importlib.util.module_from_spec(spec))
    spec.loader.exec_module(geometry)  # the checkout's numpy generator (sample_blends is not in the extension)
    g = geometry.build_character()
    names = tuple(g.shape_keys)
    groups = {m.name: (np.asarray(m.vertices), np.asarray(m.weights, dtype=np.float64)) for m in g.markers}
    return CharacterMesh.from_arrays(g.vertices, triangulate(g.faces), names, np.stack([g.shape_keys[n] for n in names]),
                                     vertex_groups=groups, name="sample")


def _groups():
    return {name: (np.array([v]), np.array([1.0])) for name, v in DENSE_VERTICES.items()}


def ict_character(model, *, seed=1000):
    """Another person of ``model``: identity coefficients drawn with ``seed``, the model's own expressions."""
    coeffs = np.random.default_rng(seed).normal(size=model.identity.shape[0])
    return CharacterMesh.from_arrays(model.person(coeffs), model.triangles, model.shape_names, model.deltas,
                                     vertex_groups=_groups(), name="ict")


def _smooth(values, neighbours, iterations):
    """Laplacian smoothing of per-vertex ``values`` (V, ...) over the mesh's vertex neighbours."""
    rows, cols = neighbours
    count = np.bincount(rows, minlength=len(values)).astype(np.float64)
    count[count == 0] = 1.0
    for _ in range(iterations):
        acc = np.zeros_like(values)
        np.add.at(acc, rows, values[cols])
        values = 0.5 * values + 0.5 * acc / count.reshape(-1, *([1] * (values.ndim - 1)))
    return values


def toon_character(model):
    """The cartoon character (see the module docstring); deterministic."""
    v = model.neutral.copy()
    eye_l = v[DENSE_VERTICES["eyelid_upper_L"]] * [1, 1, 1]
    eyes = np.array([[eye_l[0], eye_l[1], eye_l[2] - 0.006], [-eye_l[0], eye_l[1], eye_l[2] - 0.006]])
    mouth = 0.5 * (v[DENSE_VERTICES["mouth_corner_L"]] + v[DENSE_VERTICES["mouth_corner_R"]])

    def bump(centre, width):
        return np.exp(-0.5 * ((v - centre) ** 2).sum(axis=1) / width**2)[:, None]

    warped = v.copy()
    for c in eyes:  # big eyes: the region around each eye scaled up about its centre
        warped += 0.45 * bump(c, 0.022) * (v - c)
    chin = bump(mouth + [0, 0, -0.035], 0.03)
    warped += -0.35 * chin * (v - (mouth + [0, 0, -0.035]))  # a small chin
    warped += 0.012 * bump(mouth, 0.03) * np.array([0.0, -1.0, 0.0])  # a muzzle: the mouth pushed forward
    tris = model.triangles
    rows = np.concatenate([tris[:, 0], tris[:, 1], tris[:, 2], tris[:, 1], tris[:, 2], tris[:, 0]])
    cols = np.concatenate([tris[:, 1], tris[:, 2], tris[:, 0], tris[:, 0], tris[:, 1], tris[:, 2]])
    style = {"mouth": 1.6, "brow": 2.0, "cheek": 1.4, "nose": 1.5, "eye": 1.0, "jaw": 1.0}
    deltas = []
    hinge = np.array([0.0, -0.01, -0.005])  # below the ears, behind the cheekbones
    jaw_open = model.deltas[model.shape_names.index("jawOpen")]
    jaw_region = np.clip(np.linalg.norm(jaw_open, axis=1) / np.linalg.norm(jaw_open, axis=1).max() * 1.5, 0, 1)
    for name, d in zip(model.shape_names, model.deltas):
        if name == "jawOpen":  # a hinge: the jaw region rotates 20 degrees about a transverse axis
            a = np.radians(20.0)
            rel = warped - hinge
            rot = np.stack([rel[:, 0], np.cos(a) * rel[:, 1] - np.sin(a) * rel[:, 2],
                            np.sin(a) * rel[:, 1] + np.cos(a) * rel[:, 2]], axis=1)
            deltas.append(jaw_region[:, None] * (rot - rel))
            continue
        gain = next((g for key, g in style.items() if name.startswith(key)), 1.0)
        deltas.append(gain * _smooth(d, (rows, cols), 12))
    return CharacterMesh.from_arrays(warped, tris, model.shape_names, np.stack(deltas), vertex_groups=_groups(),
                                     name="toon")


def make_target(name, model):
    """The benchmark character ``name`` (one of ``TARGETS``)."""
    if name == "sample":
        return sample_character()
    if name == "ict":
        return ict_character(model)
    if name == "toon":
        return toon_character(model)
    raise ValueError(f"unknown target {name!r}; known: {', '.join(TARGETS)}")
