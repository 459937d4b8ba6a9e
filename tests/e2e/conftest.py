"""Shared fixtures for the end-to-end tests: the built extension zips and the cached Blender venvs.

A prerequisite that cannot be made (no network on a cold cache) skips the tests that need it, with the
reason, on a developer's machine; in CI (``FACECAP_CI=1``, set by ``.ci/run``) it fails them.
"""

import signal
import subprocess
import sys
from pathlib import Path

import pytest
from matrix_env import missing_prerequisite

from facecap.solvers.tools.build_extension import default_cache_dir

# A suite started in the background (an asynchronous list of a non-interactive shell: `cmd &` in a script)
# inherits SIGINT ignored, and so would every command these tests start and then interrupt as Ctrl-C does (they
# would finish instead): the commands get the default back (a handled signal is reset to it across exec).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session")
def cache_dir():
    return default_cache_dir()


@pytest.fixture(scope="session")
def extension_zips(tmp_path_factory):
    """The release workflow's build command (``.github/workflows/release.yml``) run once as written there, with
    the manifest's version as the tag and a temporary folder as ``dist``: {(build, platform): zip path} for
    every build, and what it printed."""
    import shlex
    import tomllib

    import yaml

    root = Path(__file__).resolve().parents[2]
    version = tomllib.loads((root / "blender_manifest.toml").read_text(encoding="utf-8"))["version"]
    (job,) = yaml.safe_load((root / ".github" / "workflows" / "release.yml").read_text(encoding="utf-8"))["jobs"].values()
    (line,) = [s["run"] for s in job["steps"] if "facecap build-extension" in s.get("run", "")]
    out = tmp_path_factory.mktemp("release")
    argv = [a.replace("$GITHUB_REF_NAME", f"v{version}") for a in shlex.split(line)]
    assert argv[0] == "python"
    proc = subprocess.run([sys.executable, *argv[1:]], capture_output=True, text=True, timeout=1800, cwd=out)
    if proc.returncode != 0 and "could not download" in proc.stderr:
        missing_prerequisite(proc.stderr.strip().splitlines()[-1])
    assert proc.returncode == 0, f"build-extension failed:\n{proc.stdout}\n{proc.stderr}"
    zips = {}
    for line in proc.stdout.splitlines():
        which, _, rest = line.partition(": ")
        if ", validated)" in rest:
            build, platform = which.split(" ")
            zips[(build, platform)] = Path(rest.split(" (")[0])
    return {"zips": zips, "stdout": proc.stdout, "dist": out / "dist"}
