"""Footage the project's scenario generator does not make, for judging the LK tracker on kinds nobody tuned it
on (``tests/core/test_tracker_outside.py``, and the benchmark below).

Written apart from ``synthetic/scenarios_footage.py`` on purpose (its textures, warps and motion are not used):
an image (multi-octave value noise with a 1/f spectrum, or a real photograph: a studio-light panorama that
ships in the ``bpy`` wheel), a smooth random warp of the whole frame (a few low-frequency sine modes that
rise and fall in time), a similarity head motion (rotation, zoom and shift, sinusoids) and a real codec
(MJPG at a chosen quality, or lossless FFV1). Point p of the first frame is at ``S_t(p + W_t(p))`` in frame t.

``python -m facecap.solvers.tools.bench.outside_footage`` prints the tracker beside the plain LK on every kind
(960x720, 120 frames, 3 clips each; ``--size``, ``--frames``, ``--clips``).

:data:`KINDS` are the kinds; a clip is drawn from a seed (:func:`outside_clip`).
"""

import argparse
import importlib.util
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...video.tracking import track_points
from .reference_trackers import plain_lk

#: kind -> texture, codec, JPEG quality, warp amplitude (pixels at 960x720), similarity amplitudes
#: (degrees, zoom fraction, shift as a fraction of the width)
KINDS = {
    "octaves_warp_mjpg": dict(texture="octaves", codec="MJPG", quality=75, warp=6.0, motion=(3.0, 0.04, 0.02)),
    "photo_warp_mjpg": dict(texture="photo", codec="MJPG", quality=75, warp=6.0, motion=(3.0, 0.04, 0.02)),
    "octaves_strong_warp_mjpg": dict(texture="octaves", codec="MJPG", quality=60, warp=12.0,
                                     motion=(5.0, 0.06, 0.03)),
    # the stress kind without the codec: what a lower LK eigenvalue floor must not spoil where the detail is intact
    "octaves_strong_warp_ffv1": dict(texture="octaves", codec="FFV1", quality=None, warp=12.0,
                                     motion=(5.0, 0.06, 0.03)),
}


def octaves_image(width, height, rng):
    """Grey image: value noise summed over octaves with amplitude proportional to the cell size (1/f)."""
    import cv2  # OpenCV: imported on first use

    img = np.zeros((height, width), np.float32)
    cell = max(width, height) / 2.0
    while cell >= 2.0:
        gw, gh = int(np.ceil(width / cell)) + 2, int(np.ceil(height / cell)) + 2
        grid = rng.standard_normal((gh, gw)).astype(np.float32)
        up = cv2.resize(grid, (int(gw * cell), int(gh * cell)), interpolation=cv2.INTER_CUBIC)
        img += up[:height, :width] * cell
        cell /= 2.0
    img = (img - img.mean()) / img.std()
    return np.clip(128 + 45 * img, 0, 255).astype(np.uint8)


def photographs():
    """The studio-light panoramas the bpy wheel ships (sorted), or [] where bpy is not installed."""
    spec = importlib.util.find_spec("bpy")
    if not (spec and spec.origin):
        return []
    return sorted(Path(spec.origin).parent.glob("*/datafiles/studiolights/world/*.exr"))


def photo_image(width, height, rng):
    """A crop of one of the panoramas in the bpy wheel (studio lights), grey, 8-bit. Without them the photo kinds
    cannot be made (another texture would be another kind): RuntimeError."""
    import cv2  # OpenCV: imported on first use

    files = photographs()
    if not files:
        raise RuntimeError("the photo kinds crop a studio-light panorama of the bpy wheel: install bpy (the "
                           "[blender] extra) or leave them out")
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
    hdr = cv2.imread(str(files[int(rng.integers(len(files)))]), cv2.IMREAD_ANYCOLOR | cv2.IMREAD_ANYDEPTH)
    if hdr is None:
        raise RuntimeError(f"OpenCV could not read the panorama {files[0].parent} (OpenEXR support)")
    grey = cv2.cvtColor(hdr.astype(np.float32), cv2.COLOR_BGR2GRAY)
    h, w = grey.shape
    crop = grey[h // 4: h // 4 + h // 2, :]
    crop = cv2.resize(crop, (width, height), interpolation=cv2.INTER_AREA)
    tone = crop / (1.0 + crop)  # a plain tone map: the sky does not wash out the rest
    lo, hi = np.percentile(tone, [1, 99])
    return np.clip(255 * (tone - lo) / max(hi - lo, 1e-6), 0, 255).astype(np.uint8)


@dataclass(frozen=True, eq=False)
class Motion:
    """The warp's sine modes and the similarity's sinusoids of one clip (pixels of the clip)."""

    freq: np.ndarray  # (K, 2) spatial frequencies, radians per pixel
    phase: np.ndarray  # (K,)
    amp: np.ndarray  # (K, 2) displacement amplitudes
    period: np.ndarray  # (K,) frames
    sim: np.ndarray  # (4, 3): angle, log zoom, tx, ty x (amplitude, period, phase)
    size: tuple

    def warp(self, t, p):
        s = np.sin(p @ self.freq.T + self.phase) * np.sin(np.pi * t / self.period) ** 2  # (..., K)
        return p + s @ self.amp

    def similarity(self, t):
        a, z, tx, ty = (amp * np.sin(2 * np.pi * t / per + ph) - amp * np.sin(ph) for amp, per, ph in self.sim)
        c, s = np.exp(z) * np.cos(a), np.exp(z) * np.sin(a)
        w, h = self.size
        centre = np.array([w / 2, h / 2])
        A = np.array([[c, -s], [s, c]])
        return A, centre - A @ centre + [tx, ty]

    def forward(self, t, p):
        A, b = self.similarity(t)
        return self.warp(t, p) @ A.T + b

    def inverse(self, t, x, iterations=10):
        A, b = self.similarity(t)
        q = (x - b) @ np.linalg.inv(A).T
        p = q.copy()
        for _ in range(iterations):  # p + W(p) = q, by fixed-point iteration (the warp is small and smooth)
            p = q - (self.warp(t, p) - p)
        return p


def draw_motion(kind, size, rng):
    spec = KINDS[kind]
    w, h = size
    k = 4
    scale = w / 960.0
    freq = rng.normal(size=(k, 2)) * (2 * np.pi / (0.6 * w))
    amp = rng.normal(size=(k, 2)) * spec["warp"] * scale / np.sqrt(k)
    deg, zoom, shift = spec["motion"]
    sim = np.array([[np.radians(deg), rng.uniform(60, 120), rng.uniform(0, 6.3)],
                    [zoom, rng.uniform(60, 120), rng.uniform(0, 6.3)],
                    [shift * w, rng.uniform(60, 120), rng.uniform(0, 6.3)],
                    [shift * w, rng.uniform(60, 120), rng.uniform(0, 6.3)]])
    return Motion(freq, rng.uniform(0, 2 * np.pi, k), amp, rng.uniform(40, 90, k), sim, size)


@dataclass(frozen=True, eq=False)
class OutsideClip:
    path: Path
    seeds: np.ndarray  # (M, 2) first-frame positions (pixels)
    truth: np.ndarray  # (F, M, 2)


def outside_clip(path, kind, *, seed=0, size=(960, 720), frames=120, points=48, fps=30.0):
    """Write a clip of ``kind`` to ``path`` (.avi for MJPG, .mkv for FFV1) and return it with its truth."""
    import cv2  # OpenCV: imported on first use

    spec = KINDS[kind]
    rng = np.random.default_rng([seed, list(KINDS).index(kind)])
    w, h = size
    image = (photo_image if spec["texture"] == "photo" else octaves_image)(w, h, rng).astype(np.float32)
    motion = draw_motion(kind, size, rng)
    fourcc = cv2.VideoWriter_fourcc(*("MJPG" if spec["codec"] == "MJPG" else "FFV1"))
    writer = cv2.VideoWriter(str(path), fourcc, fps, (w, h), isColor=False)
    if spec["codec"] == "MJPG":
        writer.set(cv2.VIDEOWRITER_PROP_QUALITY, spec["quality"])
    step = 4  # the inverse map on a coarse grid (within 0.003 px of the exact one at 960x720), interpolated: the warp is smooth and the similarity linear
    ys, xs = np.mgrid[0:h + step:step, 0:w + step:step].astype(np.float64)
    grid = np.stack([xs, ys], -1)
    qy, qx = (np.mgrid[0:h, 0:w] / step).astype(np.float32)  # each pixel's place on the coarse grid
    try:
        for t in range(frames):
            coarse = motion.inverse(t, grid).astype(np.float32)
            src = cv2.remap(coarse, qx, qy, cv2.INTER_LINEAR)
            frame = cv2.remap(image, src[..., 0], src[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
            writer.write(np.clip(frame, 0, 255).astype(np.uint8))
    finally:
        writer.release()
    first = image.astype(np.uint8)
    margin = int(0.2 * min(w, h))
    mask = np.zeros((h, w), np.uint8)
    mask[margin: h - margin, margin: w - margin] = 255
    seeds = cv2.goodFeaturesToTrack(first, points, 0.01, 0.5 * np.sqrt((w - 2 * margin) * (h - 2 * margin) / points),
                                    mask=mask, blockSize=7).reshape(-1, 2).astype(np.float64)
    truth = np.stack([motion.forward(t, seeds) for t in range(frames)])
    return OutsideClip(Path(path), seeds, truth)


def bench_outside(*, kinds=tuple(KINDS), seeds=(0, 1, 2), size=(960, 720), frames=120, log=print):
    """The tracker beside the plain LK on every outside kind: one line per clip, then the medians per kind."""
    def score(pos, truth):
        err = np.linalg.norm(pos - truth, axis=2)[1:]
        lost = np.isnan(err)
        return float(np.median(np.where(lost, np.inf, err))), 100.0 * float(lost.mean())

    if not photographs():
        left = [k for k in kinds if KINDS[k]["texture"] == "photo"]
        if left:
            log(f"left out (they need the bpy wheel's photographs): {', '.join(left)}")
        kinds = tuple(k for k in kinds if k not in left)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for kind in kinds:
            for seed in seeds:
                suffix = ".avi" if KINDS[kind]["codec"] == "MJPG" else ".mkv"
                clip = outside_clip(Path(d) / f"{kind}-{seed}{suffix}", kind, seed=seed, size=size, frames=frames)
                ours = score(track_points(str(clip.path), points=clip.seeds).markers.positions, clip.truth)
                plain = score(plain_lk(clip.path, clip.seeds), clip.truth)
                rows.append((kind, seed, ours, plain))
                log(f"{kind} clip {seed}: ours {ours[0]:.3f} px, {ours[1]:.2f} % lost; plain LK {plain[0]:.3f} px, "
                    f"{plain[1]:.2f} % lost")
    for kind in kinds:
        k = [r for r in rows if r[0] == kind]
        log(f"{kind}: median ours {np.median([r[2][0] for r in k]):.3f} px, plain {np.median([r[3][0] for r in k]):.3f}"
            f" px; lost ours {np.mean([r[2][1] for r in k]):.2f} %, plain {np.mean([r[3][1] for r in k]):.2f} %")
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m facecap.solvers.tools.bench.outside_footage",
                                     description="The LK tracker beside the plain LK on footage from outside the "
                                                 "project's scenario generator.")
    parser.add_argument("--size", default="960x720", help="resolution (default 960x720)")
    parser.add_argument("--frames", type=int, default=120, help="frames per clip (default 120)")
    parser.add_argument("--clips", type=int, default=3, help="clips per kind (default 3)")
    args = parser.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))
    bench_outside(seeds=tuple(range(args.clips)), size=(w, h), frames=args.frames)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
