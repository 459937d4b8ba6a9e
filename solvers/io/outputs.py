"""The output policy: what any facecap command may write, decided in one place before any work.

Every command that writes files a user names (``retarget``, ``tune``, ``track``, ``batch``, ``convert``,
``demo``, the review page and the exports; ``bench`` writes only in its own temporary folders) describes its outputs as
``Output(key, path, kind)`` and calls ``check_outputs`` before it reads or solves anything. An output

* is never one of the command's inputs (after ``~``, ``..``, symbolic and hard links and, on a
  case-insensitive file system, case), nor a file of an input's image sequence or folder;
* is never another output, nor the folder of another output;
* is never a folder, a device, a FIFO or a socket, nor below a symbolic-link loop;
* replaces an existing file only when that file is facecap's own earlier output of the same kind: it
  carries the mark facecap puts on what it writes (an extended attribute, ``MARK``, where the file system
  keeps them) and its first bytes are of that kind (``KINDS``); anything else is refused, naming
  ``--overwrite``. An existing output .blend is not replaced but added to (``headless``).

Free space is checked once the sizes are known (``check_free_space``: before the solve). Files are
written atomically (``files.atomic_path``) and a write that fails all the same (a full disk, a
permission taken away) is one ``OutputError`` naming the file (``write_error``).
"""

import csv
import errno
import os
import re
import shutil
import stat
from dataclasses import dataclass
from fnmatch import fnmatchcase
from pathlib import Path

from ..errors import ConfigError, FacecapError
from .limits import file_kind

#: Room a temporary file's name needs beside its output (``files.new_temporary``).
TEMP_NAME_ROOM = 64
#: Bytes read from an existing file to recognise it.
HEAD_BYTES = 1 << 16


class OutputError(FacecapError):
    """An output cannot or may not be written; the message names it and what to do."""


@dataclass(frozen=True)
class Output:
    """One file a command writes: ``key`` as the user names it (``[output.weights]``, ``--summary``,
    ``OUT``), its ``path`` and its ``kind`` (a ``KINDS`` name)."""

    key: str
    path: Path
    kind: str


def _head(path, size=HEAD_BYTES):
    try:
        with open(path, "rb") as fh:
            return fh.read(size)
    except OSError:
        return b""


def _first_line(head):
    text = head.decode("utf-8-sig", "replace")
    for line in text.splitlines():
        if line.strip():
            return line
    return ""


def _frame_header(head):
    """The header cells of a CSV that starts with a ``frame`` column, else None."""
    line = _first_line(head)
    counts = {d: line.count(d) for d in (",", ";", "\t", "|")}
    delimiter = max(counts, key=counts.get)
    cells = next(csv.reader([line], delimiter=delimiter), [])
    return cells if cells and cells[0].strip().lower() == "frame" else None


def _coordinate_columns(cells):
    rest = [c for c in cells[1:] if c.strip().lower() != "segment"]
    return bool(rest) and all(c.rpartition("_")[2].lower() in ("x", "y", "z") for c in rest)


def _json_keys(head):
    """Top-level keys named in the first bytes of a JSON object (a cheap look, not a parse)."""
    text = head.decode("utf-8-sig", "replace").lstrip()
    if not text.startswith("{"):
        return set()
    return set(re.findall(r'"([A-Za-z_]+)"\s*:', text[:HEAD_BYTES]))


def _is_blend(head):
    return head.startswith((b"BLENDER", b"\x1f\x8b", b"\x28\xb5\x2f\xfd"))


#: kind -> (what it is, for messages; whether the first bytes of an existing file are one)
KINDS = {
    "blend": (".blend file", _is_blend),
    "weights_csv": ("weights CSV (frame,<shape>,...)",
                    lambda h: (c := _frame_header(h)) is not None and not _coordinate_columns(c)),
    "markers_csv": ("marker CSV (frame,<marker>_x,...)",
                    lambda h: (c := _frame_header(h)) is not None and _coordinate_columns(c)),
    "report": ("facecap report (JSON)", lambda h: bool({"facecap_report"} & _json_keys(h))
               or {"strategy", "residual_rms_mm"} <= _json_keys(h)),
    "track_report": ("facecap track report (JSON)", lambda h: bool({"facecap_track", "frame_numbering"}
                                                                    & _json_keys(h))),
    "batch_summary": ("facecap batch summary (JSON)", lambda h: "facecap_batch" in _json_keys(h)),
    "batch_csv": ("facecap batch summary (CSV)", lambda h: _first_line(h).startswith("take,status,")),
    "markers_json": ("facecap marker JSON", lambda h: "facecap_markers" in _json_keys(h)),
    "html": ("facecap page (HTML)", lambda h: b'name="generator" content="facecap' in h
             or b"<title>facecap review" in h or b"<title>facecap batch" in h),
    "c3d": ("C3D file", lambda h: len(h) >= 2 and h[1] == 0x50 and h[0] >= 2),
    "trc": ("TRC file", lambda h: h.startswith(b"PathFileType")),
    "npz": ("stored library (.npz)", lambda h: h.startswith(b"PK\x03\x04") and b"shape_names" in h[:4096]),
    "template": ("facecap human template (.npz)", lambda h: h.startswith(b"PK\x03\x04") and b"format.npy" in h[:128]),
    "png": ("PNG image", lambda h: h.startswith(b"\x89PNG\r\n\x1a\n")),
    "extension_zip": ("facecap extension zip", lambda h: h.startswith(b"PK\x03\x04")),
    "bench_json": ("facecap benchmark JSON", lambda h: {"rows", "summary"} <= _json_keys(h)),
    "release_sums": ("facecap release checksums", lambda h: re.match(rb"[0-9a-f]{64}  facecap-", h) is not None),
    "release_notes": ("facecap release notes", lambda h: h.startswith(b"# FaceCap ")),
    "config_docs": ("facecap config reference", lambda h: h.startswith(b"# Config reference")),
    "commands_docs": ("facecap command reference", lambda h: h.startswith(b"# Command reference")),
    "glb": ("binary glTF (.glb)", lambda h: h.startswith(b"glTF")),
    "fbx": ("FBX file", lambda h: h.startswith(b"Kaydara FBX Binary") or h.lstrip().startswith(b"; FBX")),
    "plotly_js": ("plotly.js script", lambda h: b"plotly.js v" in h[:400]),
}


#: The extended attribute every file facecap writes carries (``files.atomic_path``), where the file system
#: keeps them: what tells facecap's own output from someone's file of the same format (a weights CSV
#: exported elsewhere, a copy the user made).
MARK = "user.facecap.output"
#: Kinds an existing file of which is added to, not replaced: any such file qualifies, marked or not
ADDED_TO = ("blend",)
#: Kinds judged by their first bytes alone: the checkout's generated references, kept in version control
#: (which keeps no mark)
BY_CONTENT = ("config_docs", "commands_docs")


def mark_output(path, kind=None):
    """Mark ``path`` as written by facecap, with its ``kind`` (a KINDS key) where the writer knows it
    (nothing happens where extended attributes are not kept)."""
    try:
        os.setxattr(path, MARK, kind.encode() if kind in KINDS else b"1")
    except (OSError, AttributeError):  # a file system without user attributes; not Linux
        pass


def output_mark(path):
    """The mark of ``path``: the kind its writer recorded, True when it carries facecap's mark without a
    kind, False when it could carry one but does not, None when the file system (or platform) keeps no
    extended attributes (then its content alone is judged)."""
    try:
        value = os.getxattr(path, MARK).decode("ascii", "replace")
        return value if value in KINDS else True
    except AttributeError:
        return None
    except OSError as exc:
        return False if exc.errno in (errno.ENODATA, getattr(errno, "ENOATTR", errno.ENODATA)) else None


def is_kind(path, kind):
    """Whether the existing file ``path`` is facecap's own output of ``kind``: its mark says so where its
    writer recorded the kind (a rig's weights CSV whose control columns end in _x/_y/_z reads like a
    marker CSV), else its first bytes are of that kind and, where the file system keeps extended
    attributes, it carries facecap's mark."""
    mark = output_mark(path)
    if kind not in ADDED_TO + BY_CONTENT and mark is False:
        return False
    if isinstance(mark, str):
        return mark == kind
    return KINDS[kind][1](_head(path))


def _fail(message, config):
    if config is not None:
        raise ConfigError(message, path=config)
    raise OutputError(message)


def resolved(path):
    """``path`` with ``~`` expanded and ``..`` / symbolic links resolved (the parts that exist).

    Raises OutputError for a symbolic-link loop.
    """
    try:
        return Path(os.path.realpath(os.path.expanduser(str(path)), strict=False))
    except (OSError, RuntimeError, ValueError) as exc:  # a loop (3.11 raises RuntimeError), NUL bytes
        raise OutputError(f"{path}: cannot be resolved ({exc})") from None


def user_path(value, base=None):
    """An absolute Path of a path a user gave (``~`` expanded, relative to ``base``), links resolved,
    except where resolving would hide what the checks must see: a special file (``/dev/stdout`` links
    to a pipe's name in /proc, which does not exist as a file) and a symbolic-link loop keep their
    spelling (the output policy and the readers then say what they are)."""
    p = Path(os.path.expanduser(str(value)))
    if base is not None:
        p = Path(base) / p
    try:
        mode = os.stat(p).st_mode
        if not stat.S_ISREG(mode) and not stat.S_ISDIR(mode):
            return Path(os.path.abspath(p))
    except (OSError, ValueError):
        pass  # missing (an output to be), or a loop: resolved below as far as it goes
    try:
        return p.resolve()
    except (OSError, RuntimeError):  # a symbolic-link loop (3.11 raises RuntimeError)
        return Path(os.path.abspath(p))


def _case_insensitive(folder):
    """Whether ``folder`` (or its nearest existing ancestor) lives on a case-insensitive file system."""
    folder = Path(folder)
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    flipped = Path(str(folder).swapcase())
    try:
        return flipped != folder and flipped.exists() and os.path.samefile(flipped, folder)
    except OSError:
        return False


def path_key(path):
    """A comparable key of ``path`` (resolved; casefolded on a case-insensitive file system)."""
    p = resolved(path)
    return str(p).casefold() if _case_insensitive(p.parent) else str(p)


def same_file(a, b):
    """Whether paths ``a`` and ``b`` name one file (spelling, links, case, hard links)."""
    if path_key(a) == path_key(b):
        return True
    try:
        return os.path.exists(a) and os.path.exists(b) and os.path.samefile(a, b)
    except OSError:
        return False


_PRINTF = re.compile(r"%0?(\d*)d")


def _in_input(out, inp):
    """Whether output ``out`` is a file that input ``inp`` reads: the file itself, a file of its
    folder, or one its frame pattern (``%04d``) or glob matches. Returns how, or None."""
    if same_file(out, inp):
        return "is the same file as"
    text = os.path.expanduser(str(inp))
    out_key = path_key(out)
    if _PRINTF.search(text) or any(c in text for c in "*?["):
        parent = path_key(Path(text).parent)
        pattern = _PRINTF.sub(lambda m: "[0-9]" * int(m.group(1)) if m.group(1) else "*", Path(text).name)
        if os.path.dirname(out_key) == parent and fnmatchcase(os.path.basename(out_key), pattern):
            return "is a file of the image sequence of"
        return None
    if os.path.isdir(text) and os.path.dirname(out_key) == path_key(text):
        return "is inside the folder read as"
    return None


def check_outputs(outputs, inputs=None, *, overwrite=False, config=None, folders=()):
    """Raise (one line naming the key and what to do) unless every output may be written.

    outputs : iterable of Output
    inputs : {key: path} of what the command reads (files, folders, frame patterns, globs)
    overwrite : replace existing files that are not facecap's own output of the output's kind
    config : the config file the keys belong to (then ConfigError, with the file named)
    folders : [(key, path)] of folders the command writes files into (checked to be creatable)

    Raises
    ------
    ConfigError (with ``config``) or OutputError.
    """
    outputs = [o for o in outputs if o.path is not None]
    inputs = {k: v for k, v in (inputs or {}).items() if v is not None}
    for out in outputs:  # what it clashes with first: no flag allows writing over an input
        try:
            resolved(out.path)
        except OutputError as exc:
            _fail(f"{out.key} {exc}", config)
        for in_key, inp in inputs.items():
            how = _in_input(out.path, inp)
            if how is not None:
                _fail(f"{out.key} {how} {in_key} ({resolved(inp)}): a command never writes over what it reads",
                      config)
    for i, a in enumerate(outputs):
        for b in outputs[i + 1:]:
            if same_file(a.path, b.path):
                _fail(f"{a.key} and {b.key} are the same file ({resolved(a.path)}): one would be lost", config)
            for outer, inner in ((a, b), (b, a)):
                if Path(path_key(inner.path)).is_relative_to(path_key(outer.path)):
                    _fail(f"{outer.key} ({resolved(outer.path)}) is a folder of {inner.key}: give the file a "
                          "name of its own", config)
    for out in outputs:
        check_output(out, overwrite=overwrite, config=config)
    for key, folder in folders:
        for in_key, inp in inputs.items():
            if same_file(folder, inp):
                _fail(f"{key} is {in_key} ({resolved(inp)}); it must be a folder for the outputs", config)
        check_location(folder, key, config=config, folder=True)


def check_files_in(folder, names, key, kind, *, inputs=None, overwrite=False, owned=()):
    """The output policy for a command writing the files ``names`` (of ``kind``) into the folder ``folder`` that
    the option ``key`` names: each file as any output (``check_outputs``), the folder writable. In a folder of
    ``owned`` (facecap's own, e.g. the checkout's docs/images) its files are replaced as they are. Returns the
    folder."""
    folder = Path(os.path.expanduser(str(folder)))
    mine = any(same_file(folder, o) for o in owned)
    check_outputs([Output(f"{key} ({n})", folder / n, kind) for n in names], inputs, overwrite=overwrite or mine,
                  folders=[(key, folder)])
    return folder


def check_output(out, *, overwrite=False, config=None):
    """The checks of one output on its own (see ``check_outputs``)."""
    path = Path(os.path.expanduser(str(out.path)))
    where = f"{out.key} {path}"
    try:
        real = resolved(path)
        try:
            st = os.stat(path)
        except FileNotFoundError:  # also "sub/../x" with no sub yet: the folders made, it is the file there
            st = os.stat(real)
            path = real
    except FileNotFoundError:
        st = None
    except OutputError as exc:
        _fail(f"{out.key} {exc}", config)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            _fail(f"{where}: a symbolic link loop", config)
        st = None  # e.g. a missing folder on the way: check_location says what is wrong
    if st is not None:
        if stat.S_ISDIR(st.st_mode):
            _fail(f"{where}: is a folder; a file name is needed", config)
        if not stat.S_ISREG(st.st_mode):
            _fail(f"{where}: is {file_kind(st.st_mode)}; facecap writes only regular files", config)
        if not overwrite and not is_kind(path, out.kind):
            _fail(f"{where}: exists and is not a {KINDS[out.kind][0]} facecap wrote; give another path, or "
                  "--overwrite to replace it", config)
    check_location(path, out.key, config=config)


def check_location(path, key, *, config=None, folder=False):
    """Raise naming ``key`` when ``path`` cannot be written: a file where a folder is needed (or the
    reverse), a read-only folder, a name or path too long for the file system, a link loop."""
    path = Path(os.path.expanduser(str(path)))

    def fail(message):
        _fail(f"{key} {path}: {message}", config)

    try:
        exists = path.exists()
    except OSError as exc:
        fail(f"cannot be reached ({exc.strerror or exc})")
    if exists:
        if folder and not path.is_dir():
            fail("is a file; a folder is needed")
        if not folder and path.is_dir():
            fail("is a folder; a file name is needed")
        if not os.access(path, os.W_OK):
            fail("is not writable")
    parent = path.parent
    try:
        while not parent.exists():
            if parent.parent == parent:
                break
            parent = parent.parent
    except OSError as exc:
        fail(f"cannot be reached ({exc.strerror or exc})")
    if not parent.is_dir():
        fail(f"cannot be created: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        fail(f"cannot be written: the folder {parent} is read-only")
    try:
        name_max = os.pathconf(parent, "PC_NAME_MAX")
        path_max = os.pathconf(parent, "PC_PATH_MAX")
    except (OSError, ValueError, AttributeError):  # no pathconf (Windows): the usual limits
        name_max, path_max = 255, 4096
    longest = max((len(os.fsencode(part)) for part in path.parts), default=0)
    if longest > name_max - TEMP_NAME_ROOM:
        fail(f"a name in the path is {longest} bytes; this file system allows {name_max} (less the room a "
             "temporary file beside it needs)")
    if len(os.fsencode(str(resolved(path)))) > path_max - TEMP_NAME_ROOM:
        fail(f"the path is longer than this file system allows ({path_max} bytes)")


def check_free_space(sizes, *, config=None):
    """Raise when a file system lacks the room for what will be written on it.

    sizes : [(Output, expected bytes)], estimates on the low side (a refusal must be certain).
    """
    need, first = {}, {}
    for out, size in sizes:
        folder = Path(os.path.expanduser(str(out.path))).parent
        while not folder.exists() and folder != folder.parent:
            folder = folder.parent
        try:
            device = os.stat(folder).st_dev
        except OSError:
            continue
        need[device] = need.get(device, 0) + int(size)
        first.setdefault(device, (out, folder))
    for device, total in need.items():
        out, folder = first[device]
        try:
            free = shutil.disk_usage(folder).free
        except OSError:
            continue
        if free < total:
            _fail(f"{out.key} {out.path}: not enough free space: the outputs there need about "
                  f"{_size(total)} and {folder} has {_size(free)} free", config)


def _size(n):
    for unit in ("bytes", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024


#: errno -> what it means for an output, for ``write_error``
_WRITE_ERRORS = {errno.ENOSPC: "no space left on the device", errno.EDQUOT: "the disk quota is exceeded",
                 errno.EACCES: "permission denied", errno.EPERM: "permission denied",
                 errno.EROFS: "the file system is read-only", errno.EFBIG: "the file is too large",
                 errno.ENAMETOOLONG: "the name is too long", errno.EIO: "an input/output error"}


#: errnos of a write that failed for want of room or permission (not a bug)
WRITE_ERRNOS = frozenset(_WRITE_ERRORS)


def write_error(path, exc):
    """An OutputError for ``exc`` (an OSError, or Blender's RuntimeError) raised writing ``path``."""
    reason = _WRITE_ERRORS.get(getattr(exc, "errno", None))
    if reason is None:
        text = str(exc)
        reason = next((r for code, r in _WRITE_ERRORS.items() if os.strerror(code) in text), None) \
            or (getattr(exc, "strerror", None) or text.removeprefix("Error: ").strip() or type(exc).__name__)
    return OutputError(f"{path}: cannot be written: {reason}; nothing was written there")
