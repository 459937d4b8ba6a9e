"""Synthetic face footage with exact ground truth, for tests and benchmarks.

A textured, face-like reference image R is deformed per frame by a smooth local displacement
field D_t (bumps at mouth, brows, cheeks) and then a global similarity S_t. A reference point p
appears in frame t at ``S_t(p + D_t(p))``; so the true flow relative to the reference (on the
reference grid, the thesis' convention ``R(p) = I_t(p + F_t(p))``) is ``F_t(p) = S_t(p + D_t(p)) - p``.
Frames are rendered by inverting that map (fixed-point iteration) and resampling R bilinearly.
"""

from dataclasses import dataclass

import numpy as np

from .reading import opencv, write_video


def face_texture(width=320, height=240, *, seed=0):
    """A band-limited, well-textured face-like grayscale image (float32, 0..255)."""
    cv2 = opencv()
    rng = np.random.default_rng(seed)
    img = np.zeros((height, width), np.float32)
    for sigma, amp in ((12.0, 40.0), (5.0, 30.0), (2.0, 22.0), (1.0, 12.0)):
        noise = rng.normal(size=(height, width)).astype(np.float32)
        noise = cv2.GaussianBlur(noise, (0, 0), sigma)
        img += amp * noise / (noise.std() + 1e-9)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    cx, cy, s = width / 2, height / 2, min(width, height)

    def blob(x, y, rx, ry):
        return np.exp(-(((xx - x) / rx) ** 2 + ((yy - y) / ry) ** 2))

    face = np.clip(1.5 - (((xx - cx) / (0.36 * s)) ** 2 + ((yy - cy) / (0.46 * s)) ** 2), 0, 1)
    img += 60 * face
    for side in (-1, 1):
        img -= 70 * blob(cx + side * 0.14 * s, cy - 0.1 * s, 0.06 * s, 0.03 * s)  # eyes
        img -= 45 * blob(cx + side * 0.14 * s, cy - 0.2 * s, 0.08 * s, 0.015 * s)  # brows
        img -= 30 * blob(cx + side * 0.04 * s, cy + 0.07 * s, 0.015 * s, 0.012 * s)  # nostrils
    img -= 60 * blob(cx, cy + 0.22 * s, 0.12 * s, 0.025 * s)  # mouth
    img = cv2.GaussianBlur(img, (0, 0), 0.8)
    return np.clip(img + 110, 0, 255).astype(np.float32)


@dataclass(frozen=True)
class Motion:
    """Per-frame motion parameters: bump amplitudes (T, K) and similarity (T, 4): angle, log-scale, tx, ty."""

    centres: np.ndarray  # (K, 2) bump centres in reference pixels
    radii: np.ndarray  # (K,)
    directions: np.ndarray  # (K, 2) unit displacement directions
    amplitudes: np.ndarray  # (T, K) pixels
    similarity: np.ndarray  # (T, 4)
    size: tuple  # (width, height)

    @property
    def n_frames(self):
        return self.amplitudes.shape[0]

    def local(self, t, pts):
        """D_t at reference points ``pts`` (..., 2)."""
        d = pts[..., None, :] - self.centres  # (..., K, 2)
        g = np.exp(-0.5 * np.sum(d * d, axis=-1) / self.radii**2)  # (..., K)
        return g @ (self.amplitudes[t][:, None] * self.directions)

    def local_grid(self, t):
        """D_t on the whole reference pixel grid, (H, W, 2) float32 (separable Gaussians: fast)."""
        w, h = self.size
        x, y = np.arange(w, dtype=float), np.arange(h, dtype=float)
        out = np.zeros((h, w, 2), np.float64)
        for k in range(len(self.centres)):
            gx = np.exp(-0.5 * (x - self.centres[k, 0]) ** 2 / self.radii[k] ** 2)
            gy = np.exp(-0.5 * (y - self.centres[k, 1]) ** 2 / self.radii[k] ** 2)
            g = np.outer(gy, gx) * self.amplitudes[t, k]
            out[..., 0] += g * self.directions[k, 0]
            out[..., 1] += g * self.directions[k, 1]
        return out.astype(np.float32)

    def _sim(self, t):
        a, ls, tx, ty = self.similarity[t]
        c = np.array(self.size, float) / 2
        s = np.exp(ls)
        R = s * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        return R, c, np.array([tx, ty])

    def forward(self, t, pts):
        """Where reference points ``pts`` (..., 2) appear in frame t."""
        R, c, tr = self._sim(t)
        q = pts + self.local(t, pts)
        return (q - c) @ R.T + c + tr

    def inverse(self, t, x, iterations=8):
        """Reference points that land on frame-t pixels ``x`` (..., 2) (fixed-point inversion)."""
        R, c, tr = self._sim(t)
        q = (x - c - tr) @ np.linalg.inv(R).T + c
        p = q.copy()
        for _ in range(iterations):
            p = q - self.local(t, p)
        return p

    def flow_between(self, a, b):
        """True field f_ab on frame a's grid pointing into frame b: (H, W, 2)."""
        w, h = self.size
        grid = np.stack(np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float)), axis=-1)
        return self.forward(b, self.inverse(a, grid, iterations=20)) - grid

    def flow(self, t):
        """True flow of frame t relative to the reference, on the reference grid: (H, W, 2)."""
        w, h = self.size
        grid = np.stack(np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float)), axis=-1)
        return self.forward(t, grid) - grid


def make_motion(n_frames, width=320, height=240, *, amplitude=3.0, similarity=True, rotation_deg=2.0,
                scale=0.02, shift=6.0, seed=0, period=40.0):
    """Smooth, quasi-periodic face motion; frame 0 is the neutral reference (no motion)."""
    rng = np.random.default_rng(seed)
    s = min(width, height)
    cx, cy = width / 2, height / 2
    centres = np.array([[cx, cy + 0.3 * s], [cx - 0.12 * s, cy + 0.22 * s], [cx + 0.12 * s, cy + 0.22 * s],
                        [cx - 0.14 * s, cy - 0.2 * s], [cx + 0.14 * s, cy - 0.2 * s], [cx, cy + 0.05 * s]])
    radii = np.array([0.16, 0.08, 0.08, 0.09, 0.09, 0.12]) * s
    directions = np.array([[0, 1], [-0.7, -0.7], [0.7, -0.7], [0, -1], [0, -1], [0, 0.5]], float)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    t = np.arange(n_frames, dtype=float)

    periods = period * rng.uniform(0.7, 1.4, size=(len(centres),))
    amps = amplitude * 0.5 * (1 - np.cos(2 * np.pi * t[:, None] / periods))  # 0 at t=0
    amps *= rng.uniform(0.6, 1.0, size=(len(centres),))
    sim = np.zeros((n_frames, 4))
    if similarity:
        sp = period * rng.uniform(1.2, 2.0, size=4)
        sim[:, 0] = np.radians(rotation_deg) * np.sin(2 * np.pi * t / sp[0])
        sim[:, 1] = np.log1p(scale * np.sin(2 * np.pi * t / sp[1]))
        sim[:, 2] = shift * np.sin(2 * np.pi * t / sp[2])
        sim[:, 3] = 0.6 * shift * np.sin(2 * np.pi * t / sp[3])
    return Motion(centres, radii, directions, amps, sim, (width, height))


def render(texture, motion, t, *, noise=0.0, rng=None):
    """Frame t as uint8: ``I_t(x) = R(inverse_t(x))``."""
    cv2 = opencv()
    h, w = texture.shape
    grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)), axis=-1)
    R, c, tr = motion._sim(t)
    q = ((grid - c - tr) @ np.linalg.inv(R).T + c).astype(np.float32)
    local = motion.local_grid(t)  # D_t on the reference grid; sampled by remap below
    p = q.copy()
    for _ in range(10):  # fixed point p = q - D_t(p)
        d = cv2.remap(local, p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        p = q - d
    img = cv2.remap(texture, p[..., 0], p[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    if noise:
        img = img + (rng or np.random.default_rng(t)).normal(scale=noise, size=img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class SyntheticClip:
    path: str
    texture: np.ndarray
    motion: Motion
    codec: str
    fps: float


def write_synthetic_clip(path, n_frames=60, width=320, height=240, *, fps=30.0, noise=0.0, codec=None,
                         seed=0, occlusions=(), **motion_options):
    """Render a synthetic performance and write it as a real video file; returns a :class:`SyntheticClip`.

    ``occlusions``: ``[(first, last, (x, y, w, h)), ...]`` flat grey boxes painted over those frames.
    """
    tex = face_texture(width, height, seed=seed)
    motion = make_motion(n_frames, width, height, seed=seed, **motion_options)
    rng = np.random.default_rng(seed + 1)
    frames = np.stack([render(tex, motion, t, noise=noise, rng=rng) for t in range(n_frames)])
    for first, last, (x, y, w, h) in occlusions:
        frames[first: last + 1, y: y + h, x: x + w] = 128
    used = write_video(path, frames, fps=fps, codec=codec)
    return SyntheticClip(str(path), tex, motion, used, float(fps))
