"""``python -m facecap build-extension``: the Blender extension zips, one per platform, with the wheels bundled.

Blender ships numpy but neither scipy nor OpenCV, and an artist cannot ``pip install`` into it. So the
extension carries unmodified PyPI wheels for them (``wheels.lock.toml``: file names and sha256 per
platform), as Blender's extension platform expects. The build

1. fetches every locked wheel into a cache (``$FACECAP_CACHE/wheels``, default ``~/.cache/facecap``),
   downloading missing ones with ``pip download`` (pip's HTTP cache makes a repeat fast) and checking
   each file's sha256 against the lock;
2. stages the add-on source with the wheels in ``./wheels`` and a generated ``blender_manifest.toml``
   (the repository's manifest plus ``platforms = [...]`` and ``wheels = [...]``: never hand-edited);
3. runs Blender's own extension tool (``blender_ext.py``, shipped inside the ``bpy`` wheel) as a
   subprocess to ``build --split-platforms`` and ``validate`` one zip per platform.

No Blender module is imported here: the tool is found on disk under the installed ``bpy`` package.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from dataclasses import dataclass
from pathlib import Path

from ..errors import FacecapError

REPO = Path(__file__).resolve().parents[2]
LOCK_FILE = REPO / "wheels.lock.toml"
MANIFEST = "blender_manifest.toml"
PLATFORMS = ("windows-x64", "linux-x64", "macos-arm64", "macos-x64")
BLENDER_PYTHON = "3.11"      # every supported Blender (4.2-5.0) runs CPython 3.11
SIZE_TARGET_MB = 110.0       # one platform's zip; above this the build warns
TOOL_TIMEOUT = 900           # seconds for one pip download or extension-tool run


class BuildError(FacecapError):
    """The extension could not be built (a wheel, the lock, the manifest or Blender's tool)."""


@dataclass(frozen=True)
class LockedWheel:
    """One wheel of ``wheels.lock.toml``: which package, for which Blender platform, and its hash."""

    name: str
    version: str
    platform: str
    file: str
    sha256: str
    size: int


@dataclass(frozen=True)
class BuiltZip:
    """One built and validated extension zip."""

    platform: str
    path: Path
    size: int
    wheels: tuple[str, ...]


def default_cache_dir():
    """``$FACECAP_CACHE``, else ``$XDG_CACHE_HOME/facecap``, else ``~/.cache/facecap``."""
    if os.environ.get("FACECAP_CACHE"):
        return Path(os.environ["FACECAP_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "facecap"


def read_lock(path=LOCK_FILE):
    """The locked wheels and the import names each package provides.

    Returns
    -------
    wheels : list of LockedWheel
    imports : dict of str -> str
        Top-level module name -> the package that provides it (``{"cv2": "opencv-contrib-python-headless"}``).
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise BuildError(f"{path}: the wheel lock file is missing (build from a source checkout)") from None
    except tomllib.TOMLDecodeError as exc:
        raise BuildError(f"{path}: not valid TOML ({exc})") from None
    wheels, imports = [], {}
    for p, package in enumerate(data.get("package", [])):
        try:
            name, version = package["name"], package["version"]
            imports.update({module: name for module in package["imports"]})
            for w in package["wheel"]:
                wheels.append(LockedWheel(name, version, w["platform"], w["file"], w["sha256"].lower(), int(w["size"])))
        except KeyError as exc:
            raise BuildError(f"{path}: package {p + 1} has no `{exc.args[0]}`") from None
    for w in wheels:
        if w.platform not in PLATFORMS:
            raise BuildError(f"{path}: {w.file} has platform '{w.platform}'; expected one of {', '.join(PLATFORMS)}")
        if f"-{w.version}-" not in w.file or not w.file.endswith(".whl"):
            raise BuildError(f"{path}: '{w.file}' is not a {w.name} {w.version} wheel")
    return wheels, imports


@dataclass(frozen=True)
class LockedAsset:
    """One file taken from a locked universal wheel and bundled at ``target`` in the add-on."""

    name: str
    version: str
    file: str
    sha256: str
    size: int
    member: str
    target: str


def read_assets(path=LOCK_FILE):
    """The locked assets (``[[asset]]`` tables) of ``wheels.lock.toml``."""
    path = Path(path)
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    assets = []
    for i, a in enumerate(data.get("asset", [])):
        try:
            assets.append(LockedAsset(a["name"], a["version"], a["file"], a["sha256"].lower(), int(a["size"]),
                                      a["member"], a["target"]))
        except KeyError as exc:
            raise BuildError(f"{path}: asset {i + 1} has no `{exc.args[0]}`") from None
    return assets


def fetch_assets(assets, cache_dir=None, *, log=print):
    """{asset: bytes of its member} from the locked wheels (downloaded once, hash checked)."""
    store = Path(cache_dir or default_cache_dir())
    store.mkdir(parents=True, exist_ok=True)
    out = {}
    for a in assets:
        path = _cached(LockedWheel(a.name, a.version, "any", a.file, a.sha256, a.size), store, log)
        with zipfile.ZipFile(path) as z:
            try:
                out[a] = z.read(a.member)
            except KeyError:
                raise BuildError(f"{a.file} has no {a.member}") from None
    return out


def sha256_of(path):
    """Hex sha256 of a file, read in 1 MB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def fetch_wheels(wheels, cache_dir=None, *, log=print):
    """Every locked wheel as a verified file in ``<cache>/wheels``; downloads only the missing ones.

    Returns
    -------
    dict of str -> Path
        Wheel file name -> its cached path.
    """
    store = Path(cache_dir or default_cache_dir()) / "wheels"
    store.mkdir(parents=True, exist_ok=True)
    paths = {}
    for w in wheels:
        paths[w.file] = _cached(w, store, log)
    return paths


def _cached(wheel, store, log):
    """The LockedWheel's file in ``store``: downloaded unless it is there with its locked hash."""
    path = store / wheel.file
    if not (path.is_file() and sha256_of(path) == wheel.sha256):
        log(f"downloading {wheel.file} ({wheel.size / 1e6:.1f} MB)")
        _download(wheel, store)
    return path


def _download(wheel, store):
    """``pip download`` one locked wheel for its platform into ``store``, atomically, hash checked."""
    _name, _version, _python, abi, platform_tags = wheel.file[:-4].split("-")
    with tempfile.TemporaryDirectory(dir=store, prefix=".download-") as tmp:
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:",
               "--python-version", BLENDER_PYTHON, "--dest", tmp, f"{wheel.name}=={wheel.version}"]
        if platform_tags != "any":  # a universal wheel needs no platform or ABI
            cmd[-3:-3] = ["--platform", platform_tags.split(".")[0], "--implementation", "cp", "--abi", abi]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=TOOL_TIMEOUT)
        got = Path(tmp) / wheel.file
        if proc.returncode != 0 or not got.is_file():
            found = ", ".join(p.name for p in Path(tmp).iterdir()) or "nothing"
            detail = proc.stderr.strip().splitlines()[-1:] or [f"got {found}"]
            raise BuildError(f"could not download {wheel.file} with pip: {detail[0]}")
        digest = sha256_of(got)
        if digest != wheel.sha256:
            raise BuildError(f"{wheel.file}: sha256 {digest} does not match the lock ({wheel.sha256})")
        os.replace(got, store / wheel.file)


def find_extension_tool():
    """Blender's extension CLI (``blender_ext.py``) inside the installed ``bpy`` wheel, without importing bpy."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or spec.origin is None:
        raise BuildError("Blender's extension tool comes with the bpy wheel, which is not installed here "
                         "(pip install -e \".[blender]\")")
    found = sorted(Path(spec.origin).parent.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        raise BuildError(f"no scripts/addons_core/bl_pkg/cli/blender_ext.py under {Path(spec.origin).parent}")
    return found[-1]


def generated_manifest(text, wheel_paths, platforms):
    """The repository's manifest with ``platforms`` and ``wheels`` added as top-level keys.

    Parameters
    ----------
    text : str
        ``blender_manifest.toml`` as written in the repository (must not list wheels or platforms).
    wheel_paths : sequence of str
        Paths relative to the extension root (``./wheels/<file>``).
    platforms : sequence of str
        Blender platform names (``linux-x64``, ...).
    """
    data = tomllib.loads(text)
    for key in ("wheels", "platforms"):
        if key in data:
            raise BuildError(f"{MANIFEST}: `{key}` is generated by build-extension from {LOCK_FILE.name}; "
                             "remove it from the repository's manifest")
    lines = [
        "# Generated by `python -m facecap build-extension` from wheels.lock.toml.",
        "platforms = [" + ", ".join(f'"{p}"' for p in platforms) + "]",
        "wheels = [",
        *(f'  "{w}",' for w in wheel_paths),
        "]",
        "",
    ]
    first_table = re.search(r"^\[", text, flags=re.MULTILINE)
    at = first_table.start() if first_table else len(text)
    out = text[:at] + "\n".join(lines) + "\n" + text[at:]
    check = tomllib.loads(out)
    if check["wheels"] != list(wheel_paths) or check["platforms"] != list(platforms):
        raise BuildError(f"{MANIFEST}: the generated wheel and platform lists did not read back")
    return out


def _top_level_excludes(manifest):
    """Root entries the manifest excludes outright (``/tests/``, ``/README.md``): not worth staging."""
    patterns = manifest.get("build", {}).get("paths_exclude_pattern", [])
    return {p.strip("/") for p in patterns if p.startswith("/") and "*" not in p and p.strip("/").count("/") == 0}


def _ignore(out_dir):
    """copytree's ignore: caches, backups, and the output folder (earlier zips must not ship in new ones)."""
    base = shutil.ignore_patterns("__pycache__", "*.pyc", "*.blend1")

    def ignore(directory, names):
        return set(base(directory, names)) | {n for n in names if (Path(directory) / n).resolve() == out_dir}

    return ignore


def stage_source(stage, wheel_files, platforms, *, source=REPO, out_dir=None, assets=None):
    """Copy the add-on source into ``stage`` with the wheels in ``./wheels``, the ``assets``
    ({LockedAsset: bytes}) at their targets and the generated manifest."""
    text = (Path(source) / MANIFEST).read_text(encoding="utf-8")
    skip = _top_level_excludes(tomllib.loads(text)) | {"wheels", MANIFEST}
    out_dir = None if out_dir is None else Path(out_dir).resolve()
    ignore = _ignore(out_dir)
    for entry in sorted(Path(source).iterdir()):
        if (entry.name.startswith(".") or entry.name in skip or entry.name.endswith(".egg-info")
                or entry.resolve() == out_dir):
            continue
        if entry.is_dir():
            shutil.copytree(entry, stage / entry.name, ignore=ignore)
        else:
            shutil.copy2(entry, stage / entry.name)
    (stage / "wheels").mkdir()
    for path in wheel_files:
        shutil.copy2(path, stage / "wheels" / Path(path).name)
    for asset, data in (assets or {}).items():
        target = stage / asset.target
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
    rel = [f"./wheels/{Path(p).name}" for p in wheel_files]
    (stage / MANIFEST).write_text(generated_manifest(text, rel, platforms), encoding="utf-8")
    return tomllib.loads(text)


def _run_tool(tool, *args, cwd=None):
    proc = subprocess.run([sys.executable, str(tool), *map(str, args)], capture_output=True, text=True,
                          timeout=TOOL_TIMEOUT, cwd=cwd)
    if proc.returncode != 0:
        raise BuildError(f"Blender's extension tool failed ({args[0]}): "
                         + (proc.stdout + proc.stderr).strip().replace("\n", " | "))
    return proc.stdout


def build(out_dir, *, platforms=PLATFORMS, cache_dir=None, tool=None, lock=LOCK_FILE, source=REPO, log=print):
    """Build and validate one extension zip per platform in ``out_dir``.

    Parameters
    ----------
    out_dir : path-like
        Where the zips go (created if missing); same-named zips are replaced.
    platforms : sequence of str
        A subset of ``PLATFORMS``; each gets its own zip with only its wheels.
    cache_dir, tool, lock, source
        Wheel cache (default ``default_cache_dir()``), ``blender_ext.py`` (default: from the bpy wheel),
        the lock file and the extension source root.

    Returns
    -------
    list of BuiltZip
        In the order of ``platforms``.
    """
    platforms = tuple(dict.fromkeys(platforms))
    unknown = [p for p in platforms if p not in PLATFORMS]
    if unknown or not platforms:
        raise BuildError(f"unknown platform(s) {unknown}; choose from {', '.join(PLATFORMS)}")
    wheels, _ = read_lock(lock)
    chosen = [w for w in wheels if w.platform in platforms]
    for p in platforms:
        missing = {w.name for w in wheels} - {w.name for w in chosen if w.platform == p}
        if missing:
            raise BuildError(f"{Path(lock).name}: no {p} wheel for {', '.join(sorted(missing))}")
    tool = Path(tool) if tool else find_extension_tool()
    paths = fetch_wheels(chosen, cache_dir, log=log)
    assets = fetch_assets(read_assets(lock), cache_dir, log=log)
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="facecap-extension-") as tmp:
        stage = Path(tmp) / "facecap"
        stage.mkdir()
        manifest = stage_source(stage, [paths[w.file] for w in chosen], platforms, source=source, out_dir=out_dir,
                                assets=assets)
        _run_tool(tool, "build", "--source-dir", stage, "--output-dir", out_dir, "--split-platforms", cwd=tmp)
    built = []
    for p in platforms:
        path = out_dir / f"{manifest['id']}-{manifest['version']}-{p.replace('-', '_')}.zip"
        if not path.is_file():
            raise BuildError(f"Blender's extension tool did not write {path}")
        _run_tool(tool, "validate", path)
        built.append(BuiltZip(p, path, path.stat().st_size, tuple(w.file for w in chosen if w.platform == p)))
    return built


def main(argv=None, *, parents=()):
    """Entry point for ``facecap build-extension``; returns the exit code."""
    parser = argparse.ArgumentParser(
        prog="facecap build-extension", parents=list(parents),
        description="Build and validate the Blender extension zips (one per platform, scipy and OpenCV bundled).")
    parser.add_argument("--out", default="dist", help="output folder (default: ./dist)")
    parser.add_argument("--platform", action="append", choices=PLATFORMS,
                        help="build only this platform (repeatable; default: all four)")
    parser.add_argument("--cache", help="wheel cache folder (default: $FACECAP_CACHE or ~/.cache/facecap)")
    args = parser.parse_args(argv)
    built = build(args.out, platforms=args.platform or PLATFORMS, cache_dir=args.cache,
                  log=lambda line: print(line, flush=True))
    for z in built:
        mb = z.size / 1e6
        over = f"  (over the {SIZE_TARGET_MB:.0f} MB target)" if mb > SIZE_TARGET_MB else ""
        print(f"{z.platform}: {z.path} ({mb:.1f} MB, validated){over}")
    return 0
