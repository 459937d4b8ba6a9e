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
import logging
import signal
import sys
import threading
import time
import tomllib
from pathlib import Path

from ..errors import ConfigError, FacecapError
from ..io.csv import write_markers_csv, write_weights_csv
from ..io.files import write_json_atomic
from .flow import track_with_flow_job
from .reading import Cancelled, Footage
from .tracking import track_points_job
from .flow_config import frame_number_error

try:
    from tqdm import tqdm
except ImportError:  # a Blender without the pip dependencies: plain progress lines
    tqdm = None

log = logging.getLogger(__name__)

#: Every key of a track config: {section: {key: (default, what it means)}} (``facecap config-docs`` writes
#: it into docs/config.md; the config is checked against it).
TRACK_KEYS = {
    "source": {
        "video": ("", "Video file, image folder, glob or printf pattern. **Required.**"),
        "first": ("the first frame", "First footage frame read (frame 1 is the first of the footage)"),
        "last": ("the last frame", "Last footage frame read"),
        "step": ("1", "Read every n-th frame"),
        "scale": ("1", "Downscale factor in (0, 1] before tracking"),
        "fps": ("the video's (image sequences: 24)", "Frame rate"),
        "frame_offset": ("", "Removed: frames count from 1 (an error that says so)"),
    },
    "tracking": {
        "points": ("", "`name,x,y` file of the points at the reference frame (source pixels); or `region`"),
        "region": ("", "[x, y, w, h] in source pixels: automatic features in this box; or `points`"),
        "method": ("`lk`", "`lk` (Lucas-Kanade points), or dense flow: `dis`, `farneback`, `tvl1`"),
        "reference": ("the first frame read", "The neutral frame the points are given at"),
        "max_points": ("100", "`region`: the most features found"),
        "reregister": ("`true`", "`lk`: drift control by re-registration to the reference"),
        "reseed": ("`true`", "`lk`: re-acquire lost points from the reference patch"),
        "win_size": ("21", "`lk`: window size (working pixels)"),
        "levels": ("3", "`lk`: pyramid levels"),
        "fb_threshold": ("1", "`lk`: forward-backward error (working pixels) above which a point is lost"),
        "drift": ("`fuse`", "Dense flow: `fuse` (chained and direct), `direct` (to the reference) or `none`"),
        "preset": ("`balanced`", "`dis`: `ultrafast`, `fast` or `balanced` (speed against quality)"),
    },
    "output": {
        "markers": ("", "The 2D tracks: `frame,<name>_x,<name>_y` in pixels (origin top left). **Required.**"),
        "confidence": ("", "Per-sample confidence in [0, 1]: `frame,<name>,...`"),
        "report": ("", "JSON: summary, losses, re-acquisitions, footage"),
    },
}
SCHEMA = {section: set(keys) for section, keys in TRACK_KEYS.items()}
METHODS = ("lk", "dis", "farneback", "tvl1")


def load_track_config(path):
    """Parse and check a track config; returns a dict of resolved settings."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError("config file not found", path=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read: {exc}", path=path) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"not valid TOML: {exc}", path=path) from None
    base = path.resolve().parent
    for section, keys in SCHEMA.items():
        table = data.get(section, {})
        if not isinstance(table, dict):
            raise ConfigError("must be a table", path=path, key=section)
        unknown = sorted(set(table) - keys)
        if unknown:
            raise ConfigError(f"unknown key(s) {unknown}; expected some of {sorted(keys)}", path=path, key=section)
    src, trk, out = (data.get(s, {}) for s in ("source", "tracking", "output"))
    if "video" not in src:
        raise ConfigError("missing `video` (a video file or image sequence)", path=path, key="source")
    if "markers" not in out:
        raise ConfigError("missing `markers` (the output CSV)", path=path, key="output")
    if ("points" in trk) == ("region" in trk):
        raise ConfigError("give exactly one of `points` (a name,x,y file) and `region` = [x, y, w, h]",
                          path=path, key="tracking")
    method = str(trk.get("method", "lk")).lower()
    if method not in METHODS:
        raise ConfigError(f"`method` must be one of {', '.join(METHODS)}; got {trk.get('method')!r}",
                          path=path, key="tracking")
    region = trk.get("region")
    if region is not None and (not isinstance(region, list) or len(region) != 4
                               or not all(isinstance(v, (int, float)) for v in region)):
        raise ConfigError(f"`region` must be [x, y, w, h] in pixels; got {region!r}", path=path, key="tracking")

    def resolve(value, key):
        if not isinstance(value, str) or not value:
            raise ConfigError(f"`{key}` must be a path string; got {value!r}", path=path, key=key.split(".")[0])
        p = Path(value)
        return str(p if p.is_absolute() else base / p)


    for section, key in (("source", "first"), ("source", "last"), ("source", "frame_offset"),
                         ("tracking", "reference")):
        table = src if section == "source" else trk
        if key in table and (problem := frame_number_error(f"{section}.{key}", table[key])):
            raise ConfigError(problem, path=path, key=f"{section}.{key}")
    footage = {k: src[k] for k in ("first", "last", "step", "scale", "fps") if k in src}
    options = {k: trk[k] for k in trk if k not in ("points", "region", "method", "reference")}
    lk_only, dense_only = {"reregister", "reseed", "win_size", "fb_threshold", "levels"}, {"drift", "preset"}
    wrong = sorted(set(options) & (dense_only if method == "lk" else lk_only))
    if wrong:
        raise ConfigError(f"{wrong} do not apply to method {method!r}", path=path, key="tracking")
    return {
        "video": resolve(src["video"], "source.video"),
        "footage": footage,
        "points": resolve(trk["points"], "tracking.points") if "points" in trk else None,
        "region": region,
        "method": method,
        "reference": trk.get("reference"),
        "options": options,
        "markers": resolve(out["markers"], "output.markers"),
        "confidence": resolve(out["confidence"], "output.confidence") if "confidence" in out else None,
        "report": resolve(out["report"], "output.report") if "report" in out else None,
    }


class FrameProgress:
    """Frames done of a long job: a tqdm bar (rate, ETA) on a terminal; elsewhere (a log file, CI) a plain
    ``label: done/total frames`` line after the first frame, at most every ``every`` seconds and at the
    end, through :mod:`logging` (``--quiet`` hides them).

    tqdm is a dependency of the pip package; a Blender without it (the extension zip) gets the plain lines.
    """

    def __init__(self, label, *, stream=None, every=10.0):
        self.label, self.every = label, every
        self.stream = stream if stream is not None else sys.stderr
        self.last, self.start = time.monotonic(), time.monotonic()
        self.bar = None
        self.use_bar = tqdm is not None and getattr(self.stream, "isatty", lambda: False)()

    def __call__(self, done, total):
        if self.use_bar:
            if self.bar is None:
                self.bar = tqdm(total=total, desc=self.label, unit="frame", file=self.stream, dynamic_ncols=True,
                                leave=True)
            self.bar.update(done - self.bar.n)
            return True
        now = time.monotonic()
        if done in (1, total) or now - self.last >= self.every:
            self.last = now
            rate = done / max(now - self.start, 1e-9)
            log.info(f"{self.label}: {done}/{total} frames ({rate:.0f} frames/s)")
        return True

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None


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
            "summary": result.summary(), "method": result.method, "reference": result.reference,
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
    if not parents:  # run on its own (python -m facecap.solvers.video.cli); the command line gives -q / -v
        parser.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    args = parser.parse_args(argv)
    with sigint_cancels() as stop:
        return _main(args, stop)


def _main(args, stop):
    shown = None
    try:
        settings = load_track_config(args.config)
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
        print(f"facecap: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("facecap: interrupted", file=sys.stderr)
        return 130
    print(f"{result.summary()}; wrote {settings['markers']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
