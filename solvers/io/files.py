"""Atomic output files: a crash or an error never leaves a half-written output behind.

A file is written under a temporary name beside its final one (``.<name>.facecap-tmp.<pid>.<tag><suffix>``)
and renamed into place in one step. An interrupted run (SIGINT, SIGTERM) removes its temporary file;
one killed outright leaves it, and a later run removes it (``remove_stale_temporaries``: the process
that wrote it is gone). Outputs get the permissions the user's umask gives new files.

Small text inputs (maps, corrections, seed points) are read with ``read_text_input``: one error naming
the file when it is missing or unreadable.
"""

import contextlib
import json
import os
import re
import tempfile
import threading
from pathlib import Path

import numpy as np

from ..errors import InputFileError

TMP_MARK = ".facecap-tmp."
_STALE = re.compile(r"^\..+\.facecap-tmp\.(\d+)\.[^/]*$")
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
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix if suffix is None else suffix
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}{TMP_MARK}{os.getpid()}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~umask())  # mkstemp makes it 0600
    return Path(tmp)


@contextlib.contextmanager
def atomic_path(path, *, suffix=None):
    """Yield a temporary path beside ``path`` (see ``new_temporary``); on success it replaces ``path``
    in one step. Whatever happens, the temporary file is gone afterwards."""
    tmp = new_temporary(path, suffix=suffix)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def remove_stale_temporaries(folder):
    """Remove this program's temporary files in ``folder`` whose writing process is gone; returns them."""
    folder = Path(folder)
    removed = []
    if not folder.is_dir():
        return removed
    for entry in folder.iterdir():
        match = _STALE.match(entry.name)
        if match and entry.is_file() and not _alive(int(match.group(1))):
            try:
                entry.unlink()
                removed.append(entry)
            except OSError:
                pass
    return removed


def _alive(pid):
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True  # someone else's live process
    return True


def write_text_atomic(path, text):
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_json_atomic(path, data):
    write_text_atomic(path, json.dumps(data, indent=2, default=_json_default) + "\n")


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
    try:
        return Path(path).read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputFileError(path, missing) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot read: {exc}") from None
