"""Project error classes: every bad input raises one of these with a message a user can act on."""

import difflib
import platform
import sys
import tomllib
from contextlib import contextmanager
from pathlib import Path

from .extension_builds import build_for_python


#: A message quoting what it found (a header, a value) is cut to this many characters in the middle:
#: one readable line, however long the file's line was.
MAX_MESSAGE = 600


def one_line(text, limit=MAX_MESSAGE):
    """``text`` on one line, at most ``limit`` characters (the middle elided)."""
    text = " ".join(str(text).split())
    if len(text) <= limit:
        return text
    keep = (limit - 5) // 2
    return f"{text[:keep]} ... {text[-keep:]}"


class FacecapError(Exception):
    """Base class for readable, expected errors (bad files, bad settings, impossible solves)."""


class Cancelled(FacecapError):
    """The user cancelled a long operation (a progress callback returned False): video, a download."""


class InputFileError(FacecapError):
    """A file could not be read. The message names the file and, where known, the line and field."""

    def __init__(self, path, message, *, line=None, field=None):
        self.path = str(path)
        self.line = line
        self.field = field
        where = self.path
        if line is not None:
            where += f", line {line}"
        if field is not None:
            where += f", field '{field}'"
        super().__init__(f"{where}: {one_line(message)}")


class ConfigError(FacecapError):
    """A take config or setting is missing or wrong. The message names the key."""

    def __init__(self, message, *, path=None, key=None):
        self.path = None if path is None else str(path)
        self.key = key
        where = ""
        if path is not None:
            where += f"{path}: "
        if key is not None:
            where += f"[{key}] "
        super().__init__(where + one_line(message))


class ConfigProblems(ConfigError):
    """Every problem found in one config, reported at once: one ``ConfigError`` line each (``errors``)."""

    def __init__(self, errors):
        self.errors = list(errors)
        first = self.errors[0]
        self.path, self.key = first.path, first.key
        FacecapError.__init__(self, "\n".join(str(e) for e in self.errors))


class Problems:
    """Collects the ConfigErrors of one config so that all are reported together.

    ``part(fn, *args, default=...)`` runs one parser and keeps its error; keys already reported (and
    everything below them) are ``reported`` and a later error about them is a consequence, not news.
    """

    def __init__(self):
        self.errors = []
        self.reported = set()

    def add(self, error, covers=None):
        """Keep ``error`` unless it is about a key already reported; ``covers``: the key whose later
        errors it explains (default: its own key)."""
        errors = error.errors if isinstance(error, ConfigProblems) else [error]
        for e in errors:
            if e.key is not None and self.covered(e.key):
                continue
            self.errors.append(e)
            for key in (e.key, covers):
                if key is not None:
                    self.reported.add(key)

    def covered(self, key):
        """Whether ``key`` (``section.key``) is, or is below, a key already reported."""
        return any(key == k or key.startswith(k + ".") for k in self.reported)

    def part(self, fn, *args, default=None, **kwargs):
        """``fn(*args, **kwargs)``, or ``default`` when it raises a ConfigError (kept)."""
        try:
            return fn(*args, **kwargs)
        except ConfigError as exc:
            self.add(exc)
            return default

    def raise_any(self):
        if len(self.errors) == 1:
            raise self.errors[0]
        if self.errors:
            raise ConfigProblems(self.errors)


def suggest(word, candidates):
    """`` (did you mean 'x'?)`` for the candidate closest to ``word``, or ''."""
    if not isinstance(word, str):
        return ""
    candidates = [str(c) for c in candidates]
    folded = {c.casefold(): c for c in candidates}
    close = difflib.get_close_matches(word, candidates, n=1, cutoff=0.6)
    match = folded.get(word.casefold()) or (close[0] if close else None)
    return f" (did you mean '{match}'?)" if match else ""


def table_problems(data, options, *, prefix="", open_sections=("controls",), required=True):
    """Every problem of TOML tables ``data`` against an option table ``options`` (``solvers.options.Option``
    rows: ``section``, ``key``, ``required``, ``check``), all at once:
    [(key, message, covers)] for unknown sections and keys (with a "did you mean"), values of the wrong
    kind or out of range, missing required keys (if ``required``). ``key``: ``section.key`` after
    ``prefix`` (``defaults.``), None for a section's own problems; ``covers``: the key whose later
    problems are consequences (a misspelt section covers the absent one it means). In ``open_sections``
    any key is a table (``[controls]``: a key per shape).
    """
    by_name = {o.name: o for o in options}
    sections = tuple(dict.fromkeys(o.section for o in options))
    problems = []
    for section, body in data.items():
        if section not in sections:
            hint = suggest(section, sections)
            meant = hint.split("'")[1] if hint else section
            problems.append((None, f"unknown section [{prefix}{section}]{hint}; known: {', '.join(sections)}",
                             prefix + (meant if meant not in data else section)))
            continue
        if not isinstance(body, dict):
            problems.append((None, f"[{prefix}{section}] must be a table; got {body!r}", prefix + section))
            continue
        keys = [o.key for o in options if o.section == section]
        for key, value in body.items():
            opt = by_name.get(f"{section}.{key}")
            if opt is None and section in open_sections:
                opt = by_name.get(f"{section}.<shape>")
            if opt is None:
                name = f"{prefix}{section}.{key}"
                problems.append((name, f"unknown key{suggest(key, keys)}; known keys: {', '.join(keys)}", name))
                continue
            problem = opt.check(value)
            if problem is not None and getattr(opt, "choices", ()) and value not in opt.choices:
                problem += suggest(value, opt.choices)
            if problem is not None:
                problems.append((f"{prefix}{section}.{key}", problem, f"{prefix}{section}.{key}"))
    for opt in options:
        body = data.get(opt.section)
        if required and opt.required and not (isinstance(body, dict) and opt.key in body):
            problems.append((prefix + opt.name, "missing required key", prefix + opt.name))
    return problems


#: Top-level module -> the PyPI package that provides it (bundled in the extension zips: wheels.lock.toml).
PACKAGES = {"scipy": "scipy", "cv2": "opencv-contrib-python-headless"}
_MANIFEST = Path(__file__).resolve().parents[1] / "blender_manifest.toml"


class MissingDependencyError(FacecapError):
    """A feature needs scipy or OpenCV and it cannot be imported; the message says what to install.

    Blender ships numpy but neither scipy nor OpenCV; the extension zip for each platform bundles them
    (docs/install.md). They are missing only in a source checkout linked into Blender, a zip without
    wheels or a damaged install. Inside Blender the advice is the zip built for this computer (an artist
    cannot pip-install into Blender's Python); elsewhere it is the pip package.
    """

    def __init__(self, module, feature, reason):
        self.module, self.feature = module, feature
        package = PACKAGES.get(module, module)
        what = package if package == module else f"{package} ({module})"
        if "bpy" in sys.modules:
            advice = (f"install the FaceCap build for this computer, {extension_zip_name()}, with Edit > "
                      "Preferences > Get Extensions > Install from Disk: it bundles scipy and OpenCV")
        else:
            advice = f"install it into this Python: pip install {package}"
        reason = one_line(reason, 200)
        super().__init__(f"{feature} needs {what}, which cannot be imported here ({reason}); {advice}")


@contextmanager
def needs(module, feature):
    """Turn an ImportError of the imports in the block into a ``MissingDependencyError``.

    Parameters
    ----------
    module : str
        The top-level module imported in the block (``"scipy"`` or ``"cv2"``).
    feature : str
        What needs it, as the user knows it (``"Clean Markers"``), starting with a capital.
    """
    try:
        yield
    except ImportError as exc:
        raise MissingDependencyError(module, feature, str(exc) or type(exc).__name__) from exc


def blender_platform():
    """This computer's platform in Blender's naming (``linux-x64``, ``windows-x64``, ``macos-arm64``, ...)."""
    system = {"darwin": "macos"}.get(platform.system().lower(), platform.system().lower())
    machine = platform.machine().lower()
    machine = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64"}.get(machine, machine)
    return f"{system}-{machine}"


def extension_zip_name(python=None):
    """The name of the extension zip built for this platform and this Python's Blenders, e.g.
    ``facecap-0.1.0-blender5.1-and-newer-linux_x64.zip`` (``python``: default this interpreter's)."""
    try:
        version = tomllib.loads(_MANIFEST.read_text(encoding="utf-8"))["version"]
    except (OSError, ValueError, KeyError):
        version = "<version>"  # the name without a version is still the right advice
    build = build_for_python(python or sys.version_info)
    platform_name = blender_platform()
    if build is None:  # no Blender runs this Python: name the pattern
        return f"facecap-{version}-<build for your Blender>-{platform_name.replace('-', '_')}.zip"
    return build.zip_name(version, platform_name)
