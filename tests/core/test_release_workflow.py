"""The release workflow (``.github/workflows/release.yml``) cannot run here, so its structure is checked: a version tag
starts it, its build step is the command a developer runs (and tests/e2e runs) with every build and platform, and
it publishes the zips with their checksums and the notes that say which zip is whose. What that command writes
beside the zips (``solvers/tools/release.py``) is checked here on stand-in zips."""

import re
import shlex
import tomllib
from pathlib import Path

import pytest
import yaml

from facecap.solvers.errors import FacecapError
from facecap.solvers.extension_builds import BUILDS
from facecap.solvers.tools import build_extension, release
from facecap.solvers.tools.build_extension import BuiltZip, sha256_of

REPO = Path(__file__).resolve().parents[2]
WORKFLOW = REPO / ".github" / "workflows" / "release.yml"
VERSION = tomllib.loads((REPO / "blender_manifest.toml").read_text(encoding="utf-8"))["version"]


def workflow():
    return yaml.safe_load(WORKFLOW.read_text(encoding="utf-8"))


def run_lines():
    (job,) = workflow()["jobs"].values()
    return [step["run"] for step in job["steps"] if "run" in step]


def build_command():
    """The workflow's one ``python -m facecap build-extension`` line, as argv after ``python -m facecap``."""
    (line,) = [r for r in run_lines() if "facecap build-extension" in r]
    argv = shlex.split(line)
    assert argv[:3] == ["python", "-m", "facecap"], line
    return argv[3:]


def test_a_version_tag_and_nothing_else_starts_a_release():
    flow = workflow()
    triggers = flow[True] if True in flow else flow["on"]  # YAML 1.1 reads the key `on` as True
    assert list(triggers) == ["push"] and triggers["push"] == {"tags": ["v*"]}
    assert flow["permissions"] == {"contents": "write"}


def test_the_build_step_is_the_documented_command_for_every_build_and_platform():
    argv = build_command()
    assert argv[0] == "build-extension"
    assert "--build" not in argv and "--platform" not in argv  # every generation x platform
    assert argv[argv.index("--release") + 1] == "$GITHUB_REF_NAME" and argv[argv.index("--out") + 1] == "dist"
    parser_argv = [a.replace("$GITHUB_REF_NAME", f"v{VERSION}") for a in argv[1:]]
    with pytest.raises(SystemExit) as stop:  # the command exists and takes these options: --help parses them
        build_extension.main(parser_argv + ["--help"])
    assert stop.value.code == 0
    install = (REPO / "docs" / "install.md").read_text(encoding="utf-8")
    assert "python -m facecap build-extension" in install


def test_the_environment_is_the_development_one_on_a_python_with_a_bpy_wheel():
    (job,) = workflow()["jobs"].values()
    setup = next(s for s in job["steps"] if s.get("uses", "").startswith("actions/setup-python"))
    assert setup["with"]["python-version"] in {b.python for b in BUILDS}
    assert 'python -m pip install -e ".[blender]"' in run_lines()


def test_the_release_publishes_every_zip_the_checksums_and_the_notes():
    (publish,) = [r for r in run_lines() if r.startswith("gh release create")]
    argv = shlex.split(publish)
    assert argv[3] == "$GITHUB_REF_NAME"
    assert {"dist/*.zip", f"dist/{release.CHECKSUMS}"} <= set(argv)
    assert argv[argv.index("--notes-file") + 1] == f"dist/{release.NOTES}"


def _built(tmp_path):
    zips = []
    for b in BUILDS:
        for p in b.platforms:
            path = tmp_path / b.zip_name(VERSION, p)
            path.write_bytes(f"{b.name} {p}".encode() * 1000)
            zips.append(BuiltZip(b.name, p, path, path.stat().st_size, ()))
    return zips


def test_the_release_files_say_which_zip_is_whose_and_check_each(tmp_path):
    built = _built(tmp_path)
    manifest = {"version": VERSION, "website": "https://github.com/facecap/facecap"}
    sums, notes = release.write_release(built, tmp_path, manifest, sha256_of)
    lines = sums.read_text().splitlines()
    assert len(lines) == len(built)
    for z in built:
        assert f"{sha256_of(z.path)}  {z.path.name}" in lines
    text = notes.read_text()
    mac_intel = next(line for line in text.splitlines() if line.startswith("| Mac with an Intel processor |"))
    assert f"facecap-{VERSION}-blender4.2-5.0-macos_x64.zip" in mac_intel and "none: that Blender has no build" in mac_intel
    for z in built:
        row = next(line for line in text.splitlines() if line.startswith(f"| {release.COMPUTERS[z.platform]} |"))
        assert f"`{z.path.name}` ({z.size / 1e6:.1f} MB)" in row
    assert "Install from Disk" in text and f"/blob/v{VERSION}/docs/install.md" in text


def test_a_tag_that_is_not_the_manifest_version_stops_before_any_download():
    release.check_tag(f"v{VERSION}", VERSION)
    with pytest.raises(FacecapError, match=r"release tag 'v9\.9\.9' does not match blender_manifest.toml's version"):
        build_extension.main(["--release", "v9.9.9", "--cache", "/nonexistent/never-used"])


def test_install_md_table_names_every_zip_in_its_cell(tmp_path):
    """docs/install.md's zip table is the one build-extension --docs writes (sizes aside, checked against real
    zips in tests/e2e/test_extension_install.py): every zip, in its computer's row and its Blender's column."""
    text = (REPO / "docs" / "install.md").read_text(encoding="utf-8")
    block = text.split(release.BEGIN, 1)[1].split(release.END, 1)[0].strip()
    expected = release.zip_table(_built(tmp_path)).strip()
    sizes = re.compile(r"\(\d+\.\d MB\)")
    assert sizes.sub("(size)", block) == sizes.sub("(size)", expected)


def test_the_readme_and_install_md_link_the_release_page():
    website = tomllib.loads((REPO / "blender_manifest.toml").read_text(encoding="utf-8"))["website"]
    page = f"{website}/releases/latest"
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    artist = next(line for line in readme.splitlines() if line.startswith("**Artist"))
    assert page in artist
    assert page in (REPO / "docs" / "install.md").read_text(encoding="utf-8")


def test_install_md_download_and_wheel_sizes_are_the_lock_s():
    """The sizes docs/install.md gives for what a build downloads and for each bundled wheel come from
    wheels.lock.toml (issue 40: the MediaPipe wheel the build downloads was unmentioned)."""
    from facecap.solvers.tools.build_extension import read_assets, read_lock

    text = (REPO / "docs" / "install.md").read_text(encoding="utf-8")
    wheels, _ = read_lock()
    assets = {a.name: a.size for a in read_assets()}
    total = sum(w.size for w in wheels) + sum(assets.values())
    assert (f"A first build downloads {total / 1e6:.0f} MB ({sum(w.size for w in wheels) / 1e6:.0f} MB of SciPy and "
            "OpenCV wheels") in " ".join(text.split())
    assert f"plotly's, {assets['plotly'] / 1e6:.1f} MB" in text and f"{assets['mediapipe'] / 1e6:.1f} MB" in text
    columns = ("windows-x64", "linux-x64", "macos-arm64", "macos-x64")
    for w in wheels:
        label = {"scipy": "SciPy", "opencv-contrib-python-headless": "OpenCV"}[w.name]
        row = next(line for line in text.splitlines() if line.startswith(f"| {label} {w.version} wheel |"))
        cells = [c.strip() for c in row.strip("|").split("|")][1:]
        assert cells[columns.index(w.platform)] == f"{w.size / 1e6:.1f} MB", (w.file, row)
