"""Reading ICT-FaceKit as its authors publish it: the repository's ``FaceXModel`` folder of OBJ files, the
repository folder holding it, or the zip GitHub downloads (read in place, never unpacked).

What is read is the face region (the model's README: vertices 0-9408 of ``generic_neutral_mesh.obj``): the
neutral, the polygons among those vertices, the 53 expression OBJs and the 100 identity OBJs as deltas from
the neutral, and the 68 Multi-PIE landmark vertices of ``vertex_indices.json``. The arrays come out as
``ict_face.npz`` holds them (``face_model.ICT_KEYS``: centimetres, ICT's axes; deltas computed in float64,
stored float32), so the template's data digest identifies the release whichever form it was read from.

Nothing is read before the whole download is looked at: every file facecap reads is there (or the download is
named incomplete), a regular file, no larger than the release's files allow (``MAX_OBJ_BYTES``,
``MAX_JSON_BYTES``, ``MAX_RELEASE_BYTES`` in all), and in a zip neither encrypted, nor compressed with a method
Python cannot read, nor compressed more than ``MAX_RATIO`` times (``solvers.io.archives``). Reading an OBJ then
stops at ``MAX_OBJ_LINES`` lines and at twice the release's vertices and polygons: a file past them is not
ICT-FaceKit's (a zip of a few hundred KB could otherwise hold gigabytes of polygons).
"""

import json
import os
import stat
import zipfile
import zlib
from pathlib import Path

import numpy as np

from ..errors import Cancelled, FacecapError, InputFileError
from ..io.archives import check_members

#: The release facecap's template figures come from, and where to download it.
RELEASE_COMMIT = "da5f95a607f5e6b37755b38d3385d7f2853732e5"
RELEASE_URL = f"https://github.com/ICT-VGL/ICT-FaceKit/archive/{RELEASE_COMMIT}.zip"
FOLDER = "FaceXModel"
NEUTRAL = "generic_neutral_mesh.obj"
INDICES = "vertex_indices.json"
#: Vertices of the face region (the first ones of every OBJ).
FACE_VERTICES = 9409
#: The expression OBJs, in the order the template's digest is taken over.
EXPRESSIONS = tuple(
    [f"{base}_{side}" for base in ("browDown", "browInnerUp", "browOuterUp", "cheekPuff", "cheekSquint", "eyeBlink",
                                   "eyeLookDown", "eyeLookIn", "eyeLookOut", "eyeLookUp", "eyeSquint", "eyeWide")
     for side in "LR"]
    + ["jawForward", "jawLeft", "jawOpen", "jawRight", "mouthClose", "mouthDimple_L", "mouthDimple_R", "mouthFrown_L",
       "mouthFrown_R", "mouthFunnel", "mouthLeft", "mouthLowerDown_L", "mouthLowerDown_R", "mouthPress_L",
       "mouthPress_R", "mouthPucker", "mouthRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower",
       "mouthShrugUpper", "mouthSmile_L", "mouthSmile_R", "mouthStretch_L", "mouthStretch_R", "mouthUpperUp_L",
       "mouthUpperUp_R", "noseSneer_L", "noseSneer_R"])
IDENTITIES = tuple(f"identity{i:03d}" for i in range(100))
#: The files read, in order
FILES = (NEUTRAL, *(f"{name}.obj" for name in EXPRESSIONS + IDENTITIES), INDICES)
#: The whole head of the release (the model's README), which its OBJ files hold
RELEASE_VERTICES = 26719
RELEASE_POLYGONS = 26384
#: Bounds on what is read, a few times what the release holds: its OBJ files are 2.5-3.4 MB of about 82,000
#: lines (vertices, texture coordinates, polygons), ``vertex_indices.json`` 0.2 MB, the 155 files 0.4 GB; its
#: zip's members compress 2-4 times.
MAX_OBJ_BYTES = 16 << 20
MAX_JSON_BYTES = 4 << 20
MAX_RELEASE_BYTES = 1 << 30
MAX_OBJ_LINES = 400_000
MAX_RATIO = 20
#: Entries of the zip's directory (the repository's zip has a few hundred)
MAX_MEMBERS = 20_000


def is_release(path):
    """Whether ``path`` looks like an ICT-FaceKit download (a zip, or a folder with the OBJ files)."""
    path = Path(path)
    if path.is_file():
        return zipfile.is_zipfile(path)
    return (path / NEUTRAL).is_file() or (path / FOLDER / NEUTRAL).is_file()


class _Release:
    """The release's files by name, from a folder or a zip, each looked at before any is read (``check``)."""

    def __init__(self, path):
        self.path = Path(path)
        self.zip = None
        if self.path.is_file():
            self.zip = _open_zip(self.path)
            members = [n for n in self.zip.namelist() if n.endswith(f"{FOLDER}/{NEUTRAL}") or n == NEUTRAL]
            if not members:
                self.zip.close()
                raise InputFileError(self.path, f"not an ICT-FaceKit download: no {FOLDER}/{NEUTRAL} inside")
            self.prefix = members[0][: -len(NEUTRAL)]
        else:
            self.prefix = self.path / FOLDER if (self.path / FOLDER / NEUTRAL).is_file() else self.path

    def where(self, name):
        return f"{self.path}:{self.prefix}{name}" if self.zip else str(Path(self.prefix) / name)

    def _missing(self, missing):
        return InputFileError(self.where(missing[0]), f"missing from the ICT-FaceKit download ({len(missing)} of the "
                              f"{len(FILES)} {FOLDER} files facecap reads are; download the whole release: "
                              f"{RELEASE_URL})")

    def check(self):
        """Raise unless every file read is there and within the release's bounds (the module docstring)."""
        what = f"a bad download, or not the ICT-FaceKit release facecap knows; download it again ({RELEASE_URL})"
        if self.zip is not None:
            infos = {}
            for name in FILES:
                try:
                    infos[name] = self.zip.getinfo(self.prefix + name)
                except KeyError:
                    pass
            missing = [n for n in FILES if n not in infos]
            if missing:
                raise self._missing(missing)
            check_members(self.path, infos.values(), max_ratio=MAX_RATIO, what=what, total=MAX_RELEASE_BYTES,
                          max_bytes=lambda i: MAX_JSON_BYTES if i.filename.endswith(INDICES) else MAX_OBJ_BYTES)
            return
        sizes, missing = {}, []
        for name in FILES:
            try:
                st = os.stat(Path(self.prefix) / name)
            except OSError:
                missing.append(name)
                continue
            limit = MAX_JSON_BYTES if name == INDICES else MAX_OBJ_BYTES
            if not stat.S_ISREG(st.st_mode) or st.st_size > limit:
                how = "not a regular file" if not stat.S_ISREG(st.st_mode) else f"{st.st_size / 2**20:.1f} MiB"
                raise InputFileError(self.where(name), f"{how}; ICT-FaceKit's files are at most {limit >> 20} MiB: "
                                     f"{what}")
            sizes[name] = st.st_size
        if missing:
            raise self._missing(missing)
        if sum(sizes.values()) > MAX_RELEASE_BYTES:
            raise InputFileError(self.path, f"its {FOLDER} files hold {sum(sizes.values()) / 2**30:.1f} GiB; {what}")

    def open(self, name):
        try:
            return self.zip.open(self.prefix + name) if self.zip else open(Path(self.prefix) / name, "rb")
        except (KeyError, FileNotFoundError):
            raise self._missing([name]) from None

    def close(self):
        if self.zip:
            self.zip.close()


def _open_zip(path):
    """``path`` as a ZipFile whose directory has at most ``MAX_MEMBERS`` entries (read before the directory is)."""
    try:
        with open(path, "rb") as fh:
            end = zipfile._EndRecData(fh)  # the end record: entries, where the directory is
        entries = end[zipfile._ECD_ENTRIES_TOTAL] if end else 0
    except (OSError, AttributeError, IndexError, TypeError):  # the directory is judged by zipfile below
        entries = 0
    if entries > MAX_MEMBERS:
        raise InputFileError(path, f"a zip of {entries} files; ICT-FaceKit's holds a few hundred: not its download "
                                   f"({RELEASE_URL})")
    try:
        return zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, EOFError, NotImplementedError, ValueError) as exc:
        raise InputFileError(path, f"the ICT-FaceKit download could not be read ({exc}); download it again "
                                   f"({RELEASE_URL})") from None


def read_release(path, *, progress=None):
    """The face region of the ICT-FaceKit release at ``path`` as ``ict_face.npz``'s arrays.

    ``progress(done, total)`` is called after each OBJ file; returning False cancels (``Cancelled``)."""
    release = _Release(path)
    try:
        release.check()
        total = 1 + len(EXPRESSIONS) + len(IDENTITIES)
        with release.open(NEUTRAL) as f:
            neutral, quads = _read_obj(f, release.where(NEUTRAL), faces=True)
        _report(progress, 1, total)
        done = 1

        def deltas(names):
            nonlocal done
            out = np.empty((len(names), FACE_VERTICES, 3), dtype=np.float32)
            for i, name in enumerate(names):
                with release.open(f"{name}.obj") as f:
                    out[i] = _read_obj(f, release.where(f"{name}.obj"))[0] - neutral
                done += 1
                _report(progress, done, total)
            return out

        expressions, identities = deltas(EXPRESSIONS), deltas(IDENTITIES)
        with release.open(INDICES) as f:
            landmarks = _landmarks(f, release.where(INDICES))
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, NotImplementedError) as exc:  # damaged, unreadable
        raise InputFileError(path, f"the ICT-FaceKit download could not be read ({exc}); download it again "
                             f"({RELEASE_URL})") from None
    finally:
        release.close()
    return {"neutral_cm": neutral.astype(np.float32), "quads": quads, "expression_names": np.array(EXPRESSIONS),
            "expression_deltas_cm": expressions, "identity_deltas_cm": identities,
            "landmarks_multipie68": landmarks}


def _report(progress, done, total):
    if progress is not None and progress(done, total) is False:
        raise Cancelled("reading ICT-FaceKit cancelled")


def _read_obj(stream, where, *, faces=False):
    """(the first FACE_VERTICES vertices (V, 3) float64, the polygons among them (Q, 4) or None) of an OBJ,
    read within the release's bounds (``MAX_OBJ_LINES`` lines, twice its vertices and polygons)."""
    coords, polygons, n, vertices, faces_seen = [], [], 0, 0, 0
    for number, raw in enumerate(stream, 1):
        if number > MAX_OBJ_LINES:
            raise InputFileError(where, f"more than {MAX_OBJ_LINES} lines; ICT-FaceKit's OBJ files have about 82,000: "
                                 f"not its file ({RELEASE_URL})", line=number)
        if raw.startswith(b"v "):
            vertices += 1
            if vertices > 2 * RELEASE_VERTICES:
                raise InputFileError(where, f"more than {2 * RELEASE_VERTICES} vertices; ICT-FaceKit's head has "
                                     f"{RELEASE_VERTICES}: not its file ({RELEASE_URL})", line=number)
            if n < FACE_VERTICES:
                parts = raw.split()
                if len(parts) < 4:
                    raise InputFileError(where, f"expected `v x y z`, got {raw.strip()[:60]!r}", line=number)
                coords.append(parts[1:4])
                n += 1
                if n == FACE_VERTICES and not faces:
                    break  # the face region is read; the rest of the head is not needed
            continue
        if faces and raw.startswith(b"f "):
            faces_seen += 1
            if faces_seen > 2 * RELEASE_POLYGONS:
                raise InputFileError(where, f"more than {2 * RELEASE_POLYGONS} polygons; ICT-FaceKit's head has "
                                     f"{RELEASE_POLYGONS}: not its file ({RELEASE_URL})", line=number)
            try:
                corners = [int(c.split(b"/")[0]) - 1 for c in raw.split()[1:]]
            except ValueError:
                raise InputFileError(where, f"expected `f v/vt ...`, got {raw.strip()[:60]!r}", line=number) from None
            if any(c < 0 for c in corners):
                raise InputFileError(where, "relative (negative) face indices are not ICT-FaceKit's", line=number)
            if len(corners) in (3, 4) and max(corners) < FACE_VERTICES:
                polygons.append(corners + corners[-1:] * (4 - len(corners)))
    if n < FACE_VERTICES:
        raise InputFileError(where, f"{n} vertices; ICT-FaceKit's head meshes have the {FACE_VERTICES} of the face "
                             "region first")
    try:
        values = np.array(coords, dtype=np.float64)
    except ValueError:
        bad = next(i for i, c in enumerate(coords) if not _numbers(c))
        raise InputFileError(where, f"vertex {bad + 1}: expected three numbers, got "
                             f"{b' '.join(coords[bad]).decode(errors='replace')!r}") from None
    quads = np.array(polygons, dtype=np.int64).reshape(-1, 4) if faces else None
    if faces and not len(quads):
        raise InputFileError(where, "no polygons among the face region's vertices")
    return values, quads


def _numbers(parts):
    try:
        [float(p) for p in parts]
    except ValueError:
        return False
    return True


def _landmarks(stream, where):
    try:
        data = json.load(stream)
        landmarks = np.asarray(data["idx_to_landmark_verts"], dtype=np.int64)
    except (ValueError, KeyError, TypeError):
        raise InputFileError(where, "expected JSON with `idx_to_landmark_verts` (the 68 landmark vertices)") from None
    if landmarks.shape != (68,) or landmarks.min() < 0 or landmarks.max() >= FACE_VERTICES:
        raise FacecapError(f"{where}: `idx_to_landmark_verts` must be 68 vertices of the face region (below "
                           f"{FACE_VERTICES}); this is another release of ICT-FaceKit than {RELEASE_COMMIT[:7]} "
                           f"({RELEASE_URL})")
    return landmarks
