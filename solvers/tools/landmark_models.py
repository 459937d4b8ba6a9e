"""``python -m facecap landmark-models``: the face-landmark models into the facecap cache.

    python -m facecap landmark-models             # the older face-mesh models, from the locked mediapipe wheel
    python -m facecap landmark-models fetch       # MediaPipe's Face Landmarker bundle (with the blendshape head)
    python -m facecap landmark-models info        # which models a landmark take uses, and where they are

The three older MediaPipe face-mesh files are taken out of the locked ``mediapipe`` 0.10.21 wheel (the
``[[asset]]`` entries of ``wheels.lock.toml``: downloaded once with pip, hash checked, the same fetch the
extension build uses). The Face Landmarker bundle is downloaded from MediaPipe's own address by the
template's downloader (``template.download``: a ``.part`` file renamed when complete), bounded by the
bundle's known size and a deadline, and installed only when its SHA-256 is the one facecap knows.
"""

import argparse
import os
import sys
import time
from pathlib import Path

from ..errors import FacecapError
from ..video.face_models import MODEL_FILES, cache_models_dir, find_models
from ..video.landmarker_bundle import BUNDLE_SHA256, BUNDLE_SIZE, BUNDLE_URL, bundle_path, check_bundle, find_bundle
from .build_extension import fetch_assets, read_assets
from .template import download

DEADLINE_S = 300  # the whole bundle download (3.8 MB)
MANUAL = (f"download {BUNDLE_URL} in a browser and put it at {bundle_path()} (or name it in "
          "$FACECAP_FACE_LANDMARKER)")


def install_models(cache_dir=None, *, log=print):
    """Write the three older model files into :func:`~..video.face_models.cache_models_dir`; returns it."""
    wanted = set(MODEL_FILES.values())
    assets = [a for a in read_assets() if Path(a.target).name in wanted]
    if {Path(a.target).name for a in assets} != wanted:
        raise FacecapError("wheels.lock.toml does not lock the face-landmark models (asset entries for "
                           + ", ".join(sorted(wanted)) + ")")
    target = cache_models_dir()
    target.mkdir(parents=True, exist_ok=True)
    for asset, data in fetch_assets(assets, cache_dir, log=log).items():
        path = target / Path(asset.target).name
        tmp = path.with_name(path.name + ".part")
        tmp.write_bytes(data)
        os.replace(tmp, path)  # atomic: a reader never sees half a model
    return target


def bundle_installed(path=None):
    """True when the bundle at ``path`` (default: the cache's) is there with the known digest."""
    path = Path(path) if path is not None else bundle_path()
    try:
        check_bundle(path)
    except (FacecapError, OSError):
        return False
    return True


def fetch_bundle(url=BUNDLE_URL, out=None, *, progress=None, deadline=DEADLINE_S):
    """Download the Face Landmarker bundle from ``url`` to ``out`` (default :func:`bundle_path`) unless it is
    there already; returns its path. The download stops when it passes the bundle's size or ``deadline``
    seconds (nothing kept); a file with another digest is removed and refused. ``progress(done, total)``
    returning False cancels (``Cancelled``)."""
    out = Path(out) if out is not None else bundle_path()
    if bundle_installed(out):
        return out
    start = time.monotonic()

    def bounded(done, total):
        if done > BUNDLE_SIZE or (total and total != BUNDLE_SIZE):
            raise FacecapError(f"{url}: the server sends {max(done, total):,} bytes, not the bundle's "
                               f"{BUNDLE_SIZE:,}; nothing was installed ({MANUAL})")
        if time.monotonic() - start > deadline:
            raise FacecapError(f"{url}: the download took more than {deadline} s ({done:,} of {BUNDLE_SIZE:,} "
                               f"bytes); nothing was installed. Try again, or {MANUAL}")
        return True if progress is None else progress(done, total or BUNDLE_SIZE)

    staged = out.with_name(f"{out.name}.new-{os.getpid()}")
    try:
        download(url, staged, progress=bounded, timeout=min(60, deadline), what="the Face Landmarker bundle",
                 manual=MANUAL)
        check_bundle(staged)
        os.replace(staged, out)
    finally:
        staged.unlink(missing_ok=True)
    return out


def _download_progress(done, total):
    print(f"\rfacecap: downloading the Face Landmarker bundle, {done / 1e6:.1f} of {total / 1e6:.1f} MB",
          end="\n" if done >= total else "", file=sys.stderr, flush=True)


def describe():
    """Lines saying which models a landmark take uses and where they are."""
    lines = []
    try:
        found = find_bundle()
    except FacecapError as exc:
        found, lines = None, [f"Face Landmarker bundle: {exc}"]
    if found is not None:
        ok = bundle_installed(found)
        lines.append(f"Face Landmarker bundle: {found}" + ("" if ok else " (NOT the known file: it will be refused)"))
    elif not lines:
        lines.append(f"Face Landmarker bundle: not installed (`python -m facecap landmark-models fetch` puts it at "
                     f"{bundle_path()}; SHA-256 {BUNDLE_SHA256[:16]}...)")
    try:
        lines.append(f"older face-mesh models (the fallback): {find_models()['mesh'].parent}")
    except FacecapError:
        lines.append("older face-mesh models (the fallback): not installed (`python -m facecap landmark-models`)")
    return lines


def main(argv=None, *, parents=()):
    parser = argparse.ArgumentParser(
        prog="facecap landmark-models", parents=list(parents),
        description="Put face-landmark models into the facecap cache: the older face-mesh models from the locked "
                    "mediapipe wheel (no action), or MediaPipe's Face Landmarker bundle with its blendshape head "
                    "(`fetch`, hash-checked); `info` says which a landmark take uses.")
    parser.add_argument("action", nargs="?", choices=("wheel", "fetch", "info"), default="wheel",
                        help="wheel (default): the older models; fetch: the Face Landmarker bundle; info: where "
                             "they are")
    parser.add_argument("--url", default=BUNDLE_URL, help="where `fetch` downloads the bundle from (default: "
                                                          "MediaPipe's address)")
    args = parser.parse_args(argv)
    if args.action == "fetch":
        out = fetch_bundle(args.url, progress=_download_progress if sys.stderr.isatty() else None)
        print(f"Face Landmarker bundle in {out} (SHA-256 checked)")
        return 0
    if args.action == "info":
        print("\n".join(describe()))
        return 0
    target = install_models()
    print(f"face-landmark models in {target}: {', '.join(MODEL_FILES.values())}")
    return 0
