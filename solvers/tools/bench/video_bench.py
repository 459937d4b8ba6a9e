"""Video benchmarks: ``python -m facecap.solvers.tools.bench.video_bench [--frames N]``.

* LK tracking of 100 points on 1280x720 (goal >= 60 frames/s): the tracker alone on decoded
  frames, with and without re-registration, and end to end from an FFV1 video file (decode included).
* DIS dense flow at 640x480 (goal >= 30 frames/s): one DIS call per frame, and the drift-controlled
  reference flow (two DIS calls plus the fusion) per frame.
Every row is the median frames/s over ``repeats`` interleaved runs (the reference machine has 2
shared cores, so single runs are noisy); figures are printed, not asserted.
"""

import argparse
import os
import sys
import tempfile
import time

import numpy as np

from ...video.flow import FlowEstimator, ReferenceFlow
from ...video.reading import Footage, opencv, write_video
from ...video.synthetic import face_texture, make_motion, render
from ...video.tracking import LKTracker, auto_seeds, track_points


def _frames(n, w, h, seed=0):
    tex = face_texture(w, h, seed=seed)
    motion = make_motion(n, w, h, seed=seed, amplitude=3.0 * w / 320, shift=6.0 * w / 320)
    return np.stack([render(tex, motion, t, noise=2.0) for t in range(n)])


def _rate(n, seconds):
    return n / max(seconds, 1e-9)


def _medians(runs, repeats):
    """``runs``: [(name, callable() -> frames done)]; median frames/s of each over interleaved repeats."""
    rates = {name: [] for name, _ in runs}
    for _ in range(max(int(repeats), 1)):
        for name, run in runs:
            t0 = time.perf_counter()
            n = run()
            rates[name].append(_rate(n, time.perf_counter() - t0))
    return [(name, float(np.median(rates[name]))) for name, _ in runs]


def bench_tracking(n_frames=120, width=1280, height=720, n_points=100, repeats=3):
    """Frames/s (medians) of 100-point LK tracking at 1280x720; returns a list of (name, frames/s)."""
    imgs = _frames(n_frames, width, height)
    names, pts = auto_seeds(imgs[0], [width * 0.2, height * 0.1, width * 0.6, height * 0.8], max_points=n_points)

    def tracker(rereg):
        def run():
            tr = LKTracker(imgs[0], pts, reregister=rereg)
            for img in imgs[1:]:
                tr.step(img)
            return n_frames - 1
        return run

    runs = [("LK 1280x720, %d pts, re-registration (4 LK calls/frame)" % len(pts), tracker(True)),
            ("LK 1280x720, %d pts, continuous only (2 LK calls/frame)" % len(pts), tracker(False))]
    with tempfile.TemporaryDirectory() as d:
        for ext, codec in (("avi", "FFV1 (lossless)"), ("mp4", "mp4v (MPEG-4 part 2)")):
            path = os.path.join(d, "bench." + ext)
            write_video(path, imgs)
            runs.append((f"decode + gray only, {codec} 1280x720", lambda p=path: sum(1 for _ in Footage(p))))
            runs.append((f"LK 1280x720 end to end from {codec} (decode + gray + track)",
                         lambda p=path: track_points(Footage(p), points=pts, names=names).markers.n_frames))
        return _medians(runs, repeats)


def bench_flow(n_frames=60, width=640, height=480, repeats=3):
    """Frames/s (medians) of DIS flow at 640x480; returns a list of (name, frames/s)."""
    imgs = _frames(n_frames, width, height, seed=1)
    runs = []
    for preset in ("balanced", "medium", "fast"):
        est = FlowEstimator("dis", preset=preset)

        def one(est=est):
            for img in imgs[1:]:
                est.calc(imgs[0], img)
            return n_frames - 1
        runs.append((f"DIS ({preset}) 640x480, one flow per frame", one))
    for preset in ("balanced", "fast"):
        def fused(preset=preset):
            rf = ReferenceFlow(imgs[0], drift="fuse", preset=preset)
            for img in imgs[1:]:
                rf.step(img)
            return n_frames - 1
        runs.append((f"DIS ({preset}) 640x480, reference flow with drift fusion (2 flows/frame)", fused))
    return _medians(runs, repeats)


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m facecap.solvers.tools.bench.video_bench")
    parser.add_argument("--frames", type=int, default=120, help="frames per tracking run (default 120)")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved runs per row; medians (default 3)")
    args = parser.parse_args(argv)
    cv2 = opencv()
    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads, {os.cpu_count()} CPUs", flush=True)
    for name, fps in bench_tracking(args.frames, repeats=args.repeats):
        print(f"{name}: {fps:.0f} frames/s median (goal >= 60)", flush=True)
    for name, fps in bench_flow(max(args.frames // 2, 10), repeats=args.repeats):
        print(f"{name}: {fps:.0f} frames/s median (goal >= 30)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
