"""``python -m facecap build-extension``: the Blender extension zips, one per Blender generation and platform,
with the wheels bundled.

Blender ships numpy but neither scipy nor OpenCV, and an artist cannot ``pip install`` into it. So the
extension carries unmodified PyPI wheels for them (``wheels.lock.toml``: file names and sha256 per
platform and Python), as Blender's extension platform expects. Blender 4.2-5.0 run Python 3.11 and
5.1 and later Python 3.13, so there is one build per Python (``solvers/extension_builds.py``: the
Blender versions each accepts, written into its manifest). The build

1. fetches every locked wheel into a cache (``$FACECAP_CACHE/wheels``, default ``~/.cache/facecap``),
   downloading missing ones with ``pip download`` (pip's HTTP cache makes a repeat fast) and checking
   each file's sha256 against the lock;
2. stages the add-on's files (an explicit list, ``extension_files.py``: nothing else in the checkout), per
   build, with that build's wheels in ``./wheels`` and a generated
   ``blender_manifest.toml`` (the repository's manifest plus the build's ``blender_version_min``/``max``,
   ``platforms = [...]`` and ``wheels = [...]``: never hand-edited);
3. runs Blender's own extension tool (``blender_ext.py``, shipped inside the ``bpy`` wheel) as a
   subprocess to ``build --split-platforms`` and ``validate`` one zip per platform, named after the build
   (``facecap-0.1.0-blender5.1-and-newer-linux_x64.zip``).

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
from ..extension_builds import BUILDS, PLATFORMS, build_for_python, build_named
from ..io.outputs import Output, check_files_in, check_outputs, mark_output
from . import release
from .extension_files import copy_addon

REPO = Path(__file__).resolve().parents[2]
LOCK_FILE = REPO / "wheels.lock.toml"
MANIFEST = "blender_manifest.toml"
SIZE_TARGET_MB = 120.0       # one zip; above this the build warns
TOOL_TIMEOUT = 900           # seconds for one pip download or extension-tool run


class BuildError(FacecapError):
    """The extension could not be built (a wheel, the lock, the manifest or Blender's tool)."""


@dataclass(frozen=True)
class LockedWheel:
    """One wheel of ``wheels.lock.toml``: which package, for which Python and Blender platform, and its hash."""

    name: str
    version: str
    python: str
    platform: str
    file: str
    sha256: str
    size: int


@dataclass(frozen=True)
class BuiltZip:
    """One built and validated extension zip."""

    build: str
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
            name, version, python = package["name"], package["version"], package["python"]
            imports.update({module: name for module in package["imports"]})
            for w in package["wheel"]:
                wheels.append(LockedWheel(name, version, python, w["platform"], w["file"], w["sha256"].lower(),
                                          int(w["size"])))
        except KeyError as exc:
            raise BuildError(f"{path}: package {p + 1} has no `{exc.args[0]}`") from None
    for w in wheels:
        build = build_for_python(w.python)
        if build is None:
            raise BuildError(f"{path}: {w.name} {w.version} is for Python {w.python}, which no extension build "
                             f"uses ({', '.join(b.python for b in BUILDS)})")
        if w.platform not in build.platforms:
            raise BuildError(f"{path}: {w.file} has platform '{w.platform}'; the {build.name} build is for "
                             f"{', '.join(build.platforms)}")
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
        # a universal wheel: pip finds it for any build's Python
        path = _cached(LockedWheel(a.name, a.version, BUILDS[0].python, "any", a.file, a.sha256, a.size), store, log)
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
               "--python-version", wheel.python, "--dest", tmp, f"{wheel.name}=={wheel.version}"]
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


def generated_manifest(text, wheel_paths, platforms, ext_build=BUILDS[0]):
    """The repository's manifest for one build: its Blender range, ``platforms`` and ``wheels`` added.

    Parameters
    ----------
    text : str
        ``blender_manifest.toml`` as written in the repository (its ``blender_version_min`` is the oldest
        build's; it must not set ``blender_version_max`` nor list wheels or platforms).
    wheel_paths : sequence of str
        Paths relative to the extension root (``./wheels/<file>``).
    platforms : sequence of str
        Blender platform names (``linux-x64``, ...).
    ext_build : ExtensionBuild
        Whose ``blender_version_min`` and (unless its range is open) ``blender_version_max`` are written.
    """
    data = tomllib.loads(text)
    for key in ("wheels", "platforms", "blender_version_max"):
        if key in data:
            raise BuildError(f"{MANIFEST}: `{key}` is generated by build-extension (from {LOCK_FILE.name} and "
                             "solvers/extension_builds.py); remove it from the repository's manifest")
    if data.get("blender_version_min") != BUILDS[0].blender_min:
        raise BuildError(f"{MANIFEST}: blender_version_min must be the oldest build's, "
                         f"\"{BUILDS[0].blender_min}\"; got {data.get('blender_version_min')!r}")
    versions = [f'blender_version_min = "{ext_build.blender_min}"']
    if ext_build.blender_max is not None:
        versions.append(f'blender_version_max = "{ext_build.blender_max}"  # exclusive')
    text = re.sub(r'^blender_version_min\s*=.*$', lambda _: "\n".join(versions), text, count=1, flags=re.MULTILINE)
    lines = [
        f"# Generated by `python -m facecap build-extension` from wheels.lock.toml ({ext_build.blenders}).",
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
    range_back = (check["blender_version_min"], check.get("blender_version_max"))
    if (check["wheels"] != list(wheel_paths) or check["platforms"] != list(platforms)
            or range_back != (ext_build.blender_min, ext_build.blender_max)):
        raise BuildError(f"{MANIFEST}: the generated Blender range, wheel and platform lists did not read back")
    return out


def stage_source(stage, wheel_files, platforms, *, ext_build=BUILDS[0], source=REPO, assets=None):
    """Copy the add-on's files (``extension_files.addon_files``: an explicit list, so nothing else in the
    checkout ships: not a take, not ``out/``, not earlier zips) into ``stage`` with the wheels in ``./wheels``,
    the ``assets`` ({LockedAsset: bytes}) at their targets and the manifest generated for ``ext_build``."""
    text = (Path(source) / MANIFEST).read_text(encoding="utf-8")
    try:
        copy_addon(source, stage)
    except FileNotFoundError as exc:
        raise BuildError(f"{exc.args[0]}; build from a whole source checkout") from None
    (stage / "wheels").mkdir()
    for path in wheel_files:
        shutil.copy2(path, stage / "wheels" / Path(path).name)
    for asset, data in (assets or {}).items():
        target = stage / asset.target
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
    rel = [f"./wheels/{Path(p).name}" for p in wheel_files]
    (stage / MANIFEST).write_text(generated_manifest(text, rel, platforms, ext_build), encoding="utf-8")
    return tomllib.loads(text)


def _valid_tags(tool):
    """``--valid-tags <Blender's tag list>``: run outside Blender, the tool checks no tags unless told where
    Blender keeps the list extensions.blender.org accepts (beside the tool in the bpy wheel)."""
    tags = Path(tool).resolve().parents[3] / "modules" / "_bpy_internal" / "extensions" / "tags.py"
    return ["--valid-tags", tags] if tags.is_file() else []


def _run_tool(tool, *args, cwd=None):
    proc = subprocess.run([sys.executable, str(tool), *map(str, args)], capture_output=True, text=True,
                          timeout=TOOL_TIMEOUT, cwd=cwd)
    if proc.returncode != 0:
        raise BuildError(f"Blender's extension tool failed ({args[0]}): "
                         + (proc.stdout + proc.stderr).strip().replace("\n", " | "))
    return proc.stdout


def _plan(wheels, builds, platforms, lock):
    """[(build, its platforms among ``platforms``, its wheels for them)], checking every platform of a
    build has a wheel of each of the build's packages."""
    jobs = []
    for b in builds:
        mine = tuple(p for p in platforms if p in b.platforms)
        if not mine:
            continue
        ours = [w for w in wheels if w.python == b.python]
        chosen = [w for w in ours if w.platform in mine]
        for p in mine:
            missing = {w.name for w in ours} - {w.name for w in chosen if w.platform == p}
            if missing:
                raise BuildError(f"{Path(lock).name}: no {p} wheel for {', '.join(sorted(missing))} "
                                 f"(Python {b.python}, the {b.name} build)")
        jobs.append((b, mine, chosen))
    if not jobs:
        raise BuildError(f"no build is made for {', '.join(platforms)}: "
                         + "; ".join(f"{b.name} is for {', '.join(b.platforms)}" for b in builds))
    return jobs


def build(out_dir, *, builds=None, platforms=PLATFORMS, cache_dir=None, tool=None, lock=LOCK_FILE, source=REPO,
          log=print, overwrite=False):
    """Build and validate one extension zip per build and platform in ``out_dir``.

    Parameters
    ----------
    out_dir : path-like
        Where the zips go (created if missing); same-named zips facecap built are replaced, other files in
        their way refused before anything is fetched (the output policy; ``overwrite`` replaces them).
    builds : sequence of str, optional
        Names of builds (``solvers/extension_builds.py``); default all.
    platforms : sequence of str
        A subset of ``PLATFORMS``; each build makes a zip for those of them it supports, with only its
        wheels.
    cache_dir, tool, lock, source
        Wheel cache (default ``default_cache_dir()``), ``blender_ext.py`` (default: from the bpy wheel),
        the lock file and the extension source root.

    Returns
    -------
    list of BuiltZip
        Build by build, each in the order of ``platforms``.
    """
    platforms = tuple(dict.fromkeys(platforms))
    unknown = [p for p in platforms if p not in PLATFORMS]
    if unknown or not platforms:
        raise BuildError(f"unknown platform(s) {unknown}; choose from {', '.join(PLATFORMS)}")
    try:
        chosen_builds = [build_named(n) for n in dict.fromkeys(builds)] if builds else list(BUILDS)
    except KeyError as exc:
        raise BuildError(exc.args[0]) from None
    wheels, _ = read_lock(lock)
    jobs = _plan(wheels, chosen_builds, platforms, lock)
    version = tomllib.loads((Path(source) / MANIFEST).read_text(encoding="utf-8")).get("version", "")
    check_files_in(out_dir, [b.zip_name(version, p) for b, mine, _ in jobs for p in mine], "--out", "extension_zip",
                   overwrite=overwrite)
    tool = Path(tool) if tool else find_extension_tool()
    paths = fetch_wheels([w for _, _, chosen in jobs for w in chosen], cache_dir, log=log)
    assets = fetch_assets(read_assets(lock), cache_dir, log=log)
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    built = []
    for b, mine, chosen in jobs:
        # The tool's own output goes beside the final zips (same file system: renamed, not copied).
        with tempfile.TemporaryDirectory(prefix="facecap-extension-") as tmp, \
                tempfile.TemporaryDirectory(prefix=".facecap-build-", dir=out_dir) as made:
            stage = Path(tmp) / "facecap"
            stage.mkdir()
            manifest = stage_source(stage, [paths[w.file] for w in chosen], mine, ext_build=b, source=source,
                                    assets=assets)
            _run_tool(tool, "build", "--source-dir", stage, "--output-dir", made, "--split-platforms",
                      *_valid_tags(tool), cwd=tmp)
            for p in mine:
                tool_zip = Path(made) / f"{manifest['id']}-{manifest['version']}-{p.replace('-', '_')}.zip"
                if not tool_zip.is_file():
                    raise BuildError(f"Blender's extension tool did not write {tool_zip.name}")
                path = out_dir / b.zip_name(manifest["version"], p)
                os.replace(tool_zip, path)
                mark_output(path, "extension_zip")  # facecap's own: the next build replaces it
                _run_tool(tool, "validate", path, *_valid_tags(tool))
                built.append(BuiltZip(b.name, p, path, path.stat().st_size,
                                      tuple(w.file for w in chosen if w.platform == p)))
    return built


def main(argv=None, *, parents=()):
    """Entry point for ``facecap build-extension``; returns the exit code."""
    parser = argparse.ArgumentParser(
        prog="facecap build-extension", parents=list(parents),
        description="Build and validate the Blender extension zips (one per Blender generation and platform, "
                    "scipy and OpenCV bundled).")
    parser.add_argument("--out", default="dist", help="output folder (default: ./dist)")
    parser.add_argument("--build", action="append", choices=[b.name for b in BUILDS],
                        help="make only this build's zips (repeatable; default: all: "
                             + "; ".join(f"{b.name}: {b.blenders}" for b in BUILDS) + ")")
    parser.add_argument("--platform", action="append", choices=PLATFORMS,
                        help="build only this platform (repeatable; default: every platform of each build)")
    parser.add_argument("--cache", help="wheel cache folder (default: $FACECAP_CACHE or ~/.cache/facecap)")
    parser.add_argument("--release", metavar="TAG",
                        help="a release's build (the release workflow's): TAG must be v<the manifest's version>; "
                             f"also writes {release.CHECKSUMS} and {release.NOTES} (which zip is whose) beside the zips")
    parser.add_argument("--docs", metavar="PAGE", help="rewrite the zip table of PAGE (docs/install.md) with the "
                                                       "zips built")
    parser.add_argument("--overwrite", action="store_true", help="let the zips replace files in --out that facecap "
                        "did not build (default: refused)")
    args = parser.parse_args(argv)
    manifest = tomllib.loads((REPO / MANIFEST).read_text(encoding="utf-8"))
    if args.release is not None:  # before any download: a mislabelled release never starts
        release.check_tag(args.release, manifest["version"])
        check_outputs([Output(f"--release ({n})", Path(args.out) / n, kind) for n, kind in release.FILES],
                      overwrite=args.overwrite)
    built = build(args.out, builds=args.build, platforms=args.platform or PLATFORMS, cache_dir=args.cache,
                  log=lambda line: print(line, flush=True), overwrite=args.overwrite)
    for z in built:
        mb = z.size / 1e6
        over = f"  (over the {SIZE_TARGET_MB:.0f} MB target)" if mb > SIZE_TARGET_MB else ""
        print(f"{z.build} {z.platform}: {z.path} ({mb:.1f} MB, validated){over}")
    if args.release is not None:
        for path, (_, kind) in zip(release.write_release(built, args.out, manifest, sha256_of), release.FILES):
            mark_output(path, kind)  # facecap's own: the next release build replaces them
            print(f"wrote {path}")
    if args.docs is not None:
        print(f"wrote {release.write_docs_table(built, args.docs)}")
    return 0
