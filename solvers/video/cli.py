"""``facecap track --config take.toml``: track footage and write 2D markers as a wide CSV.

Config (paths relative to the config file)::

    [source]
    video = "clip.mp4"          # video file, image folder, glob or printf pattern
    first = 1                   # optional frame range / step / downscale / rate
    last = 600
    step = 1
    scale = 1.0
    fps = 30.0                  # override (image sequences default to 24)

    [tracking]
    points = "points2d.csv"     # name,x,y at the reference frame (source pixels) ...
    region = [x, y, w, h]       # ... or automatic features in this box
    method = "lk"               # "lk" | "dis" | "farneback" | "tvl1"
    reference = 1               # neutral reference frame (default: first frame read)
    max_points = 100            # automatic features
    reregister = true           # lk: drift control by re-registration to the reference
    reseed = true               # lk: re-acquire lost points
    drift = "fuse"              # dense: "fuse" | "direct" | "none"
    win_size = 21               # lk window
    fb_threshold = 1.0          # lk forward-backward threshold (working pixels)

    [output]
    markers = "tracks.csv"      # frame,<name>_x,<name>_y (pixels, origin top-left; frame 1 = first frame)
    confidence = "conf.csv"     # optional: frame,<name> per-sample confidence in [0, 1]
    report = "track.json"       # optional: summary, losses, re-acquisitions, footage info

Frame numbers (``first``, ``last``, ``reference`` and the frames written) follow the project's one
convention: frame 1 is the first frame of the footage, as in Blender and in marker files; frame 0 and
the removed ``frame_offset`` key are errors that say so.
"""

import argparse
import contextlib
import os
import signal
import sys
import threading
import time
import tomllib
from pathlib import Path

from ..errors import ConfigError, FacecapError, InputFileError, Problems
from ..io.csv import write_markers_csv, write_weights_csv
from ..io.files import read_text_input, remove_stale_temporaries, write_json_atomic
from ..io.outputs import Output, check_outputs
from ..options import TRACK_OPTIONS, table_problems
from .flow import track_with_flow_job
from .reading import Cancelled, Footage
from .tracking import track_points_job
from .flow_config import frame_number_error

#: The track report's schema version (its first key, ``"facecap_track"``, also marks it as facecap's own)
REPORT_SCHEMA = 1
#: Options of one tracking method only
LK_ONLY, DENSE_ONLY = ("reregister", "reseed", "win_size", "fb_threshold", "levels"), ("drift", "preset")


def read_track_toml(path):
    """(absolute path, TOML tables) of a track config; ConfigError naming the file when unreadable."""
    path = Path(os.path.expanduser(str(path))).resolve()
    try:
        text = read_text_input(path, "config file not found")
        return path, tomllib.loads(text)
    except InputFileError as exc:
        raise ConfigError(str(exc).removeprefix(f"{path}: "), path=path) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"not valid TOML: {exc}", path=path) from None
    except (RecursionError, ValueError) as exc:  # nested too deeply; an integer beyond Python's digit limit
        raise ConfigError(f"not valid TOML: {exc or 'values nested too deeply'}", path=path) from None


def load_track_config(path, *, overwrite=False):
    """Parse and check a track config (``solvers.options.TRACK_OPTIONS``: every problem of the file at
    once, with a "did you mean"), then its outputs against the output policy (``solvers.io.outputs``);
    returns a dict of resolved settings."""
    path, data = read_track_toml(path)
    problems = Problems()
    for key, message, covers in table_problems(data, TRACK_OPTIONS, open_sections=()):
        problems.add(ConfigError(message, path=path, key=key), covers=covers)
    src, trk, out = ({k: v for k, v in (data.get(s) or {}).items() if not problems.covered(f"{s}.{k}")}
                     if isinstance(data.get(s), dict) else {} for s in ("source", "tracking", "output"))
    given = data.get("tracking") if isinstance(data.get("tracking"), dict) else {}
    if ("points" in given) == ("region" in given) and not problems.covered("tracking"):
        problems.add(ConfigError("give exactly one of `points` (a name,x,y file) and `region` = [x, y, w, h]",
                                 path=path, key="tracking"))
    region = trk.get("region")
    if region is not None and not (region[2] > 0 and region[3] > 0):
        problems.add(ConfigError(f"expected [x, y, w, h] with w, h > 0; got {region!r}", path=path,
                                 key="tracking.region"))
    for section, key in (("source", "first"), ("source", "last"), ("source", "frame_offset"),
                         ("tracking", "reference")):
        table = src if section == "source" else trk
        if key in table and (problem := frame_number_error(f"{section}.{key}", table[key])):
            problems.add(ConfigError(problem, path=path, key=f"{section}.{key}"))
    method = trk.get("method", "lk")
    options = {k: trk[k] for k in trk if k not in ("points", "region", "method", "reference")}
    wrong = sorted(set(options) & set(DENSE_ONLY if method == "lk" else LK_ONLY))
    if wrong:
        problems.add(ConfigError(f"{wrong} do not apply to method {method!r}", path=path, key="tracking"))
    problems.raise_any()
    base = path.parent

    def resolve(value):
        return base / os.path.expanduser(value)

    settings = {
        "config": path,
        "video": str(resolve(src["video"])),
        "footage": {k: src[k] for k in ("first", "last", "step", "scale", "fps") if k in src},
        "points": str(resolve(trk["points"])) if "points" in trk else None,
        "region": region,
        "method": method,
        "reference": trk.get("reference"),
        "options": options,
        **{key: str(resolve(out[key])) if key in out else None for key in ("markers", "confidence", "report")},
    }
    check_outputs([Output(f"[output.{key}]", settings[key], kind) for key, kind in TRACK_OUTPUTS],
                  {"the config itself": path, "[source.video]": settings["video"],
                   "[tracking.points]": settings["points"]}, overwrite=overwrite, config=path)
    return settings


#: [output] key -> the kind of file it is (``solvers.io.outputs.KINDS``)
TRACK_OUTPUTS = (("markers", "markers_csv"), ("confidence", "weights_csv"), ("report", "track_report"))


class ProgressLine:
    """``label: done/total frames (rate)`` on one self-overwriting stderr line, at most twice a second."""

    def __init__(self, stream, label):
        self.stream, self.label = stream, label
        self.last, self.start = 0.0, time.monotonic()
        self.open_line = False  # a "\r"-ended line is showing

    def __call__(self, done, total):
        now = time.monotonic()
        if done == total or now - self.last >= 0.5:
            self.last = now
            rate = done / max(now - self.start, 1e-9)
            end = "\n" if done == total else "\r"
            print(f"{self.label}: {done}/{total} frames ({rate:.0f} frames/s)", end=end, file=self.stream, flush=True)
            self.open_line = done != total
        return True

    def close_line(self):
        if self.open_line:
            print(file=self.stream, flush=True)
            self.open_line = False


def tracking_job(settings):
    """The :class:`~.reading.Job` described by ``load_track_config`` output (seeds read and checked)."""

    footage = Footage(settings["video"], **settings["footage"])
    common = dict(points=settings["points"], region=settings["region"], reference=settings["reference"])
    try:
        if settings["method"] == "lk":
            return track_points_job(footage, **common, **settings["options"])
        return track_with_flow_job(footage, method=settings["method"], **common, **settings["options"])
    except TypeError as exc:  # a wrongly typed option value
        raise FacecapError(f"bad [tracking] option: {exc}") from None


def write_outputs(settings, result, info):
    """Write the markers CSV (and the confidence CSV and JSON report when asked), each atomically."""
    write_markers_csv(settings["markers"], result.markers)
    if settings["confidence"]:
        write_weights_csv(settings["confidence"], result.markers.frames, result.markers.names, result.confidence)
    if settings["report"]:
        write_json_atomic(settings["report"], {
            "facecap_track": REPORT_SCHEMA, "summary": result.summary(), "method": result.method,
            "reference": result.reference,
            "frame_numbering": "frame 1 is the first frame of the footage",
            "footage": {"path": info.path, "fps": info.fps, "width": info.width, "height": info.height,
                        "scale": info.scale, "frames": [info.frames[0], info.frames[-1]], "count": info.n_frames},
            "markers": list(result.markers.names), "lost": result.lost, "reseeded": result.reseeded,
        })


def run_track(settings, *, progress=None):
    """Track as described by ``load_track_config`` output; writes the outputs, returns the TrackResult.

    ``progress(done, total)`` returning False cancels with :class:`~.reading.Cancelled` before
    anything is written.
    """
    job = tracking_job(settings)
    try:
        result = job.run(progress)
    except TypeError as exc:
        raise FacecapError(f"bad [tracking] option: {exc}") from None
    write_outputs(settings, result, job.info)
    return result


@contextlib.contextmanager
def sigint_cancels():
    """Within the block Ctrl-C (SIGINT) only sets the yielded Event, so long work stops between two
    frames (its progress callback returns False); a second Ctrl-C interrupts at once. Off the main
    thread signals cannot be caught: the Event is never set."""
    stop = threading.Event()
    restore = None
    if threading.current_thread() is threading.main_thread():
        def on_sigint(signum, frame):
            stop.set()
            signal.signal(signal.SIGINT, signal.default_int_handler)  # a second Ctrl-C interrupts at once

        restore = signal.signal(signal.SIGINT, on_sigint)
    try:
        yield stop
    finally:
        if restore is not None:
            signal.signal(signal.SIGINT, restore)


def main(argv=None):
    """``[track] --config take.toml``; returns the exit status (0 ok, 1 error, 130 cancelled).

    Ctrl-C (SIGINT) stops tracking between two frames: one line ``cancelled at frame N``, exit
    status 130, no output written. A second Ctrl-C interrupts at once.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["track"]:
        argv = argv[1:]
    parser = argparse.ArgumentParser(prog="facecap track", description="Track 2D markers in footage.")
    parser.add_argument("--config", required=True, help="take config (.toml) with [source], [tracking], [output]")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    parser.add_argument("--overwrite", action="store_true",
                        help="let outputs replace existing files facecap did not write (default: refused)")
    args = parser.parse_args(argv)
    with sigint_cancels() as stop:
        return _main(args, stop)


def _main(args, stop):
    shown = None
    try:
        settings = load_track_config(args.config, overwrite=args.overwrite)
        for key in ("markers", "confidence", "report"):
            if settings[key] is not None:
                remove_stale_temporaries(Path(settings[key]).parent)
        shown = None if args.quiet else ProgressLine(sys.stderr, f"track ({settings['method']})")

        def progress(done, total):
            if shown is not None:
                shown(done, total)
            return not stop.is_set()

        result = run_track(settings, progress=progress)
    except Cancelled as exc:
        if shown is not None:
            shown.close_line()
        print(f"facecap: {exc}; nothing written", file=sys.stderr)
        return 130
    except FacecapError as exc:
        if shown is not None:
            shown.close_line()
        for line in str(exc).splitlines():
            print(f"facecap: error: {' '.join(line.split())}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        if shown is not None:
            shown.close_line()
        print("facecap: interrupted", file=sys.stderr)
        return 130
    print(f"{result.summary()}; wrote {settings['markers']}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
