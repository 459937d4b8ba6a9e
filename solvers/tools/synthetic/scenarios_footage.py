"""Seeded random face footage with exact ground truth, for tracking and flow tests and benchmarks.

A textured reference image R (``texture``: ``"rich"`` band-limited texture, ``"medium"``, ``"skin"``
with faint pores and a few features, ``"dots"``: skin with painted mocap dots; and two that are not
made by the project's face texture at all: ``"natural"``, a dead-leaves image (overlapping discs of
power-law sizes with their own grain: the edges and 1/f statistics of natural images), and
``"photo"``, a real photograph) is deformed per frame
by a smooth non-rigid field D_t (bumps at mouth, brows, cheeks) and a head motion H_t (a
similarity, or a homography for ``"perspective"`` motion): reference point p is at
``H_t(p + D_t(p))`` in frame t. Frames are rendered by inverting that map, optionally with lighting
drift (a moving gain gradient and offset), motion blur (sub-frame renders averaged over the
shutter), a rolling shutter (each row exposed at its own time), low light (a dim exposure with shot
and read noise, amplified back), sensor noise, an occluder crossing the face and head motion that
takes part of the face out of the frame; then written with a real codec: lossless FFV1, MJPG at a
chosen quality, mp4 (MPEG-4 part 2 at OpenCV's fixed rate control) or VP8.

:data:`KINDS` names the footage kinds the tests and the accuracy benchmark compare trackers on;
:func:`footage_scenario` draws one clip of a kind (resolution, motion, texture seed) from a seed.
Frame numbers follow the project's convention: frame 1 is the first frame of the clip.
"""

import importlib.util
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...video.synthetic import face_texture


def _cv2():
    import cv2  # deferred: OpenCV is only needed to render and write footage

    return cv2

#: Footage kinds: texture, head motion, codec (quality for MJPG), lighting drift, blur (shutter as a
#: fraction of the frame interval), occluder, points leaving the frame, sensor noise (grey levels).
KINDS = {
    "rich_lossless": dict(texture="rich", head="similarity", codec="lossless"),
    "rich_mjpg": dict(texture="rich", head="similarity", codec="MJPG", quality=75),
    "medium_mp4": dict(texture="medium", head="similarity", codec="mp4"),
    "skin_mjpg_low": dict(texture="skin", head="similarity", codec="MJPG", quality=35),
    "skin_perspective": dict(texture="skin", head="perspective", codec="MJPG", quality=85),
    "dots_mp4": dict(texture="dots", head="perspective", codec="mp4"),
    "lighting_drift": dict(texture="medium", head="similarity", codec="MJPG", quality=80, lighting=0.3),
    "motion_blur": dict(texture="rich", head="perspective", codec="lossless", blur=0.8, speed=2.0),
    "occluded": dict(texture="rich", head="similarity", codec="MJPG", quality=80, occluder=True),
    "leaving_frame": dict(texture="medium", head="similarity", codec="lossless", leave=True),
    # Footage the face generator does not make. "natural_mjpg" is the clip the tracker was found worse
    # than the plain LK on (960x720, 300 frames, 48 points in the benchmark; the whole image warps); the
    # two after it were fixed before any tuning and kept out of it, so they say how the tracker does on
    # footage nobody tuned for: real photographs under perspective motion in VP8, and a dim, noisy
    # rolling-shutter clip.
    "natural_mjpg": dict(texture="natural", head="similarity", codec="MJPG", quality=75, field=True),
    "photo_perspective_vp8": dict(texture="photo", head="perspective", codec="vp8"),
    "lowlight_rolling": dict(texture="natural", head="similarity", codec="MJPG", quality=60, lowlight=0.3,
                             readout=0.6),
}
# A kind's draws are seeded by its place here: the first ten sorted as before, new kinds after them, so
# adding a kind never changes another kind's clips.
_SEED_ORDER = tuple(sorted(list(KINDS)[:10])) + tuple(list(KINDS)[10:])
#: The kinds that were not tuned on (decided before any change to the tracker for them).
UNTUNED = ("photo_perspective_vp8", "lowlight_rolling")
SIZES = ((640, 480), (960, 720), (1280, 720), (1920, 1080))


@dataclass(frozen=True, eq=False)
class HeadMotion:
    """Continuous-time motion of a rendered face (all lengths in pixels of the clip).

    ``D_t(p) = sum_k a_k(t) g_k(p) d_k`` with Gaussian bumps g_k; ``H_t`` a homography from
    rotation, log-scale, shift and two perspective terms (all sinusoids of t, zero at t = 0).
    """

    centres: np.ndarray  # (K, 2)
    radii: np.ndarray  # (K,)
    directions: np.ndarray  # (K, 2) unit
    amplitudes: np.ndarray  # (K,) peak bump displacement
    periods: np.ndarray  # (K,) frames
    head: np.ndarray  # (6, 3): rows angle, log-scale, tx, ty, px, py; columns amplitude, period, phase
    size: tuple  # (width, height)

    def bump_amplitudes(self, t):
        return self.amplitudes * 0.5 * (1.0 - np.cos(2 * np.pi * t / self.periods))

    def homography(self, t):
        amp, period, phase = self.head.T
        a, ls, tx, ty, px, py = amp * (np.sin(2 * np.pi * t / period + phase) - np.sin(phase))
        w, h = self.size
        c, s = np.exp(ls) * np.cos(a), np.exp(ls) * np.sin(a)
        centre = np.array([[1, 0, w / 2], [0, 1, h / 2], [0, 0, 1.0]])
        sim = np.array([[c, -s, tx], [s, c, ty], [0, 0, 1.0]])
        persp = np.array([[1, 0, 0], [0, 1, 0], [px / w, py / h, 1.0]])
        return centre @ sim @ persp @ np.linalg.inv(centre)

    def local(self, t, pts):
        d = pts[..., None, :] - self.centres
        g = np.exp(-0.5 * np.sum(d * d, axis=-1) / self.radii**2)
        return g @ (self.bump_amplitudes(t)[:, None] * self.directions)

    def local_grid(self, t):
        w, h = self.size
        x, y = np.arange(w, dtype=float), np.arange(h, dtype=float)
        out = np.zeros((h, w, 2))
        for k, a in enumerate(self.bump_amplitudes(t)):
            g = np.outer(np.exp(-0.5 * (y - self.centres[k, 1]) ** 2 / self.radii[k] ** 2),
                         np.exp(-0.5 * (x - self.centres[k, 0]) ** 2 / self.radii[k] ** 2)) * a
            out[..., 0] += g * self.directions[k, 0]
            out[..., 1] += g * self.directions[k, 1]
        return out.astype(np.float32)

    def forward(self, t, pts):
        """Where reference points ``pts`` (..., 2) appear at time t (frame index from 0)."""
        q = pts + self.local(t, pts)
        return _apply_h(self.homography(t), q)

    def inverse(self, t, x, iterations=12):
        """Reference points that land on ``x`` (..., 2) at time t (fixed-point inversion)."""
        q = _apply_h(np.linalg.inv(self.homography(t)), x)
        p = q.copy()
        for _ in range(iterations):
            p = q - self.local(t, p)
        return p

    def flow(self, t):
        """True flow of time t relative to frame 0 on the reference grid (H, W, 2)."""
        w, h = self.size
        grid = np.stack(np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float)), axis=-1)
        return self.forward(t, grid) - grid


def _apply_h(H, pts):
    p = np.asarray(pts, dtype=np.float64)
    x = p @ H[:2, :2].T + H[:2, 2]
    z = p @ H[2, :2] + H[2, 2]
    return x / z[..., None]


def random_motion(rng, size, *, head="similarity", speed=1.0, leave=False, warp=1.0, field=False):
    """A random :class:`HeadMotion` for a ``size`` = (width, height) clip: bumps at mouth, brows,
    cheeks, or with ``field`` a smooth random warp of the whole frame (wide overlapping bumps on a grid)."""
    w, h = size
    s = min(w, h)
    cx, cy = w / 2, h / 2
    if field:
        gx, gy = np.meshgrid(np.linspace(0.15, 0.85, 4) * w, np.linspace(0.15, 0.85, 4) * h)
        centres = np.column_stack([gx.ravel(), gy.ravel()]) + rng.normal(0, 0.03 * s, size=(16, 2))
        radii = 0.22 * s * rng.uniform(0.8, 1.2, size=16)
        directions = rng.normal(size=(16, 2))
    else:
        centres = np.array([[cx, cy + 0.3 * s], [cx - 0.12 * s, cy + 0.22 * s], [cx + 0.12 * s, cy + 0.22 * s],
                            [cx - 0.14 * s, cy - 0.2 * s], [cx + 0.14 * s, cy - 0.2 * s], [cx, cy + 0.05 * s]])
        centres += rng.normal(0, 0.02 * s, size=centres.shape)
        radii = np.array([0.16, 0.08, 0.08, 0.09, 0.09, 0.12]) * s * rng.uniform(0.8, 1.2, size=6)
        directions = rng.normal(size=(6, 2)) + np.array([[0, 1], [-0.7, -0.7], [0.7, -0.7], [0, -1], [0, -1], [0, 0.5]])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    k = len(centres)
    amplitudes = rng.uniform(0.01, 0.04, size=k) * s * warp  # 5-19 px at 480 lines (warp = 1)
    periods = rng.uniform(25, 60, size=k) / speed
    rot, scale, shift = np.radians(rng.uniform(1.0, 4.0)), rng.uniform(0.01, 0.04), rng.uniform(0.01, 0.03) * s
    persp = rng.uniform(0.02, 0.06) if head == "perspective" else 0.0
    if leave:
        shift = 0.25 * s
    amps = np.array([rot, scale, shift, 0.6 * shift, persp, 0.7 * persp])
    head_params = np.column_stack([amps, rng.uniform(40, 90, size=6) / speed, rng.uniform(0, 2 * np.pi, size=6)])
    return HeadMotion(centres, radii, directions, amplitudes, periods, head_params, (int(w), int(h)))


def texture(kind, size, rng):
    """Reference image (float32, 0..255) of a texture ``kind`` ("rich", "medium", "skin", "dots",
    "natural", "photo")."""
    cv2 = _cv2()
    w, h = size
    if kind == "natural":
        return dead_leaves(size, rng)
    if kind == "photo":
        return photograph(size, rng)
    seed = int(rng.integers(1 << 30))
    base = face_texture(w, h, seed=seed)
    if kind == "rich":
        return base
    smooth = cv2.GaussianBlur(base, (0, 0), 0.04 * min(w, h))  # shading and features without fine texture
    if kind == "medium":
        return np.clip(smooth + 0.45 * (base - smooth), 0, 255).astype(np.float32)
    k = min(w, h) / 480.0
    pores = cv2.GaussianBlur(rng.normal(size=(h, w)).astype(np.float32), (0, 0), 1.2 * k)
    pores *= 4.0 / (pores.std() + 1e-9)
    img = smooth + 0.15 * (base - smooth) + pores
    if kind == "dots":
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        for _ in range(int(rng.integers(60, 150))):
            x, y = rng.normal([w / 2, h / 2], [0.17 * w, 0.25 * h])
            r = rng.uniform(2.0, 3.5) * k
            img -= 70.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * r * r))
    elif kind != "skin":
        raise ValueError(f"unknown texture kind {kind!r}")
    return np.clip(img, 0, 255).astype(np.float32)


def dead_leaves(size, rng):
    """A dead-leaves image: opaque discs of power-law radii (density ~ 1/r^3, scale invariant like
    natural images), each with its own grey level, painted until about 95 % of
    the image is covered, then a fine grain (float32, 0..255)."""
    cv2 = _cv2()
    w, h = size
    s = min(w, h)
    r_min, r_max = 0.006 * s, 0.25 * s
    mean_area = np.pi * 2 * r_min**2 * np.log(r_max / r_min) / (1 - (r_min / r_max) ** 2)
    a, b = r_min**-2, r_max**-2
    radii = (a - rng.uniform(size=int(3 * w * h / mean_area)) * (a - b)) ** -0.5  # inverse CDF of r^-3
    img = np.full((h, w), 128.0, np.float32)
    for r in radii:  # back to front: a later disc hides what it covers
        cx, cy = rng.uniform(-r, w + r), rng.uniform(-r, h + r)
        x0, x1 = int(max(cx - r, 0)), int(min(cx + r + 1, w))
        y0, y1 = int(max(cy - r, 0)), int(min(cy + r + 1, h))
        if x0 >= x1 or y0 >= y1:
            continue
        yy, xx = np.ogrid[y0:y1, x0:x1]
        img[y0:y1, x0:x1][(xx - cx) ** 2 + (yy - cy) ** 2 <= r * r] = rng.uniform(30, 225)
    grain = cv2.GaussianBlur(rng.normal(size=(h, w)).astype(np.float32), (0, 0), s / 480)
    img += grain * 6.0 / (grain.std() + 1e-9)
    return np.clip(cv2.GaussianBlur(img, (0, 0), 0.6), 0, 255).astype(np.float32)


def photograph_files():
    """Real photographs to texture footage with: the CC0 studio-light panoramas that ship in the bpy
    wheel (Poly Haven; forest, city, courtyard, interior, ...), found without importing bpy."""
    spec = importlib.util.find_spec("bpy")
    roots = list(spec.submodule_search_locations or []) if spec else []
    files = sorted(f for r in roots for f in Path(r).glob("*/datafiles/studiolights/world/*.exr"))
    if not files:
        raise FileNotFoundError("the \"photo\" footage texture needs the photographs in the bpy wheel "
                                "(pip install bpy); none found")
    return files


def photograph(size, rng):
    """A crop of a real photograph (one of :func:`photograph_files`, tone-mapped to grey levels) filling
    ``size`` (float32, 0..255)."""
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")  # OpenCV reads EXR only when asked to
    cv2 = _cv2()
    files = photograph_files()
    hdr = cv2.imread(str(files[int(rng.integers(len(files)))]), cv2.IMREAD_UNCHANGED)
    if hdr is None:
        raise RuntimeError("this OpenCV build cannot read OpenEXR photographs")
    lum = hdr[..., :3].astype(np.float32) @ np.float32([0.0722, 0.7152, 0.2126])  # BGR
    lum = 0.25 * lum / (np.median(lum) + 1e-6)  # the median grey about mid-grey
    grey = 255.0 * (lum / (1.0 + lum)) ** (1 / 2.2)  # Reinhard, then display gamma
    w, h = size
    H, W = grey.shape
    ch = int(H * rng.uniform(0.6, 0.9))  # the lower part of the panorama holds the detail
    cw = min(W, int(ch * w / h))
    y0, x0 = int(rng.integers(H - ch + 1)), int(rng.integers(W - cw + 1))
    crop = grey[y0: y0 + ch, x0: x0 + cw]
    return np.clip(cv2.resize(crop, (w, h), interpolation=cv2.INTER_CUBIC), 0, 255).astype(np.float32)


@dataclass(frozen=True, eq=False)
class Occluder:
    """An ellipse of flat texture crossing the face from frame index ``start`` to ``stop``."""

    start: int
    stop: int
    path: np.ndarray  # (2, 2) centre at start and at stop
    axes: np.ndarray  # (2,) semi-axes

    def centre(self, t):
        u = np.clip((t - self.start) / max(self.stop - self.start, 1), 0, 1)
        return (1 - u) * self.path[0] + u * self.path[1]

    def covers(self, t, pts, margin=0.0):
        if not self.start <= t <= self.stop:
            return np.zeros(pts.shape[:-1], dtype=bool)
        d = (pts - self.centre(t)) / (self.axes + margin)
        return np.sum(d * d, axis=-1) <= 1.0


def _source_map(motion, t, grid, readout):
    """Reference positions imaged at each pixel of ``grid`` (H, W, 2) at time t; with a rolling
    shutter (``readout`` > 0, the frame intervals one readout takes) row y is exposed at
    ``row_time(t, y)``: maps at a few instants across the readout, interpolated per row."""
    cv2 = _cv2()
    h = grid.shape[0]
    times = [t] if readout <= 0 else row_time(t, np.linspace(0, h - 1, 7), h, readout)
    maps = []
    for tt in times:
        q = _apply_h(np.linalg.inv(motion.homography(tt)), grid).astype(np.float32)
        local = motion.local_grid(tt)
        p = q.copy()
        for _ in range(10):
            p = q - cv2.remap(local, p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        maps.append(p)
    if len(maps) == 1:
        return maps[0]
    u = np.linspace(0, len(maps) - 1, h, dtype=np.float32)  # each row between two of the instants
    k = np.minimum(u.astype(int), len(maps) - 2)
    f = (u - k)[:, None, None]
    stack = np.stack(maps)
    rows = np.arange(h)
    return ((1 - f) * stack[k, rows] + f * stack[k + 1, rows]).astype(np.float32)


def row_time(t, y, height, readout):
    """Exposure time of image row ``y`` of frame time t under a rolling shutter (mid-frame at t)."""
    return t + readout * (np.asarray(y, dtype=np.float64) / max(height - 1, 1) - 0.5)


def render(tex, motion, t, *, lighting=0.0, blur=0.0, noise=1.5, occluder=None, rng=None, sub=5, readout=0.0,
           lowlight=0.0):
    """Frame at time t as uint8 (sub-frame renders over the shutter when ``blur`` > 0; a rolling
    shutter over ``readout`` frame intervals; ``lowlight``: the exposure as a fraction of a normal one,
    with shot and read noise at that level, amplified back)."""
    cv2 = _cv2()
    h, w = tex.shape
    times = [t] if blur <= 0 else t + blur * (np.arange(sub) / (sub - 1) - 0.5)
    grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)), axis=-1)
    acc = np.zeros((h, w), np.float32)
    for tt in times:
        p = _source_map(motion, tt, grid, readout)
        acc += cv2.remap(tex, p[..., 0], p[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    img = acc / len(times)
    if lighting:
        phase = 2 * np.pi * t / 90.0
        gx = (grid[..., 0] / w - 0.5) * np.sin(phase) + (grid[..., 1] / h - 0.5) * np.cos(1.3 * phase)
        img = img * (1.0 + lighting * (0.5 * np.sin(0.7 * phase) + gx)) + 20.0 * lighting * np.sin(phase)
    if occluder is not None and occluder.start <= t <= occluder.stop:
        inside = occluder.covers(t, grid.astype(np.float64))
        img[inside] = 150.0 + 10.0 * np.sin(grid[inside][:, 0] / 9.0)
    rng = rng or np.random.default_rng(int(t * 1000))
    if lowlight:  # a dim exposure: shot noise (variance ~ signal) and read noise, quantised, then gain
        dim = np.clip(img, 0, 255) * lowlight
        dim = np.round(dim + rng.normal(size=img.shape) * np.sqrt(0.5 * dim + 4.0))
        img = dim / lowlight
    if noise:
        img = img + rng.normal(scale=noise, size=img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def write_clip(path, frames, *, codec="lossless", quality=75, fps=30.0):
    """Write uint8 grayscale ``frames`` (F, H, W) with ``codec``; returns the path written."""
    cv2 = _cv2()
    path = Path(path)
    h, w = frames.shape[1:]
    if codec == "MJPG":  # OpenCV's own MJPEG writer honours the JPEG quality (FFmpeg's ignores it)
        path = path.with_suffix(".avi")
        writer = cv2.VideoWriter(str(path), cv2.CAP_OPENCV_MJPEG, cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h), True)
        writer.set(cv2.VIDEOWRITER_PROP_QUALITY, float(quality))
        frames = np.repeat(frames[..., None], 3, axis=3)
    elif codec == "mp4":
        path = path.with_suffix(".mp4")
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h), False)
    elif codec == "vp8":  # libvpx at OpenCV's default rate: a codec none of the other kinds use
        path = path.with_suffix(".mkv")
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"VP80"), fps, (w, h), True)
        frames = np.repeat(frames[..., None], 3, axis=3)
    elif codec == "lossless":
        path = path.with_suffix(".avi")
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), fps, (w, h), False)
    else:
        raise ValueError(f"unknown codec {codec!r}")
    if not writer.isOpened():
        raise RuntimeError(f"{path}: this OpenCV build cannot write {codec}")
    try:
        for img in frames:
            writer.write(img)
    finally:
        writer.release()
    return path


@dataclass(frozen=True, eq=False)
class FootageScenario:
    """One drawn clip: where it is, how it was made, and its ground truth."""

    path: Path
    kind: str
    seed: int
    size: tuple
    n_frames: int
    motion: HeadMotion
    texture: np.ndarray
    occluder: Occluder = None
    params: dict = field(default_factory=dict)

    def truth(self, seeds, reference=1):
        """(F, M, 2) true positions in every frame of the points at ``seeds`` (M, 2) in frame ``reference``
        (under a rolling shutter: where each point is when its row is exposed)."""
        seeds = np.asarray(seeds, dtype=np.float64)
        readout, h = self.params.get("readout", 0.0), self.size[1]
        if readout <= 0:
            ref_pts = self.motion.inverse(reference - 1, seeds)
            return np.stack([self.motion.forward(t, ref_pts) for t in range(self.n_frames)])
        times = row_time(reference - 1, seeds[:, 1], h, readout)
        ref_pts = np.stack([self.motion.inverse(tt, x) for tt, x in zip(times, seeds)])
        out = []
        for t in range(self.n_frames):
            x = self.motion.forward(t, ref_pts)
            for _ in range(6):  # the row a point is seen on sets when it is seen
                x = np.stack([self.motion.forward(tt, p) for tt, p in zip(row_time(t, x[:, 1], h, readout), ref_pts)])
            out.append(x)
        return np.stack(out)

    def hidden(self, truth, margin=0.0):
        """(F, M) samples whose point is covered by the occluder or outside the frame (``margin`` px)."""
        w, h = self.size
        out = (truth[..., 0] < margin) | (truth[..., 1] < margin) | (truth[..., 0] > w - 1 - margin) \
            | (truth[..., 1] > h - 1 - margin)
        if self.occluder is not None:
            out |= np.stack([self.occluder.covers(t, truth[t], margin) for t in range(self.n_frames)])
        return out

    def face_box(self):
        """[x, y, w, h] of the face region in the reference frame (for seeds and flow masks)."""
        w, h = self.size
        s = min(w, h)
        return [int(w / 2 - 0.3 * s), int(h / 2 - 0.38 * s), int(0.6 * s), int(0.76 * s)]


def footage_scenario(seed, kind, directory, *, size=None, n_frames=60, fps=30.0):
    """Draw clip ``seed`` of footage ``kind`` (a :data:`KINDS` key), write it under ``directory``.

    ``size`` (width, height) fixes the resolution (default: drawn from :data:`SIZES`).
    """
    spec = KINDS[kind]
    rng = np.random.default_rng([21, 7, int(seed), _SEED_ORDER.index(kind)])
    size = tuple(SIZES[int(rng.integers(len(SIZES)))]) if size is None else tuple(int(v) for v in size)
    motion = random_motion(rng, size, head=spec["head"], speed=spec.get("speed", 1.0), leave=spec.get("leave", False),
                           warp=spec.get("warp", 1.0), field=spec.get("field", False))
    tex = texture(spec["texture"], size, rng)
    occ = None
    if spec.get("occluder"):
        w, h = size
        s = min(w, h)
        start = int(rng.integers(n_frames // 4, n_frames // 2))
        y = h / 2 + rng.uniform(-0.2, 0.25) * s
        occ = Occluder(start, min(n_frames - 1, start + n_frames // 3),
                       np.array([[-0.1 * w, y], [0.6 * w, y + rng.uniform(-0.1, 0.1) * s]]),
                       np.array([0.18, 0.12]) * s)
    noise = float(rng.uniform(0.5, 2.5))
    frames = np.stack([render(tex, motion, t, lighting=spec.get("lighting", 0.0), blur=spec.get("blur", 0.0),
                              noise=noise, occluder=occ, rng=rng, readout=spec.get("readout", 0.0),
                              lowlight=spec.get("lowlight", 0.0)) for t in range(n_frames)])
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    path = write_clip(directory / f"{kind}_{seed}", frames, codec=spec["codec"], quality=spec.get("quality", 75),
                      fps=fps)
    params = dict(spec, size=list(size), n_frames=n_frames, noise=round(noise, 2))
    return FootageScenario(path, kind, int(seed), size, n_frames, motion, tex, occ, params)
