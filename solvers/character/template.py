"""The optional human template: a face model whose identity modes are fitted to the actor's neutral
markers, giving the actor's own expression shapes at the markers without a calibration session.

The template is not shipped with facecap. A user who has a copy of the ICT-FaceKit model (MIT) converts it
once (``python -m facecap template convert <the download>``: the GitHub zip as downloaded, the repository
folder or its ``FaceXModel`` folder, ``ict_release``; hash-checked: ``TEMPLATE_DIGEST`` covers everything the
solve uses, the shapes' names and deltas, the identity modes, the polygons and the landmarks); facecap then finds
it in its data folder (``template_path``) or at the path ``[actor] template`` names. Loading checks the template
file's contents too (``TEMPLATE_MODEL_DIGEST``): a template installed by an earlier facecap is the same file and
keeps working; one changed since, or any other model, is refused with how to install the template again.

Fitting (``HumanTemplate.fit``): the markers (metres, turned upright by a given orientation or started by the
automatic multi-start search) are aligned to the template's surface by robust ICP, then the similarity and the
identity coefficients are solved together to convergence (``template_fit``: point-to-plane, a ridge towards the
mean face, a prior on the scale). The expression deltas at each marker's closest point, carried back by the
similarity, are the actor's shapes as the template knows them.
"""

import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FacecapError, InputFileError
from ..io.archives import check_members
from ..io.files import atomic_path, remove_stale_temporaries
from ..io.limits import check_input_file
from ..io.outputs import Output, check_outputs
from ..transforms import Similarity
from .alignment import align_automatic, refine
from .face_model import FaceModel, load_ict, model_digest
from .ict_release import RELEASE_URL
from .surface import closest_points, interpolate, make_surface
from .template_fit import fit_identity

TEMPLATE_NAME = "ict-facekit.npz"
FORMAT = "facecap human template 1"
#: SHA-256 of the face region of ICT-FaceKit @ da5f95a as its files hold it (``face_model.source_digest``: the
#: neutral, the expression names and deltas, the identity modes, the polygons, the landmarks): a conversion of
#: any other model is refused.
TEMPLATE_DIGEST = "acc3b12be22afdc7bc45c0f0ce880d5a657e8e29676328c35863c30f92334361"
#: SHA-256 of the template ``convert`` makes of it (``face_model.model_digest``): what loading checks.
TEMPLATE_MODEL_DIGEST = "f6e287e9486456a2d306c206eb781aaec56f8f6dc8a69824376fef0dbed25e9e"
#: Bounds of a template file's arrays before they are read: it holds about 20 MB (the identity modes)
MAX_TEMPLATE_ARRAY_BYTES = 64 << 20
MAX_TEMPLATE_BYTES = 256 << 20
MAX_TEMPLATE_RATIO = 50
#: Identity modes fitted (of 100) and their ridge: enough for the face's proportions, few enough that
#: 30-70 markers with 0.3 mm noise determine them.
IDENTITY_MODES = 60
IDENTITY_RIDGE = 0.3
#: Triangles tested per marker for its closest point (the face mesh is even: its nearest centroids hold it).
CANDIDATES = 32


def data_folder():
    """facecap's data folder (``FACECAP_DATA``, else the platform's user data folder)."""
    env = os.environ.get("FACECAP_DATA")
    if env:
        return Path(env).expanduser()
    if os.name == "nt":
        return Path(os.environ.get("APPDATA", Path.home())) / "facecap"
    if os.uname().sysname == "Darwin":
        return Path.home() / "Library" / "Application Support" / "facecap"
    return Path(os.environ.get("XDG_DATA_HOME", Path.home() / ".local" / "share")) / "facecap"


def template_path():
    """Where ``template convert`` writes the template and where ``[actor] template = "auto"`` looks."""
    return data_folder() / "templates" / TEMPLATE_NAME


def check_template_output(out=None, source=None, *, overwrite=False):
    """The output policy (``solvers.io.outputs``) for a template written at ``out`` (None: ``template_path()``,
    facecap's own data folder, where it always replaces what is there) from ``source``: never the source, a
    folder or someone else's file (unless ``overwrite``). Stale temporary files of killed runs beside it are
    removed. Returns the path to write."""
    path = Path(out) if out is not None else template_path()
    check_outputs([Output("--out" if out is not None else "the template", path, "template")],
                  {"the ICT-FaceKit download (SOURCE)": source}, overwrite=overwrite or out is None)
    remove_stale_temporaries(path.parent)
    return path


def convert(source, out=None, *, progress=None, overwrite=False):
    """Convert a copy of ICT-FaceKit (its download as published: the zip, the repository folder or
    ``FaceXModel``; or the reduced face file ``ict_face.npz``) into facecap's template at ``out`` (default
    ``template_path()``), written atomically through the output policy (``check_template_output``) before
    anything is read. Returns the path. ``progress(done, total)``: OBJ files read."""
    out = check_template_output(out, source, overwrite=overwrite)
    model = load_ict(source, progress=progress)
    _check_release(model, source)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out, suffix=".npz", kind="template") as tmp:
        np.savez_compressed(tmp, format=np.array(FORMAT), neutral=model.neutral, triangles=model.triangles,
                            shape_names=np.array(model.shape_names), deltas=model.deltas.astype(np.float32),
                            identity=model.identity.astype(np.float32), landmarks68=model.landmarks68,
                            digest=np.array(model.digest))
    return out


def _check_release(model, source):
    if model.digest != TEMPLATE_DIGEST:
        raise FacecapError(f"{source}: not the ICT-FaceKit release facecap knows (data digest {model.digest[:16]}..., "
                           f"expected {TEMPLATE_DIGEST[:16]}...: its shapes, their names, polygons or landmarks "
                           f"differ); the template's accuracy figures hold only for it. Download that release: "
                           f"{RELEASE_URL}")


@dataclass(frozen=True, eq=False)
class TemplateFit:
    """The template fitted to an actor: ``deltas`` (K, M, 3) the template's shapes at the markers in the
    markers' frame; ``residual_mm`` (M,) each marker's distance from the fitted surface; ``scale`` of the
    markers onto the template; ``notes``."""

    shape_names: tuple
    marker_names: tuple
    deltas: np.ndarray
    residual_mm: np.ndarray
    scale: float
    notes: tuple
    objective: float = float("nan")


class HumanTemplate:
    """A human face model used as the actor's prior (see the module docstring)."""

    def __init__(self, model, *, source=""):
        if not isinstance(model, FaceModel):
            raise FacecapError("HumanTemplate needs a FaceModel")
        self.model = model
        self.source = source or model.source
        self._surface = make_surface(model.neutral, model.triangles)

    @classmethod
    def load(cls, path):
        """A template written by ``convert`` (or, for tests, an ICT-FaceKit face file or its folder), refused
        unless it holds the release facecap knows (``TEMPLATE_MODEL_DIGEST``; ``TEMPLATE_DIGEST``)."""
        path = Path(path)
        if path.is_dir() or path.name == "ict_face.npz":
            model = load_ict(path)
            _check_release(model, path)
            return cls(model, source=str(path))
        again = ("install it again: `python -m facecap template fetch`, or `template convert` on the ICT-FaceKit "
                 f"download ({RELEASE_URL})")
        check_input_file(path, limit=MAX_TEMPLATE_BYTES)  # a FIFO would block the reader, a device feed it for ever
        try:
            with np.load(path, allow_pickle=False) as z:
                if "format" not in z.files or str(z["format"]) != FORMAT:
                    raise InputFileError(path, "not a facecap human template (convert it with "
                                               "`python -m facecap template convert`)")
                check_members(path, z.zip.infolist(), max_bytes=MAX_TEMPLATE_ARRAY_BYTES, max_ratio=MAX_TEMPLATE_RATIO,
                              what=f"not a template facecap wrote; {again}")
                model = FaceModel(z["neutral"].astype(np.float64), z["triangles"].astype(np.int64),
                                  tuple(str(n) for n in z["shape_names"]), z["deltas"].astype(np.float64),
                                  z["identity"].astype(np.float64), z["landmarks68"].astype(np.int64),
                                  source=str(path), digest=TEMPLATE_DIGEST)
        except FileNotFoundError:
            raise InputFileError(path, "file not found") from None
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, NotImplementedError) as exc:
            raise InputFileError(path, f"not a facecap human template: {exc}") from None
        if model_digest(model) != TEMPLATE_MODEL_DIGEST:
            raise InputFileError(path, "not the human template facecap converts from ICT-FaceKit "
                                       f"{RELEASE_URL.rsplit('/', 1)[1][:7]} (changed or damaged since it was "
                                       f"installed, or another model); {again}")
        return cls(model, source=str(path))

    def fit_automatic(self, names, markers, **options):
        """``fit`` for markers in any orientation: started from the automatic multi-start alignment that
        binding by position uses (which refuses when two poses fit equally well)."""
        X = np.asarray(markers, dtype=np.float64)
        ok = np.isfinite(X).all(axis=1)
        start, note = align_automatic(self._surface, X[ok], unit=1e-3, scale=1.0)
        fit = self.fit(names, X, start=start, **options)
        return TemplateFit(fit.shape_names, fit.marker_names, fit.deltas, fit.residual_mm, fit.scale,
                           (f"template: {note}",) + fit.notes, fit.objective)

    def fit(self, names, markers, *, start=None, orientation=None, modes=IDENTITY_MODES, ridge=IDENTITY_RIDGE):
        """Fit the template to the actor's neutral ``markers`` (M, 3; metres): from a ``start`` Similarity onto the
        template, else from the centroids and sizes with the markers turned by ``orientation`` (3, 3; default:
        already upright and looking down -Y). A robust ICP of the similarity onto the mean face
        (``alignment.refine``), then the similarity and the identity solved together to convergence
        (``template_fit.fit_identity``).

        Returns a TemplateFit (deltas in the markers' frame; ``objective`` the fit's cost, comparable between fits
        of the same markers from different starts); markers farther than 8 mm from the fitted surface get no
        shape (zero deltas) and are named in the notes."""
        X = np.asarray(markers, dtype=np.float64)
        ok = np.isfinite(X).all(axis=1)
        if ok.sum() < 6:
            raise FacecapError(f"template: only {int(ok.sum())} markers have a neutral position (need 6)")
        m = self.model
        unit = 1e-3
        spread = lambda p: np.sqrt(((p - p.mean(axis=0)) ** 2).sum(axis=1).mean())  # noqa: E731
        face = m.neutral[np.unique(m.triangles)]
        if start is None:
            R = np.eye(3) if orientation is None else np.asarray(orientation, dtype=np.float64)
            scale = 0.8 * spread(face) / spread(X[ok])  # markers cover most, not all, of the face
            start = Similarity(scale, R, face.mean(axis=0) - scale * R @ X[ok].mean(axis=0))
        sim, note = refine(self._surface, X[ok], start, unit=unit, scale_range=1.3)
        modes = min(modes, m.identity.shape[0])
        sim, coeffs, objective, steps, settled = fit_identity(m, X[ok], sim, modes=modes,
                                                              ridge=ridge * int(ok.sum()))
        notes = [f"template: {note}"]
        if not settled:
            notes.append(f"template: the fit had not settled after {steps} steps")
        surface = make_surface(m.person(coeffs), m.triangles)
        tri, bary, _, dist = closest_points(surface, sim.apply(X[ok]), candidates=CANDIDATES)
        deltas = np.zeros((len(m.shape_names), len(X), 3))
        deltas[:, ok] = sim.inverse_vectors(interpolate(m.deltas, m.triangles, tri, bary))
        residual = np.full(len(X), np.nan)
        residual[ok] = dist / unit
        far = ok & (np.nan_to_num(residual) > 8.0)
        if far.any():
            deltas[:, far] = 0.0
            notes.append(f"template: {int(far.sum())} marker(s) are farther than 8 mm from the fitted face and get "
                         f"no template shapes: {[n for n, f in zip(names, far) if f][:8]}")
        notes.append(f"template: fitted {modes} identity modes in {steps} steps; markers {np.nanmedian(residual):.2f} "
                     f"mm from the face (median), {np.nanmax(residual):.2f} mm worst; scale {sim.scale:.3f}")
        return TemplateFit(m.shape_names, tuple(names), deltas, residual, float(sim.scale), tuple(notes), objective)
