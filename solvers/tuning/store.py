"""Library versions, on disk, and the animator's corrections CSV (issue 7).

A ``LibraryVersion`` (made by ``tuning_take.retune_take``) is what a strategy learned, named by its
content, with its parent's name; ``to_arrays`` / ``from_arrays`` turn it into plain numpy arrays
(names as unicode arrays), stored here as .npz files (no pickles) or by the Blender layer as ID
properties. A write is atomic (a temporary file beside the target, linked into place) and never replaces an
existing file: when the name is taken, ``-2``, ``-3``... is appended, so every retune leaves every
earlier version (and the original) on disk.

Corrections are ``frame,<shape>,<shape>,...`` rows; a blank cell means the animator did not set
that shape on that frame. Shape columns match the character's shapes by name, case, separators
and alias (``solvers.aliases``), so ``JawOpen`` or ``jaw_open`` find ``jawOpen``.
"""

import csv
import hashlib
import json
import os
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..character.aliases import canonical_names, name_key
from ..character.basis import Basis
from ..errors import FacecapError, InputFileError
from ..io.csv_write import text_of_cell
from ..io.files import new_temporary, read_text_input
from ..io.outputs import mark_output, write_error
from ..pipeline import jsonable
from ..strategies.options import ExamplePairs

SUFFIX = ".npz"
FORMAT = "facecap-library-version"
_BASIS_KEYS = ("shape_names", "marker_names", "neutral", "deltas", "lower", "upper")


@dataclass(frozen=True, eq=False)
class LibraryVersion:
    """One stored version of what a strategy learned.

    name : content-hashed (``calibrated-1a2b3c4d`` for an original, ``<root>+tune8f-<hash>`` for a retune)
    parent : name of the version it was tuned from ("" for an original)
    strategy : the strategy it was made for
    kind : "actor_basis" (calibrated/refine), "character_basis" (geometric) or "examples" (linear/rbf/pca)
    payload : Basis (actor or character library) or ExamplePairs (frames of the take, markers=None)
    created : ISO 8601 UTC time
    summary : JSON-ready figures (corrected_rmse_before/after, others_moved, mu, candidate, notes, ...)
    shapes : the character's shape names it was made for
    """

    name: str
    parent: str
    strategy: str
    kind: str
    payload: object
    created: str
    summary: dict = field(default_factory=dict)
    shapes: tuple = ()

    def to_arrays(self):
        """``{key: ndarray}`` (numbers, and unicode arrays for names) holding everything ``from_arrays`` needs."""
        out = {"format": np.array(FORMAT), "format_version": np.array(1, dtype=np.int64),
               "name": np.array(self.name), "parent": np.array(self.parent), "strategy": np.array(self.strategy),
               "kind": np.array(self.kind), "created": np.array(self.created),
               "summary": np.array(json.dumps(jsonable(self.summary), sort_keys=True)),
               "shapes": np.array(self.shapes, dtype=str).reshape(-1)}
        out.update(_payload_arrays(self.kind, self.payload))
        return out

    @classmethod
    def from_arrays(cls, d):
        """The version stored by ``to_arrays`` (a dict, an ``np.load`` result or lists from ID properties)."""
        def get(key):
            if key not in d:
                raise FacecapError(f"library version: missing array '{key}' (not a facecap library version?)")
            return np.asarray(d[key])

        if _text(get("format")) != FORMAT:
            raise FacecapError(f"library version: 'format' must be '{FORMAT}'; got '{_text(get('format'))}'")
        if int(get("format_version")) != 1:
            raise FacecapError(f"library version: unsupported format_version {int(get('format_version'))} (expected 1)")
        kind = _text(get("kind"))
        if kind == "examples":
            payload = ExamplePairs(get("example_frames").astype(np.float64), get("example_weights").astype(np.float64),
                                   _names(get("example_names")), None)
        elif kind in ("actor_basis", "character_basis"):
            a = {k: get(k) for k in _BASIS_KEYS}
            payload = Basis(_names(a["shape_names"]), _names(a["marker_names"]), a["neutral"], a["deltas"],
                            a["lower"], a["upper"])
        else:
            raise FacecapError(f"library version: unknown kind '{kind}'")
        try:
            summary = json.loads(_text(get("summary")))
        except json.JSONDecodeError as exc:
            raise FacecapError(f"library version: 'summary' is not valid JSON ({exc.msg})") from None
        return cls(name=_text(get("name")), parent=_text(get("parent")), strategy=_text(get("strategy")), kind=kind,
                   payload=payload, created=_text(get("created")), summary=summary, shapes=_names(get("shapes")))


def _text(a):
    a = np.asarray(a)
    return str(a.item() if a.ndim == 0 else a.reshape(-1)[0]) if a.size else ""


def _names(a):
    return tuple(str(s) for s in np.asarray(a).reshape(-1))


def _payload_arrays(kind, payload):
    if kind == "examples":
        return {"example_frames": np.asarray(payload.frames, dtype=np.float64),
                "example_weights": np.asarray(payload.weights, dtype=np.float64),
                "example_names": np.array(payload.names, dtype=str).reshape(-1)}
    b = payload
    return {"shape_names": np.array(b.shape_names, dtype=str), "marker_names": np.array(b.marker_names, dtype=str),
            "neutral": b.neutral, "deltas": b.deltas, "lower": b.lower, "upper": b.upper}


def payload_digest(kind, payload):
    """Short content hash of a payload (version names: equal content, equal name)."""
    h = hashlib.sha1()
    for key, a in sorted(_payload_arrays(kind, payload).items()):
        h.update(key.encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:8]


def _safe(name):
    """A file name for a version name (``+`` and letters kept, anything else -> ``_``)."""
    return re.sub(r"[^A-Za-z0-9+._-]", "_", name).strip(".") or "version"


def _write_new(path, write):
    """Write through ``write(tmp_path)`` and link the result to ``path`` or the first free
    ``<stem>-N<suffix>``; never replaces a file. Returns the path written."""
    path = Path(path)
    tmp = new_temporary(path)
    try:
        try:
            write(tmp)
        except OSError as exc:  # a full disk, a permission taken away: one line naming the file
            raise write_error(path, exc) from None
        mark_output(tmp)
        for n in range(1, 10000):
            target = path if n == 1 else path.with_name(f"{path.stem}-{n}{path.suffix}")
            try:
                os.link(tmp, target)  # fails if the target exists: no overwrite, even under a race
                return target
            except FileExistsError:
                continue
            except OSError:  # a file system without hard links: exclusive create, then replace
                try:
                    os.close(os.open(target, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
                except FileExistsError:
                    continue
                os.replace(tmp, target)
                return target
        raise FacecapError(f"{path}: no free file name (tried 9,999 suffixes)")
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def save_version(version, destination):
    """Store ``version`` as an .npz; returns the path written.

    destination : a folder (the file is ``<version name>.npz`` in it) or an ``.npz`` path. An
        existing file is never replaced: a ``-2``, ``-3``... suffix is added instead.
    """
    destination = Path(destination)
    path = destination if destination.suffix == SUFFIX else destination / (_safe(version.name) + SUFFIX)
    arrays = version.to_arrays()

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)

    return _write_new(path, write)


def load_version(path):
    """The LibraryVersion stored in an .npz by ``save_version``; errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "library version file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        reason = "empty file" if path.stat().st_size == 0 else str(exc) or type(exc).__name__
        raise InputFileError(path, f"not a library version (.npz): {reason}") from None
    try:
        return LibraryVersion.from_arrays(arrays)
    except FacecapError as exc:
        raise InputFileError(path, str(exc)) from None
    except (KeyError, ValueError, TypeError, IndexError) as exc:
        raise InputFileError(path, f"not a library version: {exc}") from None


def list_versions(folder):
    """``[(path, LibraryVersion), ...]`` of the versions in ``folder``, oldest first (by creation
    time, then name); .npz files that are not versions are skipped."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputFileError(folder, "library folder not found")
    out = []
    for path in sorted(folder.glob("*" + SUFFIX)):
        try:
            out.append((path, load_version(path)))
        except InputFileError:
            continue
    return sorted(out, key=lambda pv: (pv[1].created, pv[1].name))


def _shape_lookup(shape_names):
    lookup = {}
    for n in shape_names:
        lookup.setdefault(name_key(n), n)
        canon = canonical_names(n)
        if len(canon) == 1:
            lookup.setdefault(name_key(canon[0]), n)
    return lookup


def _match_shape(header, lookup):
    hit = lookup.get(name_key(header))
    if hit is None:
        canon = canonical_names(header)
        hit = lookup.get(name_key(canon[0])) if len(canon) == 1 else None
    return hit


def read_corrections_csv(path, shape_names=None):
    """Read an animator's corrections: ``frame,<shape>,...`` rows, blank = not corrected.

    Parameters
    ----------
    path : CSV file (comma separated, header first)
    shape_names : the character's shapes; header names are matched to them (alias and case
        insensitive) and the result uses the character's spelling. None keeps the header names.

    Returns
    -------
    {frame number (float): {shape: value}} for the rows that set at least one shape

    Raises
    ------
    InputFileError naming the file, line and column of the first problem.
    """
    path = Path(path)
    text = read_text_input(path, "corrections file not found")
    rows = [(i + 1, row) for i, row in enumerate(csv.reader(text.splitlines())) if any(c.strip() for c in row)]
    if not rows:
        raise InputFileError(path, "empty file; expected a header 'frame,<shape>,...'")
    line, header = rows[0]
    header = [text_of_cell(h.strip()) for h in header]  # a formula-like name as facecap writes it ('=...)
    if header[0].lower() != "frame":
        raise InputFileError(path, f"the first column must be 'frame'; got {header[0]!r}", line=line, field="column 1")
    lookup = None if shape_names is None else _shape_lookup(shape_names)
    shapes, seen = [], {}
    for col, h in enumerate(header[1:], start=2):
        shape = h if lookup is None else _match_shape(h, lookup)
        if not h or shape is None:
            raise InputFileError(path, f"shape {h!r} is not on the character" if h else "empty shape name",
                                 line=line, field=f"column {col}")
        if shape in seen:
            raise InputFileError(path, f"{h!r} names the same shape as column {seen[shape]} ({shape})", line=line,
                                 field=f"column {col}")
        seen[shape] = col
        shapes.append(shape)
    out = {}
    for line, row in rows[1:]:
        if len(row) != len(header):
            raise InputFileError(path, f"{len(row)} cells; the header has {len(header)}", line=line)
        frame = _cell(path, line, 1, row[0], "frame number")
        if frame is None:
            raise InputFileError(path, "missing frame number", line=line, field="column 1")
        if frame in out:
            raise InputFileError(path, f"frame {frame:g} appears twice", line=line, field="column 1")
        values = {}
        for col, (shape, cell) in enumerate(zip(shapes, row[1:]), start=2):
            value = _cell(path, line, col, cell, f"value of {shape}")
            if value is not None:
                values[shape] = value
        if values:
            out[frame] = values
    if not out:
        raise InputFileError(path, "no corrected value in any row")
    return out


def _cell(path, line, col, text, what):
    text = text.strip()
    if not text:
        return None
    try:
        value = float(text)
    except ValueError:
        raise InputFileError(path, f"{what} must be a number; got {text!r}", line=line, field=f"column {col}") from None
    if not np.isfinite(value):
        raise InputFileError(path, f"{what} must be finite; got {text!r}", line=line, field=f"column {col}")
    return value
