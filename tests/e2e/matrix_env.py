"""Cached Blender environments for the install matrix: one venv per supported Blender release.

Each venv holds only that release's ``bpy`` wheel (with the packages the wheel itself requires) and the
numpy that Blender release ships, on the Python that release runs, so scipy and OpenCV can come only
from the extension zip. Venvs live in ``<cache>/venvs`` (``$FACECAP_CACHE``, default
``~/.cache/facecap``) and are reused across runs; a venv is built under a temporary name and renamed
when complete, under a file lock, so an interrupted or concurrent run never leaves a half-built one in
use. The Python of each release is found on ``PATH`` (``python3.13``) or in pyenv's versions folder.
"""

import contextlib
import glob
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

#: (bpy wheel, the numpy that Blender release bundles): the LTS releases, the last release of each
#: Python generation and the newest, latest patches.
MATRIX = (
    ("4.2.23", "1.24.3"),  # 4.2 LTS; 4.2/4.3 bundle numpy 1.24.3 (Python 3.11)
    ("4.5.15", "1.26.4"),  # 4.5 LTS; 4.4-5.0 bundle numpy 1.26.4
    ("5.0.1", "1.26.4"),   # the last release on Python 3.11
    ("5.2.3", "2.3.4"),    # 5.2 LTS; 5.1 and later bundle numpy 2.3 (Python 3.13)
    ("5.3.0", "2.3.4"),    # the newest release
)
#: The release whose default solve the others are compared with (the figure the docs quote).
REFERENCE = "5.0.1"
READY = "facecap-ready.json"
PIP_TIMEOUT = 1800
CI = os.environ.get("FACECAP_CI") == "1"


class PrerequisiteError(RuntimeError):
    """A matrix environment could not be made (typically no network on a cold cache)."""


def missing_prerequisite(reason):
    """Fail in CI (``FACECAP_CI=1``, set by ``.ci/run``), skip with the reason elsewhere."""
    import pytest

    if CI:
        pytest.fail(f"CI prerequisite missing: {reason}", pytrace=False)
    pytest.skip(reason)


def venv_python(root):
    return Path(root) / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


@contextlib.contextmanager
def file_lock(path):
    """An exclusive lock on ``path`` (POSIX; elsewhere no lock)."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _version_of(python):
    """``"3.13"`` for an interpreter that runs, else None (a pyenv shim of a version not selected fails)."""
    try:
        proc = subprocess.run([python, "-c", "import sys; print('%d.%d' % sys.version_info[:2])"],
                              capture_output=True, text=True, timeout=60)
    except OSError:
        return None
    return proc.stdout.strip() if proc.returncode == 0 else None


def find_python(version):
    """An interpreter of Python ``version`` (``"3.11"``): this one, ``python3.11`` on PATH, or pyenv's.

    Raises
    ------
    PrerequisiteError
        When there is none on this machine.
    """
    if "%d.%d" % sys.version_info[:2] == version:
        return sys.executable
    pyenv = os.environ.get("PYENV_ROOT") or os.path.expanduser("~/.pyenv")
    candidates = [shutil.which(f"python{version}")]
    candidates += sorted(glob.glob(os.path.join(pyenv, "versions", f"{version}.*", "bin", f"python{version}")))
    for python in filter(None, candidates):
        if _version_of(python) == version:
            return python
    raise PrerequisiteError(f"no Python {version} here (python{version} on PATH or in pyenv), which that "
                            "Blender release runs")


def blender_venv(cache, bpy_version, numpy_version, python_version, log=print):
    """The Python of the cached venv for ``bpy_version`` on Python ``python_version``, built on first use.

    Raises
    ------
    PrerequisiteError
        When pip cannot install the wheels (no network and nothing cached) or no such Python is here.
    """
    name = f"bpy-{bpy_version}-numpy-{numpy_version}"
    root = Path(cache) / "venvs" / name
    if (root / READY).is_file():
        return venv_python(root)
    with file_lock(root.with_name(f".{name}.lock")):
        if (root / READY).is_file():
            return venv_python(root)
        partial = root.with_name(f"{name}.partial")
        shutil.rmtree(partial, ignore_errors=True)
        shutil.rmtree(root, ignore_errors=True)
        base = find_python(python_version)
        log(f"building the Blender {bpy_version} venv in {root} (once; cached)")
        subprocess.run([base, "-m", "venv", str(partial)], check=True, capture_output=True)
        python = venv_python(partial)
        proc = subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                               f"bpy=={bpy_version}", f"numpy=={numpy_version}"],
                              capture_output=True, text=True, timeout=PIP_TIMEOUT)
        if proc.returncode != 0:
            last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
            shutil.rmtree(partial, ignore_errors=True)
            raise PrerequisiteError(f"pip could not install bpy=={bpy_version} numpy=={numpy_version}: {last}")
        probe = ("import importlib.util as u, json, numpy; print(json.dumps({'numpy': numpy.__version__, "
                 "'scipy': u.find_spec('scipy') is not None, 'cv2': u.find_spec('cv2') is not None}))")
        found = json.loads(subprocess.run([str(python), "-c", probe], check=True, capture_output=True,
                                          text=True).stdout.strip().splitlines()[-1])
        if found != {"numpy": numpy_version, "scipy": False, "cv2": False}:
            raise RuntimeError(f"the Blender {bpy_version} venv is not clean: {found}")
        (partial / READY).write_text(json.dumps({"bpy": bpy_version, **found}), encoding="utf-8")
        partial.rename(root)  # run as <root>/bin/python, the venv works from its new path
    return venv_python(root)


def blender_env(user_root):
    """This process's environment with every Blender user folder inside ``user_root``.

    The add-on must come from the installed zip, so ``PYTHONPATH`` and any ``BLENDER_*`` settings of
    the developer are dropped.
    """
    env = {k: v for k, v in os.environ.items() if not k.startswith("BLENDER_") and k != "PYTHONPATH"}
    env["BLENDER_USER_RESOURCES"] = str(user_root)
    for kind in ("CONFIG", "SCRIPTS", "EXTENSIONS", "DATAFILES"):
        env[f"BLENDER_USER_{kind}"] = str(Path(user_root) / kind.lower())
    return env
