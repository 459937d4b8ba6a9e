"""The optional human template: converted from a copy of ICT-FaceKit (hash-checked), fitted to an actor's neutral
markers, its shapes at the markers. Uses the shared copy of the model (never the repository's)."""

import os
import zipfile

import numpy as np
import pytest
from ict_release_copy import serve_release, write_ict_release
from shared_data import ICT_FACEKIT, require

from facecap.solvers.character.face_model import from_ict_arrays, load_ict
from facecap.solvers.character.ict_release import RELEASE_COMMIT, RELEASE_URL
from facecap.solvers.character.template import TEMPLATE_DIGEST, HumanTemplate, convert, template_path
from facecap.solvers.errors import Cancelled, FacecapError, InputFileError
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


@pytest.fixture(scope="module")
def release(tmp_path_factory):
    """ICT-FaceKit as GitHub serves it: the repository folder and its zip (``ICT-FaceKit-<commit>/FaceXModel``)."""
    root = tmp_path_factory.mktemp("download")
    folder = write_ict_release(require(ICT_FACEKIT) / "ict_face.npz", root / f"ICT-FaceKit-{RELEASE_COMMIT}")
    archive = root / f"ICT-FaceKit-{RELEASE_COMMIT}.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        for path in sorted(folder.rglob("*")):
            z.write(path, path.relative_to(root).as_posix())
    return folder, archive


@pytest.mark.parametrize("form", ["zip", "repository", "FaceXModel"])
def test_convert_reads_the_release_as_downloaded(model, release, form, tmp_path):
    """The zip as downloaded, the unpacked repository or its FaceXModel folder: the same face region, polygons,
    landmarks and data digest as the reduced file (so the hash check accepts the release itself)."""
    folder, archive = release
    source = {"zip": archive, "repository": folder, "FaceXModel": folder / "FaceXModel"}[form]
    seen = []
    out = convert(source, tmp_path / "t.npz", progress=lambda done, total: seen.append((done, total)))
    t = HumanTemplate.load(out).model
    reduced = HumanTemplate.load(convert(ICT_FACEKIT, tmp_path / "reduced.npz")).model
    assert t.digest == TEMPLATE_DIGEST
    assert t.shape_names == model.shape_names
    model = reduced  # the template as the reduced file converts (stored float32)
    np.testing.assert_array_equal(t.neutral, model.neutral)
    np.testing.assert_array_equal(t.deltas, model.deltas)
    np.testing.assert_array_equal(t.identity, model.identity)
    np.testing.assert_array_equal(t.landmarks68, model.landmarks68)
    np.testing.assert_array_equal(t.triangles, model.triangles)  # the polygons reaching the back of the head left out
    assert seen[-1] == (154, 154) and len(seen) == 154


@pytest.fixture
def server(release):
    with serve_release(release[1]) as url:
        yield url


def test_fetch_downloads_converts_and_cleans_up(server, tmp_path):
    """`template fetch` (here from a local server): downloaded into the cache, converted (hash-checked), the zip
    removed unless kept; a failed download names the address and leaves no partial file; a zip that is not the
    release is refused and removed, so the next fetch downloads again."""
    from facecap.solvers.tools.template import fetch

    cache = tmp_path / "cache"
    out = fetch(f"{server}/ict.zip", tmp_path / "t.npz", cache=cache)
    assert HumanTemplate.load(out).model.digest == TEMPLATE_DIGEST and list(cache.iterdir()) == []
    fetch(f"{server}/ict.zip", tmp_path / "t2.npz", cache=cache, keep=True)
    assert [p.name for p in cache.iterdir()] == ["ict.zip"]
    for url, match in ((f"{server}/missing.zip", "could not download ICT-FaceKit.*Not Found"),
                       (f"{server}/cut.zip", "could not download ICT-FaceKit")):
        with pytest.raises(FacecapError, match=match) as caught:
            fetch(url, tmp_path / "x.npz", cache=cache)
        assert url in str(caught.value) and "template convert" in str(caught.value)
    assert [p.name for p in cache.iterdir()] == ["ict.zip"] and not (tmp_path / "x.npz").exists()
    with pytest.raises(Cancelled):  # progress returning False: the partial download removed
        fetch(f"{server}/slow.zip", tmp_path / "x.npz", cache=cache, progress=lambda done, total: done < 2 << 20)
    assert [p.name for p in cache.iterdir()] == ["ict.zip"]
    (cache / "other.zip").write_bytes(b"not a zip")
    with pytest.raises(FacecapError):
        fetch(f"{server}/other.zip", tmp_path / "x.npz", cache=cache)
    assert not (cache / "other.zip").exists() and not (tmp_path / "x.npz").exists()


def _nudged(obj_text):
    """The OBJ text with its first vertex moved by 0.1 mm: another model as far as the hash check is concerned."""
    lines = obj_text.split("\n")
    i = next(i for i, line in enumerate(lines) if line.startswith("v "))
    v, x, *rest = lines[i].split()
    lines[i] = " ".join([v, repr(float(x) + 0.01), *rest])
    return "\n".join(lines)


def _variant(folder, tmp_path, changes):
    """A copy of the release folder (links) with ``changes`` {file name: new text or None to leave it out}."""
    copy = tmp_path / "ICT-FaceKit" / "FaceXModel"
    copy.mkdir(parents=True)
    for path in (folder / "FaceXModel").iterdir():
        if path.name not in changes:
            os.symlink(path, copy / path.name)
    for name, text in changes.items():
        if text is not None:
            (copy / name).write_text(text)
    return copy.parent


def test_a_broken_release_is_named_and_nothing_is_written(release, tmp_path):
    folder, _ = release
    fx = folder / "FaceXModel"
    ident = (fx / "identity050.obj").read_text()
    cases = [
        ({"identity050.obj": None}, InputFileError, r"identity050\.obj: missing from the ICT-FaceKit download"),
        ({"identity050.obj": ident[: len(ident) // 3]}, InputFileError, r"identity050\.obj: \d+ vertices"),
        ({"identity050.obj": ident.replace("\nv ", "\nv x ", 1)}, InputFileError, r"vertex 1: expected three numbers"),
        ({"identity050.obj": ident.replace("\nv ", "\nv 1\nv ", 1)}, InputFileError, r"identity050\.obj, line 4"),
        ({"vertex_indices.json": "{}"}, InputFileError, "idx_to_landmark_verts"),
        ({"jawOpen.obj": _nudged((fx / "jawOpen.obj").read_text())}, FacecapError,
         "not the ICT-FaceKit release facecap knows"),
    ]
    for i, (changes, error, message) in enumerate(cases):
        source = _variant(folder, tmp_path / str(i), changes)
        with pytest.raises(error, match=message) as caught:
            convert(source, tmp_path / "t.npz")
        assert not (tmp_path / "t.npz").exists()
        if "missing" in message or "knows" in message:
            assert RELEASE_URL in str(caught.value)
    damaged = tmp_path / "damaged.zip"  # bytes zeroed inside one member's compressed data
    data = bytearray(release[1].read_bytes())
    with zipfile.ZipFile(release[1]) as z:
        member = z.getinfo(next(n for n in z.namelist() if n.endswith("identity050.obj")))
    middle = member.header_offset + 30 + len(member.filename) + 2000  # within the face region (read)
    data[middle:middle + 64] = bytes(64)
    damaged.write_bytes(bytes(data))
    with pytest.raises(InputFileError, match=r"identity050\.obj|could not be read"):  # bad text, or zlib's error
        convert(damaged, tmp_path / "t.npz")
    assert not (tmp_path / "t.npz").exists()
    with pytest.raises(InputFileError, match="not an ICT-FaceKit download"):
        with zipfile.ZipFile(tmp_path / "other.zip", "w") as z:
            z.writestr("README.md", "not a face")
        convert(tmp_path / "other.zip", tmp_path / "t.npz")


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
