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
    method = "lk"               # "lk" | "dis" | "farneback" | "tvl1" | "landmarks" (no points or region)
    reference = 1               # neutral reference frame (default: first frame read)
    max_points = 100            # automatic features
    reregister = true           # lk: drift control by re-registration to the reference
    reseed = true               # lk: re-acquire lost points
    drift = "fuse"              # dense: "fuse" | "direct" | "none"
    win_size = 21               # lk window
    fb_threshold = 1.0          # lk forward-backward threshold (working pixels)
    smoothing = true            # landmarks: temporal filtering of the detector's jitter
    iris = true                 # landmarks: eyelids and irises from the iris model
    models = "folder"           # landmarks: where the three model files are (default: found)

    [output]
    markers = "tracks.csv"      # frame,<name>_x,<name>_y (pixels, origin top-left; frame 1 = first frame);
                                # landmarks also <name>_z (the model's relative depth, pixels)
    confidence = "conf.csv"     # optional: frame,<name> per-sample confidence in [0, 1]
    report = "track.json"       # optional: summary, losses, re-acquisitions, footage info

Frame numbers (``first``, ``last``, ``reference`` and the frames written) follow the project's one
convention: frame 1 is the first frame of the footage, as in Blender and in marker files; frame 0 and
the removed ``frame_offset`` key are errors that say so.
"""

import argparse
import contextlib
import logging
import os
import signal
import sys
import threading
import time
import tomllib
from pathlib import Path

import numpy as np

from ..errors import ConfigError, FacecapError, InputFileError, Problems, table_problems
from ..io.csv import write_markers_csv, write_weights_csv
from ..io.files import read_text_input, remove_stale_temporaries, write_json_atomic
from ..io.outputs import Output, check_outputs
from ..options import MAX_FPS, MAX_FRAME, Option
from .flow import track_with_flow_job
from .landmarks import track_landmarks_job
from .reading import Cancelled, Footage
from .tracking import track_points_job
from .flow_config import frame_number_error

try:
    from tqdm import tqdm
except ImportError:  # a Blender without the pip dependencies: plain progress lines
    tqdm = None

log = logging.getLogger(__name__)

#: Every key of a track config, checked as a take config's are (``solvers.options``: kinds, ranges with upper
#: bounds, a "did you mean" for unknown sections and keys); ``facecap config-docs`` writes it into docs/config.md.
TRACK_OPTIONS = tuple(Option(*row[:3], **row[3]) for row in (
    ("source", "video", "path", {"required": True, "doc": "Video file, image folder, glob or printf pattern"}),
    ("source", "first", "int", {"high": MAX_FRAME, "doc": "First footage frame read (frame 1 is the first of the "
                                "footage; default: the first)"}),
    ("source", "last", "int", {"high": MAX_FRAME, "doc": "Last footage frame read (default: the last)"}),
    ("source", "step", "int", {"default": 1, "low": 1, "high": 1000, "doc": "Read every n-th frame"}),
    ("source", "scale", "float", {"default": 1.0, "above": 0.0, "high": 1.0, "doc": "Downscale before tracking"}),
    ("source", "fps", "float", {"above": 0.0, "high": MAX_FPS, "doc": "Frame rate (default: the video's; image "
                                "sequences 24)"}),
    ("source", "frame_offset", "int", {"doc": "Removed: frames count from 1 (an error that says so)"}),
    ("tracking", "points", "path", {"doc": "`name,x,y` file of the points at the reference frame (source "
                                    "pixels); or `region`"}),
    ("tracking", "region", "floats", {"length": 4, "low": 0.0, "high": 1e6, "doc": "[x, y, w, h] in source "
                                      "pixels: automatic features in this box; or `points`"}),
    ("tracking", "method", "choice", {"default": "lk", "choices": ("lk", "dis", "farneback", "tvl1", "landmarks"),
                                      "doc": "`lk` (Lucas-Kanade points), dense flow: `dis`, `farneback`, `tvl1`, or "
                                      "`landmarks` (the face's landmarks: no `points` or `region`)"}),
    ("tracking", "reference", "int", {"high": MAX_FRAME, "doc": "The neutral frame the points are given at "
                                      "(default: the first frame read)"}),
    ("tracking", "max_points", "int", {"default": 100, "low": 1, "high": 10_000, "doc": "`region`: the most "
                                       "features found"}),
    ("tracking", "reregister", "bool", {"default": True, "doc": "`lk`: drift control by re-registration to the "
                                        "reference"}),
    ("tracking", "reseed", "bool", {"default": True, "doc": "`lk`: re-acquire lost points from the reference "
                                    "patch"}),
    ("tracking", "win_size", "int", {"default": 21, "low": 3, "high": 255, "doc": "`lk`: window size (working "
                                     "pixels)"}),
    ("tracking", "levels", "int", {"default": 3, "low": 0, "high": 10, "doc": "`lk`: pyramid levels"}),
    ("tracking", "fb_threshold", "float", {"default": 1.0, "above": 0.0, "high": 1e3, "doc": "`lk`: "
                                           "forward-backward error (working pixels) above which a point is lost"}),
    ("tracking", "drift", "choice", {"default": "fuse", "choices": ("fuse", "direct", "none"), "doc": "Dense flow: "
                                     "`fuse` (chained and direct), `direct` (to the reference) or `none`"}),
    ("tracking", "preset", "choice", {"default": "balanced", "choices": ("ultrafast", "fast", "balanced", "medium"),
                                      "doc": "`dis`: speed against quality"}),
    ("tracking", "smoothing", "bool", {"default": True, "doc": "`landmarks`: filter the detector's jitter (zero "
                                       "lag, fast lip motion kept)"}),
    ("tracking", "iris", "bool", {"default": True, "doc": "`landmarks`: eyelids and irises from the iris model"}),
    ("tracking", "models", "path", {"doc": "`landmarks`: folder of the three model files (default: found)"}),
    ("output", "markers", "path", {"required": True, "doc": "The 2D tracks: `frame,<name>_x,<name>_y` in pixels "
                                   "(origin top left; `landmarks` adds `<name>_z`, the model's depth)"}),
    ("output", "confidence", "path", {"doc": "Per-sample confidence in [0, 1]: `frame,<name>,...`"}),
    ("output", "report", "path", {"doc": "JSON: summary, losses, re-acquisitions, footage"}),
))
#: The track report's schema version (its first key, ``"facecap_track"``, also marks it as facecap's own)
REPORT_SCHEMA = 1
#: Options of one tracking method only
LK_ONLY, DENSE_ONLY = ("reregister", "reseed", "win_size", "fb_threshold", "levels"), ("drift", "preset")
LANDMARK_ONLY = ("smoothing", "iris", "models")


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
    """Parse and check a track config (``TRACK_OPTIONS``: every problem of the file at
    once, with a "did you mean"), then its outputs against the output policy (``solvers.io.outputs``);
    returns a dict of resolved settings."""
    path, data = read_track_toml(path)
    problems = Problems()
    for key, message, covers in table_problems(data, TRACK_OPTIONS, open_sections=()):
        problems.add(ConfigError(message, path=path, key=key), covers=covers)
    src, trk, out = ({k: v for k, v in (data.get(s) or {}).items() if not problems.covered(f"{s}.{k}")}
                     if isinstance(data.get(s), dict) else {} for s in ("source", "tracking", "output"))
    given = data.get("tracking") if isinstance(data.get("tracking"), dict) else {}
    method = trk.get("method", "lk")
    if method == "landmarks":
        if "points" in given or "region" in given:
            problems.add(ConfigError("method \"landmarks\" finds the face itself: no `points` or `region`",
                                     path=path, key="tracking"))
        if "reference" in given:
            problems.add(ConfigError("method \"landmarks\" has no reference frame", path=path,
                                     key="tracking.reference"))
    elif ("points" in given) == ("region" in given) and not problems.covered("tracking"):
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
    options = {k: trk[k] for k in trk if k not in ("points", "region", "method", "reference")}
    others = {"lk": DENSE_ONLY + LANDMARK_ONLY, "landmarks": LK_ONLY + DENSE_ONLY + ("max_points",)}
    wrong = sorted(set(options) & set(others.get(method, LK_ONLY + LANDMARK_ONLY)))
    if wrong:
        problems.add(ConfigError(f"{wrong} do not apply to method {method!r}", path=path, key="tracking"))
    problems.raise_any()
    base = path.parent

    def resolve(value):
        return base / os.path.expanduser(value)

    if "models" in options:
        options["models"] = str(resolve(options["models"]))

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
                   "[tracking.points]": settings["points"], "[tracking.models]": options.get("models")},
                  overwrite=overwrite, config=path)
    return settings


#: [output] key -> the kind of file it is (``solvers.io.outputs.KINDS``)
TRACK_OUTPUTS = (("markers", "markers_csv"), ("confidence", "weights_csv"), ("report", "track_report"))


class FrameProgress:
    """Frames done of a long job: a tqdm bar (rate, ETA) on a terminal; elsewhere (a log file, CI) a plain
    ``label: done/total frames`` line after the first report, at most every ``every`` seconds and at the
    end, through :mod:`logging` (``--quiet`` hides them).

    tqdm is a dependency of the pip package; a Blender without it (the extension zip) gets the plain lines.
    """

    def __init__(self, label, *, stream=None, every=10.0, unit="frame"):
        self.label, self.every, self.unit = label, every, unit
        self.stream = stream if stream is not None else sys.stderr
        self.last, self.start = time.monotonic(), time.monotonic()
        self.bar, self.first = None, True
        self.use_bar = tqdm is not None and getattr(self.stream, "isatty", lambda: False)()

    def __call__(self, done, total):
        if self.use_bar:
            if self.bar is None:
                self.bar = tqdm(total=total, desc=self.label, unit=self.unit, file=self.stream, dynamic_ncols=True,
                                leave=True)
            if total != self.bar.total:  # a plan that grew on the way (a rig's probes)
                self.bar.total = total
            self.bar.update(done - self.bar.n)
            return True
        now = time.monotonic()
        if self.first or done == total or now - self.last >= self.every:
            self.first, self.last = False, now
            rate = done / max(now - self.start, 1e-9)
            log.info(f"{self.label}: {done}/{total} {self.unit}s ({rate:.0f} {self.unit}s/s)")
        return True

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def tracking_job(settings):
    """The :class:`~.reading.Job` described by ``load_track_config`` output (seeds read and checked)."""

    footage = Footage(settings["video"], **settings["footage"], color=settings["method"] == "landmarks")
    common = dict(points=settings["points"], region=settings["region"], reference=settings["reference"])
    try:
        if settings["method"] == "landmarks":
            return track_landmarks_job(footage, **settings["options"])
        if settings["method"] == "lk":
            return track_points_job(footage, **common, **settings["options"])
        return track_with_flow_job(footage, method=settings["method"], **common, **settings["options"])
    except TypeError as exc:  # a wrongly typed option value
        raise FacecapError(f"bad [tracking] option: {exc}") from None


def write_outputs(settings, result, info):
    """Write the markers CSV (and the confidence CSV and JSON report when asked), each atomically."""
    write_markers_csv(settings["markers"], result.markers)
    confidence = result.confidence
    if confidence.ndim == 1:  # landmarks: one confidence per frame, the face's
        confidence = np.repeat(confidence[:, None], result.markers.n_markers, axis=1)
    if settings["confidence"]:
        write_weights_csv(settings["confidence"], result.markers.frames, result.markers.names, confidence)
    footage = {"path": info.path, "fps": info.fps, "width": info.width, "height": info.height,
               "scale": info.scale, "frames": [info.frames[0], info.frames[-1]], "count": info.n_frames}
    if settings["report"] and settings["method"] == "landmarks":
        write_json_atomic(settings["report"], {"facecap_track": REPORT_SCHEMA, "summary": result.summary(),
                                               **result.report(),
                                               "frame_numbering": "frame 1 is the first frame of the footage",
                                               "footage": footage, "markers": list(result.markers.names)})
    elif settings["report"]:
        write_json_atomic(settings["report"], {
            "facecap_track": REPORT_SCHEMA, "summary": result.summary(), "method": result.method,
            "reference": result.reference,
            "frame_numbering": "frame 1 is the first frame of the footage",
            "footage": footage, "markers": list(result.markers.names), "lost": result.lost,
            "reseeded": result.reseeded,
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


@contextlib.contextmanager
def showing_progress(label, *, quiet=False, unit="frame"):
    """A ``progress(done, total) -> bool`` for long work in steps: shown on stderr (:class:`FrameProgress`, unless
    ``quiet``), False once Ctrl-C was pressed (the work stops at its next step: ``Cancelled``, nothing written)."""
    shown = None if quiet else FrameProgress(label, unit=unit)
    with sigint_cancels() as stop:
        def progress(done, total):
            if shown is not None:
                shown(done, total)
            return not stop.is_set()

        try:
            yield progress
        finally:
            if shown is not None:
                shown.close()


def run_showing_progress(job, label, *, quiet=False, unit="frame"):
    """Run a :class:`~.reading.Job` with its progress shown (unless ``quiet``); Ctrl-C stops it between two frames
    with :class:`~.reading.Cancelled` (nothing written)."""
    with showing_progress(label, quiet=quiet, unit=unit) as progress:
        return job.run(progress)


DESCRIPTION = ("Track 2D markers in video footage (Lucas-Kanade points, or dense optical flow over the face) and "
               "write them as a CSV of pixel positions, with their confidence and a report if asked.")


def main(argv=None, *, parents=()):
    """``[track] --config take.toml``; returns the exit status (0 ok, 1 error, 130 cancelled).

    Ctrl-C (SIGINT) stops tracking between two frames: one line ``cancelled at frame N``, exit
    status 130, no output written. A second Ctrl-C interrupts at once.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["track"]:
        argv = argv[1:]
    parser = argparse.ArgumentParser(prog="facecap track", description=DESCRIPTION, parents=list(parents))
    parser.add_argument("--config", required=True, help="track config (.toml) with [source], [tracking], [output]")
    parser.add_argument("--overwrite", action="store_true",
                        help="let outputs replace existing files facecap did not write (default: refused)")
    if not parents:  # run on its own (python -m facecap.solvers.video.cli); the command line gives -q / -v
        parser.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
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
        shown = None if getattr(args, "quiet", False) else FrameProgress(f"track ({settings['method']})")

        def progress(done, total):
            if shown is not None:
                shown(done, total)
            return not stop.is_set()

        try:
            result = run_track(settings, progress=progress)
        finally:
            if shown is not None:
                shown.close()
    except Cancelled as exc:
        print(f"facecap: {exc}; nothing written", file=sys.stderr)
        return 130
    except FacecapError as exc:
        for line in str(exc).splitlines():  # a config's problems: one line each
            print(f"facecap: error: {' '.join(line.split())}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("facecap: interrupted", file=sys.stderr)
        return 130
    print(f"{result.summary()}; wrote {settings['markers']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
