"""A small, well-conditioned synthetic face basis for core tests (no Blender needed)."""

import numpy as np

from facecap.solvers import Basis


def make_basis(n_markers=60, n_shapes=20, n_stable=8, seed=0):
    """Markers on the front of an ellipsoid head (metres, facing -Y); localised random shapes.

    The first ``n_stable`` markers sit on the upper head and no shape moves them.
    """
    rng = np.random.default_rng(seed)
    # Stable markers: forehead band and temples, spread in 3D.
    az_s = np.linspace(-1.2, 1.2, n_stable)
    el_s = np.where(np.arange(n_stable) % 2 == 0, 0.9, 0.55)
    # Expressive markers: lower and mid face.
    n_face = n_markers - n_stable
    az_f = rng.uniform(-1.1, 1.1, n_face)
    el_f = rng.uniform(-0.9, 0.35, n_face)
    az = np.concatenate([az_s, az_f])
    el = np.concatenate([el_s, el_f])
    radii = np.array([0.075, 0.09, 0.11])
    pts = np.stack([np.sin(az) * np.cos(el), -np.cos(az) * np.cos(el), np.sin(el)], axis=1) * radii
    names = [f"head{i}" for i in range(n_stable)] + [f"m{i}" for i in range(n_face)]
    deltas = np.zeros((n_shapes, n_markers, 3))
    for k in range(n_shapes):
        centre = pts[n_stable + rng.integers(n_face)]
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        falloff = np.exp(-np.sum((pts - centre) ** 2, axis=1) / (2 * 0.025**2))
        falloff[:n_stable] = 0.0
        deltas[k] = rng.uniform(0.004, 0.012) * falloff[:, None] * direction
    shapes = [f"shape{k}" for k in range(n_shapes)]
    return Basis(shapes, names, pts, deltas), names[:n_stable]
