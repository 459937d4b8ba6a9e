"""The optional human template: converted from a copy of ICT-FaceKit (hash-checked), fitted to an actor's neutral
markers, its shapes at the markers. Uses the shared copy of the model (never the repository's)."""

import numpy as np
import pytest
from shared_data import ICT_FACEKIT, require

from facecap.solvers.character.face_model import from_ict_arrays, load_ict
from facecap.solvers.character.template import TEMPLATE_DIGEST, HumanTemplate, convert, template_path
from facecap.solvers.errors import FacecapError
from facecap.solvers.tools.synthetic.realism.actors import Perturbation, make_actor
from facecap.solvers.tools.synthetic.realism.layouts import layout


@pytest.fixture(scope="module")
def model():
    return load_ict(require(ICT_FACEKIT))


def test_the_model_in_facecap_conventions(model):
    assert len(model.shape_names) == 51 and "browInnerUp" in model.shape_names and "tongueOut" not in model.shape_names
    assert model.digest == TEMPLATE_DIGEST
    nose = model.neutral[model.landmarks68[30]]
    assert nose[1] == model.neutral[:, 1].min() or nose[1] < np.percentile(model.neutral[:, 1], 1)  # looks down -Y
    left = model.neutral[model.landmarks68[45]]  # the subject's left outer eye corner
    assert left[0] > 0 and left[2] > model.neutral[model.landmarks68[57], 2]  # +X left, Z up
    jaw = model.deltas[model.shape_names.index("jawOpen")]
    assert jaw[model.landmarks68[8], 2] < -0.01  # the chin drops by centimetres


def test_convert_writes_the_template_and_refuses_another_model(model, tmp_path, monkeypatch):
    monkeypatch.setenv("FACECAP_DATA", str(tmp_path / "data"))
    out = convert(ICT_FACEKIT)
    assert out == template_path() and out.is_file()
    t = HumanTemplate.load(out)
    assert t.model.shape_names == model.shape_names and t.model.digest == model.digest
    with np.load(ICT_FACEKIT / "ict_face.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays["neutral_cm"] = arrays["neutral_cm"] * 1.01
    np.savez(tmp_path / "ict_face.npz", **arrays)
    with pytest.raises(FacecapError, match="not the ICT-FaceKit release facecap knows"):
        convert(tmp_path / "ict_face.npz", tmp_path / "other.npz")
    assert not (tmp_path / "other.npz").exists()
    with pytest.raises(FacecapError, match="not a facecap human template"):
        HumanTemplate.load(_junk(tmp_path))
    with pytest.raises(FacecapError, match="missing"):
        from_ict_arrays({"neutral_cm": arrays["neutral_cm"]}, source="bad.npz")


def _junk(tmp_path):
    path = tmp_path / "junk.npz"
    np.savez(path, a=np.zeros(3))
    return path


@pytest.mark.parametrize("seed", [0, 1])
def test_template_fit_gives_the_actors_own_shapes(model, seed):
    """An exact model actor (another identity, markers placed by hand within 1.5 mm of their vertex): the fitted
    template's shapes at the markers match the actor's to a few percent."""
    lay = layout("dense")
    actor = make_actor(model, lay.vertices, lay.names, seed=seed, perturbation=Perturbation.none())
    rng = np.random.default_rng(seed)
    markers = actor.neutral + rng.normal(scale=3e-4, size=actor.neutral.shape)
    fit = HumanTemplate(model).fit(lay.names, markers)
    assert np.nanmedian(fit.residual_mm) < 1.0
    err = np.linalg.norm(fit.deltas - actor.deltas) / np.linalg.norm(actor.deltas)
    assert err < 0.15, err  # measured: 0.06-0.08 (the markers' placement off their vertices, the noise)
    turned = markers @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T  # any orientation
    auto = HumanTemplate(model).fit_automatic(lay.names, turned)
    back = auto.deltas @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert np.linalg.norm(back - actor.deltas) / np.linalg.norm(actor.deltas) < 0.15
