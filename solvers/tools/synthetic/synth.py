"""Synthetic takes with known ground truth: weights -> markers with head motion, noise and gaps.

Used by the sample-take generator and by the accuracy tests, so that every accuracy figure is
measured against weights and head poses we know exactly.
"""

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ...markers import UNIT_SCALE, MarkerSet


@dataclass(frozen=True, eq=False)
class SyntheticTake:
    """Markers plus the truth they were made from."""

    markers: MarkerSet  # noisy, with gaps, in ``units``
    clean: MarkerSet  # same head motion, no noise, no gaps
    weights: np.ndarray  # (F, K) ground truth
    head_rotvec_deg: np.ndarray  # (F, 3) head rotation in capture axes, relative to frame 0
    head_offset: np.ndarray  # (F, 3) displacement of the head pivot in capture axes (units)


def _bump(t, centre, width):
    """Raised-cosine pulse of total duration ``width`` centred at ``centre`` (peak 1)."""
    x = (t - centre) / (width / 2.0)
    return np.where(np.abs(x) < 1.0, 0.5 * (1.0 + np.cos(np.pi * x)), 0.0)


def _plateau(t, start, ramp, hold):
    """0 -> 1 over ``ramp`` s, hold for ``hold`` s, back to 0 over ``ramp`` s."""
    up = np.clip((t - start) / ramp, 0.0, 1.0)
    down = np.clip((start + 2 * ramp + hold - t) / ramp, 0.0, 1.0)
    s = np.minimum(up, down)
    return s * s * (3 - 2 * s)  # smoothstep keeps velocity continuous


def performance_weights(shape_names, n_frames, *, fps=60.0, rest=60, seed=0):
    """Plausible facial performance curves: blinks, speech-like jaw and lips, smiles, brows.

    The first and last ``rest`` frames are a neutral hold (all weights 0). Shapes that a marker
    layout cannot observe (eye gaze, tongue) stay at 0.

    Returns
    -------
    ndarray, shape (n_frames, K), values in [0, 1]
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / fps
    t0, t1 = rest / fps, (n_frames - rest) / fps
    span = t1 - t0
    curves = {}

    def add(name, values):
        curves[name] = curves.get(name, 0.0) + values

    # Blinks every 2-4 s, 0.15-0.25 s long; none while the eyes are held wide (the two act on the
    # same lid in opposite directions).
    wide = 0.4 * _bump(t, t0 + 0.5 * span, 0.6)
    tb = t0 + rng.uniform(0.3, 1.0)
    while tb < t1 - 0.3:
        width = rng.uniform(0.15, 0.25)
        amp = rng.uniform(0.85, 1.0)
        pulse = _bump(t, tb, width) * (wide == 0)
        add("eyeBlinkLeft", amp * pulse)
        add("eyeBlinkRight", amp * rng.uniform(0.9, 1.0) * pulse)
        tb += rng.uniform(2.0, 4.0)

    # Speech: syllables at ~4 Hz in two phrases.
    phrases = [(t0 + 0.2, t0 + 0.45 * span), (t0 + 0.55 * span, t1 - 0.3)]
    for a, b in phrases:
        ts = a
        while ts < b:
            width = rng.uniform(0.18, 0.32)
            pulse = _bump(t, ts, width)
            kind = rng.choice(["open", "open", "round", "closed", "spread", "roll"])
            add("jawOpen", rng.uniform(0.15, 0.5) * pulse if kind != "closed" else 0.08 * pulse)
            if kind == "open":
                lower = rng.uniform(0.1, 0.4)
                add("mouthLowerDownLeft", lower * pulse)
                add("mouthLowerDownRight", lower * rng.uniform(0.8, 1.0) * pulse)
                add("mouthUpperUpLeft", rng.uniform(0.0, 0.25) * pulse)
                add("mouthUpperUpRight", rng.uniform(0.0, 0.25) * pulse)
            elif kind == "round":
                add(str(rng.choice(["mouthFunnel", "mouthPucker"])), rng.uniform(0.3, 0.7) * pulse)
            elif kind == "closed":
                add("mouthClose", rng.uniform(0.05, 0.1) * pulse)
                press = rng.uniform(0.2, 0.5)
                add("mouthPressLeft", press * pulse)
                add("mouthPressRight", press * pulse)
            elif kind == "spread":
                stretch = rng.uniform(0.2, 0.5)
                add("mouthStretchLeft", stretch * pulse)
                add("mouthStretchRight", stretch * rng.uniform(0.8, 1.0) * pulse)
            else:
                add(str(rng.choice(["mouthRollLower", "mouthShrugLower", "mouthShrugUpper"])), rng.uniform(0.3, 0.6) * pulse)
            ts += width * rng.uniform(0.8, 1.2)

    # A smile, a one-sided smirk, a frown and brow raises.
    smile = _plateau(t, t0 + 0.30 * span, 0.4, 1.2)
    add("mouthSmileLeft", 0.75 * smile)
    add("mouthSmileRight", 0.7 * smile)
    add("cheekSquintLeft", 0.4 * smile)
    add("cheekSquintRight", 0.35 * smile)
    add("eyeSquintLeft", 0.25 * smile)
    add("eyeSquintRight", 0.25 * smile)
    smirk = _plateau(t, t0 + 0.78 * span, 0.3, 0.5)
    add("mouthSmileLeft", 0.55 * smirk)
    add("mouthDimpleLeft", 0.4 * smirk)
    frown = _plateau(t, t0 + 0.05 * span, 0.3, 0.6)
    add("browDownLeft", 0.7 * frown)
    add("browDownRight", 0.7 * frown)
    add("mouthFrownLeft", 0.5 * frown)
    add("mouthFrownRight", 0.5 * frown)
    add("noseSneerLeft", 0.3 * frown)
    add("noseSneerRight", 0.3 * frown)
    for centre in t0 + span * np.array([0.22, 0.5, 0.66, 0.9]):
        raise_ = _bump(t, centre, rng.uniform(0.5, 0.9))
        add("browInnerUp", rng.uniform(0.4, 0.8) * raise_)
        add("browOuterUpLeft", rng.uniform(0.3, 0.7) * raise_)
        add("browOuterUpRight", rng.uniform(0.3, 0.7) * raise_)
    add("eyeWideLeft", wide)
    add("eyeWideRight", wide)
    add("cheekPuff", 0.6 * _plateau(t, t0 + 0.93 * span, 0.2, 0.3))
    add("jawLeft", 0.3 * _bump(t, t0 + 0.48 * span, 0.8))
    add("mouthLeft", 0.3 * _bump(t, t0 + 0.62 * span, 0.6))

    W = np.zeros((n_frames, len(shape_names)))
    for k, name in enumerate(shape_names):
        if name in curves:
            W[:, k] = curves[name]
    W[:rest] = 0.0
    W[n_frames - rest :] = 0.0
    return np.clip(W, 0.0, 1.0)


def head_motion(n_frames, *, fps=60.0, rest=60, max_deg=25.0, max_offset=0.05, seed=1):
    """Smooth rigid head motion: still for the first ``rest`` frames, then up to +/-max_deg, +/-max_offset.

    Returns
    -------
    rotvec : (F, 3) rotation vectors in radians (character axes: X right, Y back, Z up)
    offset : (F, 3) translations in metres
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / fps
    env = np.clip((t - rest / fps) / 0.8, 0.0, 1.0)
    env = env * env * (3 - 2 * env)

    def wander(peak):
        freqs = rng.uniform(0.08, 0.6, size=4)
        phases = rng.uniform(0, 2 * np.pi, size=4)
        amps = rng.uniform(0.5, 1.0, size=4)
        x = (amps[:, None] * np.sin(2 * np.pi * freqs[:, None] * t + phases[:, None])).sum(axis=0)
        x = x - x[min(rest, n_frames - 1)]
        x = x * env
        return peak * x / np.max(np.abs(x))

    angles = np.stack([wander(np.radians(max_deg * 0.6)), wander(np.radians(max_deg * 0.4)), wander(np.radians(max_deg))], axis=1)
    rotvec = Rotation.from_euler("xyz", angles).as_rotvec()
    offset = np.stack([wander(max_offset), wander(max_offset * 0.6), wander(max_offset * 0.5)], axis=1)
    return rotvec, offset


def synthesize_take(
    basis,
    weights,
    *,
    fps=60.0,
    rest=60,
    stable=(),
    units="mm",
    pivot=(0.0, 0.03, -0.12),
    capture_rotation_deg=(0.0, 0.0, 90.0),
    capture_offset=(0.3, -0.15, 1.65),
    actor_scale=1.08,
    max_deg=25.0,
    max_offset=0.05,
    noise_sigma=0.0003,
    gap_fraction=0.05,
    max_gap=30,
    seed=2,
):
    """Markers a capture system would record if an actor performed ``weights`` on ``basis``.

    The face (basis neutral + weighted deltas, metres) moves rigidly about ``pivot``; the actor is
    ``actor_scale`` times the character and stands in the capture volume at ``capture_offset``
    rotated by ``capture_rotation_deg``; positions are written in ``units`` with Gaussian noise of
    ``noise_sigma`` metres per coordinate and runs of 2 to ``max_gap`` frames of gaps on
    ``gap_fraction`` of the samples of every marker not in ``stable``.

    Returns
    -------
    SyntheticTake
    """
    face = basis.neutral[None] + np.einsum("fk,kmd->fmd", weights, basis.deltas)
    return synthesize_points(basis.marker_names, face, weights, fps=fps, rest=rest, stable=stable, units=units,
                             pivot=pivot, capture_rotation_deg=capture_rotation_deg, capture_offset=capture_offset,
                             actor_scale=actor_scale, max_deg=max_deg, max_offset=max_offset,
                             noise_sigma=noise_sigma, gap_fraction=gap_fraction, max_gap=max_gap, seed=seed)


def synthesize_points(names, face, truth, *, fps=60.0, rest=60, stable=(), units="mm", pivot=(0.0, 0.03, -0.12),
                      capture_rotation_deg=(0.0, 0.0, 90.0), capture_offset=(0.3, -0.15, 1.65), actor_scale=1.08,
                      max_deg=25.0, max_offset=0.05, noise_sigma=0.0003, gap_fraction=0.05, max_gap=30, seed=2):
    """``synthesize_take`` for a face given as its points per frame ``face`` (F, M, 3, metres; e.g. a
    rig evaluated at its bound points ``names``); ``truth`` (F, ...) is kept as the take's weights."""
    rng = np.random.default_rng(seed)
    F = face.shape[0]
    rotvec, offset = head_motion(F, fps=fps, rest=rest, max_deg=max_deg, max_offset=max_offset, seed=seed + 1)
    R = Rotation.from_rotvec(rotvec).as_matrix()
    pivot = np.asarray(pivot, dtype=np.float64)
    moved = np.einsum("fij,fmj->fmi", R, face - pivot) + pivot + offset[:, None]
    Rc = Rotation.from_euler("xyz", capture_rotation_deg, degrees=True).as_matrix()
    to_units = 1.0 / UNIT_SCALE[units]
    capture = (actor_scale * moved @ Rc.T + np.asarray(capture_offset)) * to_units

    noisy = capture + rng.normal(0.0, noise_sigma * to_units, size=capture.shape)
    stable_set = set(stable)
    for m, name in enumerate(names):
        if name in stable_set:
            continue
        target = int(round(gap_fraction * F))
        missing = 0
        while missing < target:
            length = int(rng.integers(2, max_gap + 1))
            start = int(rng.integers(rest, max(rest + 1, F - rest - length)))
            noisy[start : start + length, m] = np.nan
            missing = int(np.isnan(noisy[:, m, 0]).sum())

    frames = np.arange(1, F + 1, dtype=np.float64)
    names = tuple(names)
    head_rot = Rotation.from_matrix(Rc @ R @ Rc.T).as_rotvec(degrees=True)
    return SyntheticTake(
        markers=MarkerSet(names, frames, noisy, fps=fps, units=units, source="synthetic take"),
        clean=MarkerSet(names, frames, capture, fps=fps, units=units, source="synthetic take (clean)"),
        weights=truth,
        head_rotvec_deg=head_rot,
        head_offset=actor_scale * offset @ Rc.T * to_units,
    )
