"""``python -m facecap template``: install the optional human template (docs/strategies.md, "semantic").

    python -m facecap template fetch [--url URL] [--keep]   # download the release facecap knows, then convert it
    python -m facecap template convert PATH [--out FILE]   # the ICT-FaceKit download -> facecap's template
    python -m facecap template info [FILE]                  # where the template is, and what it holds

The model is not shipped with facecap (ICT-FaceKit, MIT, USC Institute for Creative Technologies): ``fetch``
downloads it only when asked. The conversion is hash-checked, so the accuracy figures in docs/accuracy.md
hold for what it installs.
"""

import argparse
import http.client
import os
import sys
import urllib.error
import urllib.request
from pathlib import Path

from ..character.ict_release import RELEASE_COMMIT, RELEASE_URL
from ..character.template import HumanTemplate, convert, template_path
from ..errors import Cancelled, FacecapError
from .build_extension import default_cache_dir

CHUNK = 1 << 20
TIMEOUT_S = 60  # per network read


def _progress(done, total):
    print(f"\rfacecap: reading ICT-FaceKit {done}/{total} OBJ files", end="\n" if done == total else "",
          file=sys.stderr, flush=True)


def _download_progress(done, total):
    size = f"{done / 1e6:.0f} of {total / 1e6:.0f} MB" if total else f"{done / 1e6:.0f} MB"
    print(f"\rfacecap: downloading ICT-FaceKit, {size}", end="\n" if done == total else "", file=sys.stderr,
          flush=True)


def download(url, path, *, progress=None, timeout=TIMEOUT_S, what="ICT-FaceKit", manual=None):
    """``url`` to ``path``, atomically: read into ``<path>.part-<pid>`` (two downloads at once do not meet),
    renamed when complete, removed when not (an error, Ctrl-C, ``progress(done, total)`` returning False:
    ``Cancelled``). ``what`` names the download in messages, ``manual`` says what to do when it fails."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    part = path.with_name(f"{path.name}.part-{os.getpid()}")
    try:
        request = urllib.request.Request(url, headers={"User-Agent": "facecap"})
        with urllib.request.urlopen(request, timeout=timeout) as response, open(part, "wb") as f:
            total, done = int(response.headers.get("Content-Length") or 0), 0
            while chunk := response.read(CHUNK):
                f.write(chunk)
                done += len(chunk)
                if progress is not None and progress(done, total) is False:
                    raise Cancelled(f"the download of {what} was cancelled")
            if total and done != total:
                raise _failed(url, f"the download stopped at {done} of {total} bytes", what, manual)
        os.replace(part, path)
    except (urllib.error.URLError, http.client.HTTPException, OSError) as exc:
        raise _failed(url, getattr(exc, "reason", None) or exc, what, manual) from None
    finally:
        part.unlink(missing_ok=True)
    return path


def _failed(url, reason, what="ICT-FaceKit", manual=None):
    manual = manual or "download it in a browser and run `python -m facecap template convert <the zip>`"
    return FacecapError(f"{url}: could not download {what} ({reason}); {manual}")


def fetch(url=RELEASE_URL, out=None, *, cache=None, keep=False, progress=None, read_progress=None):
    """Download ICT-FaceKit from ``url`` into facecap's cache (``<cache>/downloads``), convert it into the
    template at ``out`` (default ``template_path()``) and remove the download unless ``keep``; a download
    already in the cache is used as it is. A download that does not convert is removed (the next fetch
    downloads again). Returns the template's path."""
    cache = Path(cache) if cache is not None else default_cache_dir() / "downloads"
    name = f"ICT-FaceKit-{RELEASE_COMMIT}.zip" if url == RELEASE_URL else Path(url.split("?")[0]).name or "ict.zip"
    archive = cache / name
    if not archive.is_file():
        download(url, archive, progress=progress)
    try:
        path = convert(archive, out, progress=read_progress)
    except Cancelled:
        raise  # the download is kept: the next fetch converts it
    except FacecapError:
        archive.unlink(missing_ok=True)
        raise
    if not keep:
        archive.unlink(missing_ok=True)
    return path


def main(argv=None, *, parents=()):
    parser = argparse.ArgumentParser(
        prog="facecap template", parents=list(parents),
        description="Install the optional human template from a copy of ICT-FaceKit (hash-checked), or say where "
                    "the installed one is; the semantic strategy fits it to the actor when nothing else is known.")
    sub = parser.add_subparsers(dest="action", required=True)
    p = sub.add_parser("fetch", help=f"download ICT-FaceKit (release {RELEASE_COMMIT[:7]}, MIT, from GitHub) and "
                                     "convert it into facecap's template")
    p.add_argument("--url", default=RELEASE_URL, help="where to download it from (default: the release on GitHub)")
    p.add_argument("--keep", action="store_true", help="keep the downloaded zip in facecap's cache")
    p.add_argument("--out", default=None, help=f"where to write the template (default: {template_path()})")
    p = sub.add_parser("convert", help="convert a copy of ICT-FaceKit into facecap's template: the zip as downloaded "
                                       f"from GitHub (release {RELEASE_COMMIT[:7]}, docs/strategies.md), the "
                                       "repository folder or its FaceXModel folder")
    p.add_argument("source", help="the ICT-FaceKit download: its zip, the repository folder or FaceXModel/ (or a "
                                  "reduced ict_face.npz)")
    p.add_argument("--out", default=None, help=f"where to write it (default: {template_path()}, which [actor] "
                                                "template = \"auto\" finds)")
    p = sub.add_parser("info", help="where the template is and what it holds")
    p.add_argument("path", nargs="?", default=None, help=f"a template file (default: {template_path()})")
    args = parser.parse_args(argv)
    tty = sys.stderr.isatty()
    if args.action == "fetch":
        out = fetch(args.url, None if args.out is None else Path(args.out).expanduser(), keep=args.keep,
                    progress=_download_progress if tty else None, read_progress=_progress if tty else None)
        print(f"facecap: human template written to {out}", file=sys.stdout)
        return 0
    if args.action == "convert":
        out = convert(Path(args.source).expanduser(), None if args.out is None else Path(args.out).expanduser(),
                      progress=_progress if tty else None)
        print(f"facecap: human template written to {out}", file=sys.stdout)
        return 0
    path = Path(args.path).expanduser() if args.path else template_path()
    if not path.exists():
        print(f"facecap: no human template at {path}; install one with `python -m facecap template fetch` (or "
              "`template convert` on a download)")
        return 1
    t = HumanTemplate.load(path)
    m = t.model
    print(f"{path}: {len(m.shape_names)} shapes, {m.identity.shape[0]} identity modes, {m.n_vertices} vertices, "
          f"data digest {m.digest[:16]}...")
    return 0
