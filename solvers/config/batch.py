"""The takes of a batch: take configs, folders of them, and batch files with shared defaults.

A *batch file* is a TOML file with a ``[batch]`` table::

    [batch]
    takes = ["takes/", "pickups/take_31.toml", "day2/*.toml"]   # files, folders, globs (this file's folder)

    [defaults.target]                # any take-config section, merged into every take
    blend = "character.blend"
    object = "Face"

    [defaults.output]
    weights = "out/{take}.csv"       # {take}: the take config's file name without .toml

Every key under ``[defaults]`` is checked like a take config's (``solvers.options``); a take's own
keys win over the defaults, key by key inside each section. Paths in the defaults resolve against
the batch file's folder, paths in a take against the take's. A folder given as a take means every
``*.toml`` in it (not recursive), or, when it holds batch files, those batch files. Batch files do
not nest. Reaching one take config twice is an error (which defaults would it get?).

A take config that cannot be read is not an error of the batch: it becomes a ``BatchTake`` with its
``error`` (reported as failed, the others run).
"""

import copy
import glob
import hashlib
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError, FacecapError, Problems, suggest, table_problems
from ..options import BY_NAME, OPTIONS, SECTIONS
from . import read_config_toml
from .paths import take_inputs

#: The sections of a batch file, and the keys of its [batch] table
BATCH_SECTIONS = ("batch", "defaults")
BATCH_KEYS = ("takes",)
#: The placeholder of a take's name in the defaults' [output] values
TAKE_PLACEHOLDER = "{take}"


@dataclass(frozen=True)
class BatchTake:
    """One take of a batch.

    name : the take's name in the summary (its config file's stem; made unique with its folders)
    path : the take config (absolute)
    data : its TOML tables with the defaults merged in (defaults' paths made absolute); None if unread
    error : why the take cannot run (one line), or None
    listed_by : the batch file that listed it (None: the command line)
    """

    name: str
    path: Path
    data: dict = None
    error: str = None
    listed_by: Path = None


def is_batch_data(data):
    """Whether TOML tables ``data`` are a batch file (it has a ``[batch]`` table)."""
    return isinstance(data.get("batch"), dict)


def collect_takes(arguments):
    """The takes named by the command line's ``arguments`` (configs, folders, batch files), in order.

    A folder means its batch file, else every TOML in it, else (a folder of take folders) every TOML
    one level down.

    Raises
    ------
    ConfigError for a missing argument, a bad batch file, nested batch files or a take reached twice.
    """
    entries = []  # (take config path, defaults or None, batch file or None)
    for argument in arguments:
        path = Path(os.path.expanduser(str(argument))).resolve()
        if path.is_dir():
            batch_files = [p for p in _tomls(path) if _is_batch_file(p)]
            for file in batch_files or []:
                entries += _batch_entries(file)
            if not batch_files:
                # a shoot laid out as one folder per take (shoot/take51/take51.toml): its take folders' configs
                found = _tomls(path) or [p for sub in sorted(path.iterdir()) if sub.is_dir() for p in _tomls(sub)]
                entries += [(p, None, None) for p in found]
        elif path.suffix.lower() == ".toml" and path.is_file() and _is_batch_file(path):
            entries += _batch_entries(path)
        elif path.exists() or path.suffix.lower() == ".toml":
            entries.append((path, None, None))  # a missing take config is that take's failure
        else:
            raise ConfigError("no such take config, folder or batch file", path=path)
    seen = {}
    for path, _, by in entries:
        if path in seen:
            first = seen[path] or "the command line"
            raise ConfigError(f"this take is listed twice (by {first} and {by or 'the command line'})", path=path)
        seen[path] = by
    names = take_names([p for p, _, _ in entries])
    return [_take(name, path, defaults, by) for name, (path, defaults, by) in zip(names, entries)]


def take_names(paths):
    """Unique short names: the file stem, with as many parent folders as it takes to tell them apart."""
    names = [p.stem for p in paths]
    depth = 1
    while len(set(names)) < len(names) and depth < max(len(p.parts) for p in paths):
        dup = {n for n in names if names.count(n) > 1}
        names = ["/".join(p.with_suffix("").parts[-depth - 1:]) if n in dup else n for n, p in zip(names, paths)]
        depth += 1
    return names


def _tomls(folder):
    """The .toml files of ``folder``; a symbolic link to another one of them is that one, not a second take."""
    files = [p for p in folder.glob("*.toml") if p.is_file()]
    kept, seen = [], set()
    for p in sorted(files, key=lambda p: (p.is_symlink(), p.name)):  # real files first: they keep their name
        real = p.resolve()
        if real not in seen:
            seen.add(real)
            kept.append(p)
    return sorted(kept)


def _is_batch_file(path):
    try:
        return is_batch_data(read_config_toml(path)[1])
    except ConfigError:
        return False  # a broken take config: that take's error, reported when it is read


def _batch_entries(path):
    """[(take config, defaults, batch file)] of a batch file."""
    path, data = read_config_toml(path)
    defaults = read_defaults(path, data)
    out = []
    for pattern in data["batch"]["takes"]:
        found = _expand(path, pattern)
        for take in found:
            if take != path and _is_batch_file(take):
                raise ConfigError(f"{take} is a batch file; batch files do not nest", path=path, key="batch.takes")
        out += [(take, defaults, path) for take in found if take != path]
    return out


def _expand(batch_file, pattern):
    """The take configs one entry of ``[batch] takes`` names."""
    full = batch_file.parent / os.path.expanduser(pattern)
    if glob.has_magic(pattern):
        found = sorted(Path(p).resolve() for p in glob.glob(str(full)) if p.endswith(".toml"))
        if not found:
            raise ConfigError(f"'{pattern}' matches no .toml file", path=batch_file, key="batch.takes")
        return found
    full = full.resolve()
    if full.is_dir():
        found = [p for p in _tomls(full) if not _is_batch_file(p)]
        if not found:
            raise ConfigError(f"the folder '{pattern}' holds no take config", path=batch_file, key="batch.takes")
        return found
    return [full]  # a missing file: that take's failure


def read_defaults(path, data):
    """Check a batch file's tables; returns its ``[defaults]`` with every path made absolute
    (against the batch file's folder), ``{take}`` left in place.

    Raises
    ------
    ConfigError naming the batch file and the key.
    """
    problems = Problems()
    for section in data:
        if section not in ("batch", "defaults"):
            problems.add(ConfigError(f"unknown section [{section}] in a batch file{suggest(section, BATCH_SECTIONS)}; "
                                     "known: batch, defaults", path=path))
    batch = data["batch"]
    for key in batch:
        if key not in BATCH_KEYS:
            problems.add(ConfigError(f"unknown key{suggest(key, BATCH_KEYS)}; known keys: {', '.join(BATCH_KEYS)}",
                                     path=path, key=f"batch.{key}"))
    takes = batch.get("takes")
    if not (isinstance(takes, list) and takes and all(isinstance(t, str) and t.strip() and "\0" not in t
                                                      for t in takes)):
        problems.add(ConfigError(f"expected a list of take configs, folders or globs; got {takes!r}", path=path,
                                 key="batch.takes"))
    defaults = data.get("defaults", {})
    if not isinstance(defaults, dict):
        problems.add(ConfigError("[defaults] must be a table of take-config sections", path=path))
        defaults = {}
    for key, message, covers in table_problems(defaults, OPTIONS, prefix="defaults.", required=False):
        problems.add(ConfigError(message, path=path, key=key), covers=covers)
    out = {}
    for section, body in defaults.items():
        if section not in SECTIONS or not isinstance(body, dict):
            continue
        out[section] = {}
        for key, value in body.items():
            name = f"defaults.{section}.{key}"
            if problems.covered(name):
                continue
            opt = BY_NAME.get(f"{section}.{key}") or BY_NAME["controls.<shape>"]
            if isinstance(value, str) and TAKE_PLACEHOLDER in value and section != "output":
                problems.add(ConfigError(f"{TAKE_PLACEHOLDER} is only filled in [defaults.output]", path=path,
                                         key=name))
            out[section][key] = _absolute(path.parent, value) if _is_path(opt) else copy.deepcopy(value)
    problems.raise_any()
    return out


def _is_path(option):
    kinds = option.kind if isinstance(option.kind, tuple) else (option.kind,)
    return "path" in kinds


def _absolute(folder, value):
    return value if not isinstance(value, str) else str(folder / os.path.expanduser(value))


def merge_defaults(defaults, data, take):
    """A take's tables with ``defaults`` under them: per section, the take's keys win; ``{take}`` in
    the defaults' [output] values becomes ``take``."""
    merged = {}
    for section, body in (defaults or {}).items():
        merged[section] = {k: v.replace(TAKE_PLACEHOLDER, take) if section == "output" and isinstance(v, str) else
                           copy.deepcopy(v) for k, v in body.items()}
    for section, body in data.items():
        if isinstance(body, dict) and isinstance(merged.get(section), dict):
            merged[section] = {**merged[section], **body}
        else:
            merged[section] = body
    return merged


def _take(name, path, defaults, listed_by):
    try:
        _, data = read_config_toml(path)
    except FacecapError as exc:
        return BatchTake(name, path, None, str(exc), listed_by)
    if is_batch_data(data):
        return BatchTake(name, path, None, f"{path}: a batch file where a take config was expected", listed_by)
    return BatchTake(name, path, merge_defaults(defaults, data, path.stem), None, listed_by)


# -- what a take's result depends on (batch --resume) ---------------------------------------------------------


def config_digest(take, extra=()):
    """sha256 of a take's effective config (its tables with the defaults merged in) and ``extra``
    (e.g. the facecap version and the run's options)."""
    text = json.dumps({"config": str(take.path), "data": take.data, "extra": list(extra)}, sort_keys=True,
                      default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


class InputDigests:
    """sha256 of the files takes read, each file read once per batch (the character .blend many
    takes share). Folders and patterns (video frames) are digested by their files' names, sizes
    and modification times."""

    def __init__(self):
        self._done = {}

    def of_config(self, config):
        """{config key: digest} of every input of a parsed take config (``take_inputs``)."""
        inputs = sorted(take_inputs(config).items())
        return {key: self.of_path(path) for key, path in inputs if key != "the config itself"}

    def of_path(self, path):
        path = Path(os.path.expanduser(str(path)))
        try:
            st = path.stat()
        except OSError:
            st = None
        key = (str(path), None if st is None else (st.st_size, st.st_mtime_ns))
        if key not in self._done:
            self._done[key] = _digest(path, st)
        return self._done[key]


def _digest(path, st):
    h = hashlib.sha256()
    if st is not None and path.is_file():
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        return h.hexdigest()
    pattern = re.sub(r"%0?\d*d", "*", str(path))  # a printf frame pattern (video takes) as a glob
    files = sorted(path.iterdir()) if path.is_dir() else sorted(Path(p) for p in glob.glob(pattern))
    if not files:
        return "missing"
    for f in files:
        s = f.stat()
        h.update(f"{f.name}\0{s.st_size}\0{s.st_mtime_ns}\n".encode())
    return h.hexdigest()
