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
import re
import shutil
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

from ..character.ict_release import RELEASE_COMMIT, RELEASE_URL
from ..character.template import HumanTemplate, check_template_output, convert, template_path
from ..errors import Cancelled, FacecapError
from ..io.files import new_temporary, pid_alive, remove_stale_temporaries
from ..io.outputs import OutputError
from .build_extension import default_cache_dir

CHUNK = 1 << 20
TIMEOUT_S = 60  # per network read
#: Largest download (bytes): the release's zip is about 0.2 GB (its OBJ files 0.4 GB unpacked); a server that
#: sends more (or announces more) is not sending it, and the disk is not filled waiting to find out
MAX_DOWNLOAD_BYTES = 768 << 20
#: The whole download's deadline (seconds): 0.2 GB at 0.5 Mbit/s; a server trickling bytes slower than the
#: per-read timeout notices is stopped here
DOWNLOAD_SECONDS = 3600.0
#: A partial download of an older facecap (``<name>.part-<pid>``), removed once its process is gone
_OLD_PART = re.compile(r"^.+\.part-(\d+)$")


def _progress(done, total):
    print(f"\rfacecap: reading ICT-FaceKit {done}/{total} OBJ files", end="\n" if done == total else "",
          file=sys.stderr, flush=True)


def _download_progress(done, total):
    size = f"{done / 1e6:.0f} of {total / 1e6:.0f} MB" if total else f"{done / 1e6:.0f} MB"
    print(f"\rfacecap: downloading ICT-FaceKit, {size}", end="\n" if done == total else "", file=sys.stderr,
          flush=True)


def download(url, path, *, progress=None, timeout=None, max_bytes=None, deadline=None, what="ICT-FaceKit",
             manual=None):
    """``url`` to ``path``, atomically: read into a temporary file beside it (``files.new_temporary``: two
    downloads at once do not meet, and one killed outright is removed by the next fetch), renamed when
    complete, removed when not (an error, Ctrl-C, ``progress(done, total)`` returning False: ``Cancelled``).
    At most ``max_bytes`` are read (a larger announced size is refused before the first byte), within
    ``deadline`` seconds in all, and only when the disk has room for an announced size (defaults:
    ``TIMEOUT_S`` per read, ``MAX_DOWNLOAD_BYTES``, ``DOWNLOAD_SECONDS``). ``what`` names the download in
    messages, ``manual`` says what to do when it fails."""
    path = Path(path)
    timeout = TIMEOUT_S if timeout is None else timeout
    max_bytes = MAX_DOWNLOAD_BYTES if max_bytes is None else max_bytes
    deadline = DOWNLOAD_SECONDS if deadline is None else deadline
    if urllib.parse.urlsplit(url).scheme.lower() not in ("http", "https"):
        raise FacecapError(f"{url}: not an http(s) address; for a file you have, run "
                           "`python -m facecap template convert <the zip>`")
    part = new_temporary(path)
    start = time.monotonic()
    try:
        request = urllib.request.Request(url, headers={"User-Agent": "facecap"})
        with urllib.request.urlopen(request, timeout=timeout) as response, open(part, "wb") as f:
            total, done = _announced(response), 0
            if total > max_bytes:
                raise _failed(url, f"the server announces {total / 2**20:.0f} MiB; facecap downloads at most "
                                   f"{max_bytes / 2**20:.0f} MiB of {what}", what, manual)
            free = shutil.disk_usage(part.parent).free
            if total > free:
                raise OutputError(f"{path.parent}: not enough free space for the download ({total / 2**20:.0f} MiB; "
                                  f"{free / 2**20:.0f} MiB free)")
            while chunk := response.read1(min(CHUNK, max_bytes + 1 - done)):  # what came: the deadline is seen
                f.write(chunk)
                done += len(chunk)
                if done > max_bytes:
                    raise _failed(url, f"more than {max_bytes / 2**20:.0f} MiB came (more than {what} holds); stopped",
                                  what, manual)
                if time.monotonic() - start > deadline:
                    raise _failed(url, f"not finished after {deadline / 60:.0f} minutes ({done / 2**20:.0f} MiB); "
                                       "stopped", what, manual)
                if progress is not None and progress(done, total) is False:
                    raise Cancelled(f"the download of {what} was cancelled")
            if total and done != total:
                raise _failed(url, f"the download stopped at {done} of {total} bytes", what, manual)
        os.replace(part, path)
    except (urllib.error.URLError, http.client.HTTPException, ValueError, OSError) as exc:
        raise _failed(url, getattr(exc, "reason", None) or exc, what, manual) from None
    finally:
        part.unlink(missing_ok=True)
    return path


def _check_address(url):
    try:
        parts = urllib.parse.urlsplit(url)
        parts.port  # noqa: B018 - a port that is not a number raises here
    except ValueError as exc:
        raise FacecapError(f"{url[:200]}: not a valid address ({exc})") from None
    if parts.scheme.lower() not in ("http", "https") or not parts.hostname:
        raise FacecapError(f"{url[:200]}: not an http(s) address; for a file you have, run "
                           "`python -m facecap template convert <the zip>`")


def _announced(response):
    try:
        return max(0, int(response.headers.get("Content-Length") or 0))
    except ValueError:
        return 0


def _failed(url, reason, what="ICT-FaceKit", manual=None):
    manual = manual or "download it in a browser and run `python -m facecap template convert <the zip>`"
    return FacecapError(f"{url}: could not download {what} ({reason}); {manual}")


def remove_stale_downloads(cache):
    """Remove the partial downloads in ``cache`` that no live fetch owns (``files.remove_stale_temporaries``,
    and ``<name>.part-<pid>`` of an older facecap whose process is gone); returns them."""
    removed = remove_stale_temporaries(cache)
    if Path(cache).is_dir():
        for entry in Path(cache).iterdir():
            match = _OLD_PART.match(entry.name)
            if match and entry.is_file() and not pid_alive(int(match.group(1))):
                entry.unlink(missing_ok=True)
                removed.append(entry)
    return removed


def _archive_name(url):
    """The cache's name of ``url``'s zip: the release's own, else the address's last part when it is a plain
    file name (never ``..``, a hidden name or a path), else ``ict.zip``."""
    if url == RELEASE_URL:
        return f"ICT-FaceKit-{RELEASE_COMMIT}.zip"
    name = urllib.parse.unquote(urllib.parse.urlsplit(url).path.rsplit("/", 1)[-1])
    return name if re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.+-]{0,100}", name) else "ict.zip"


def fetch(url=RELEASE_URL, out=None, *, cache=None, keep=False, progress=None, read_progress=None, overwrite=False):
    """Download ICT-FaceKit from ``url`` into facecap's cache (``<cache>/downloads``), convert it into the
    template at ``out`` (default ``template_path()``; the output policy is applied before the download) and
    remove the download unless ``keep``; a download already in the cache is used as it is. A download that
    does not convert is removed (the next fetch downloads again), and so are partial downloads left by
    fetches killed outright. Returns the template's path."""
    _check_address(url)
    out = check_template_output(out, overwrite=overwrite)
    cache = Path(cache) if cache is not None else default_cache_dir() / "downloads"
    remove_stale_downloads(cache)
    archive = cache / _archive_name(url)
    if archive.exists() and not archive.is_file():
        raise FacecapError(f"{archive}: in facecap's download cache but not a file; remove it")
    if not archive.is_file():
        download(url, archive, progress=progress)
    try:
        path = convert(archive, out, progress=read_progress, overwrite=True)  # ``out`` was checked above
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
    _overwrite_flag(p)
    p = sub.add_parser("convert", help="convert a copy of ICT-FaceKit into facecap's template: the zip as downloaded "
                                       f"from GitHub (release {RELEASE_COMMIT[:7]}, docs/strategies.md), the "
                                       "repository folder or its FaceXModel folder")
    p.add_argument("source", help="the ICT-FaceKit download: its zip, the repository folder or FaceXModel/ (or a "
                                  "reduced ict_face.npz)")
    p.add_argument("--out", default=None, help=f"where to write it (default: {template_path()}, which [actor] "
                                                "template = \"auto\" finds)")
    _overwrite_flag(p)
    p = sub.add_parser("info", help="where the template is and what it holds")
    p.add_argument("path", nargs="?", default=None, help=f"a template file (default: {template_path()})")
    args = parser.parse_args(argv)
    tty = sys.stderr.isatty()
    if args.action == "fetch":
        out = fetch(args.url, None if args.out is None else Path(args.out).expanduser(), keep=args.keep,
                    progress=_download_progress if tty else None, read_progress=_progress if tty else None,
                    overwrite=args.overwrite)
        print(f"facecap: human template written to {out}", file=sys.stdout)
        return 0
    if args.action == "convert":
        out = convert(Path(args.source).expanduser(), None if args.out is None else Path(args.out).expanduser(),
                      progress=_progress if tty else None, overwrite=args.overwrite)
        print(f"facecap: human template written to {out}", file=sys.stdout)
        return 0
    path = Path(args.path).expanduser() if args.path else template_path()
    if not path.exists():
        raise FacecapError(f"no human template at {path}; install one with `python -m facecap template fetch` (or "
                           "`template convert` on a download)")
    t = HumanTemplate.load(path)
    m = t.model
    print(f"{path}: {len(m.shape_names)} shapes, {m.identity.shape[0]} identity modes, {m.n_vertices} vertices, "
          f"data digest {m.digest[:16]}...")
    return 0


def _overwrite_flag(parser):
    parser.add_argument("--overwrite", action="store_true", help="let --out replace a file facecap did not write "
                        "(default: refused; never the source)")
