"""Atomic output files: a crash or an error never leaves a half-written output behind.

A file is written under a temporary name beside its final one
(``.<name>.facecap-tmp.<machine>.<pid>.<random><suffix>``) and renamed into place in one step. An
interrupted run (SIGINT, SIGTERM) removes its temporary file; one killed outright leaves it, and a later
run removes it (``remove_stale_temporaries``). ``<machine>`` tags the host, its boot and the PID
namespace the writer ran in, so a pid is only ever judged where it means something: a temporary file of
this machine and container whose process is gone is removed at once; one of another machine or
container (a farm node on shared storage) only when it has not been touched for ``STALE_AGE`` seconds.
Outputs get the permissions the user's umask gives new files.

Small text inputs (maps, corrections, seed points) are read with ``read_text_input``: one error naming
the file when it is missing or unreadable.
"""

import contextlib
import hashlib
import json
import os
import re
import socket
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from ..errors import InputFileError
from .limits import MAX_TEXT_BYTES, check_input_file
from .outputs import WRITE_ERRNOS, mark_output, write_error

TMP_MARK = ".facecap-tmp."
#: ``.<name>.facecap-tmp.<machine tag>.<pid>.<random>...`` (and Blender's ``...@`` beside it while it saves)
_TAGGED = re.compile(r"^\..+\.facecap-tmp\.([0-9a-f]{12})\.(\d+)\.[^/]*$")
#: Seconds after which a temporary file of another machine or container (or of an older facecap that
#: did not tag them) counts as left behind: no output takes a day to write.
STALE_AGE = 24 * 3600.0
_UMASK = []
_UMASK_LOCK = threading.Lock()


def umask():
    """The process umask (read once: reading it means setting it)."""
    with _UMASK_LOCK:
        if not _UMASK:
            mask = os.umask(0o022)
            os.umask(mask)
            _UMASK.append(mask)
    return _UMASK[0]


def new_temporary(path, *, suffix=None):
    """A new empty temporary file beside ``path`` named as this program's (ending in ``suffix``,
    default ``path``'s own, so writers that add an extension keep it), with a new file's permissions."""
    path = Path(path)
    suffix = path.suffix if suffix is None else suffix
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}{TMP_MARK}{machine_tag()}.{os.getpid()}.", suffix=suffix,
                                   dir=path.parent)
    except OSError as exc:
        raise write_error(path, exc) from None
    os.close(fd)
    os.chmod(tmp, 0o666 & ~umask())  # mkstemp makes it 0600
    return Path(tmp)


@contextlib.contextmanager
def atomic_path(path, *, suffix=None, kind=None):
    """Yield a temporary path beside ``path`` (see ``new_temporary``); on success it replaces ``path``
    in one step. Whatever happens, the temporary file is gone afterwards. A write that fails for want of
    room or permission (in the block or at the rename) is an ``OutputError`` naming ``path``. ``kind``
    (an output kind of ``solvers.io.outputs``) is recorded with facecap's mark where the writer knows it."""
    tmp = new_temporary(path, suffix=suffix)
    try:
        yield tmp
        mark_output(tmp, kind)  # facecap's own: a later run may replace it (solvers.io.outputs)
        os.replace(tmp, path)
    except OSError as exc:
        if exc.errno in WRITE_ERRNOS:
            raise write_error(path, exc) from None
        raise
    finally:
        if tmp.exists():
            tmp.unlink()


def machine_tag():
    """12 hex digits naming where this process's pids mean something: the host name, this boot of it
    and the PID namespace (a container has its own). Two processes with the same tag can judge each
    other's pids; with different tags they cannot."""
    if not _TAG:
        parts = [socket.gethostname()]
        for source in ("/proc/sys/kernel/random/boot_id", "/proc/self/ns/pid"):
            try:
                parts.append(os.readlink(source) if source.endswith("/pid") else Path(source).read_text().strip())
            except OSError:
                parts.append("")  # not Linux: the host name alone, and the age limit for the rest
        _TAG.append(hashlib.sha256("\0".join(parts).encode("utf-8", "replace")).hexdigest()[:12])
    return _TAG[0]


_TAG = []


def remove_stale_temporaries(folder, *, max_age=STALE_AGE, now=None):
    """Remove this program's temporary files in ``folder`` that no live writer owns; returns them.

    A temporary file written on this machine and in this PID namespace is stale when its process is
    gone; any other one (another farm node, another container, an older facecap's untagged name)
    only when it has not been modified for ``max_age`` seconds.
    """
    folder = Path(folder)
    removed = []
    if not folder.is_dir():
        return removed
    now = time.time() if now is None else now
    mine = machine_tag()
    for entry in folder.iterdir():
        if TMP_MARK not in entry.name or not entry.name.startswith("."):
            continue
        try:
            if not entry.is_file():
                continue
            match = _TAGGED.match(entry.name)
            if match and match.group(1) == mine:
                stale = not pid_alive(int(match.group(2)))
            else:
                stale = now - entry.stat().st_mtime > max_age
            if stale:
                entry.unlink()
                removed.append(entry)
        except OSError:
            pass  # gone meanwhile, or not ours to remove
    return removed


def pid_alive(pid):
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):  # gone, or no pid this system could have
        return False
    except (PermissionError, OSError):
        return True  # someone else's live process
    return True


def file_sha256(path):
    """Hex sha256 of a file's bytes, read in 1 MB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_text_atomic(path, text):
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


#: Lists of numbers longer than this (a report's per-frame figures) are written on one line: indented,
#: json's pure-Python encoder took 0.47 s for the 36,000 residuals of a take's report.
LONG_LIST = 256


def write_json_atomic(path, data):
    lists = []

    def compact(value):
        if isinstance(value, dict):
            return {k: compact(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)) and len(value) > LONG_LIST and \
                all(v is None or type(v) in (int, float) for v in value):
            lists.append(json.dumps(value, allow_nan=True))
            return f"@@facecap-list-{len(lists) - 1}@@"
        return value

    text = json.dumps(compact(data), indent=2, default=_json_default)
    for i, encoded in enumerate(lists):
        text = text.replace(f'"@@facecap-list-{i}@@"', encoded, 1)
    write_text_atomic(path, text + "\n")


def _json_default(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def read_text_input(path, missing="file not found"):
    """The text of a small input file (UTF-8, a byte-order mark allowed). Raises InputFileError naming
    the file: ``missing`` when it does not exist, the reason when it cannot be read or decoded."""
    check_input_file(path, limit=MAX_TEXT_BYTES, missing=missing)
    try:
        return Path(path).read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputFileError(path, missing) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot read: {exc}") from None
