"""Side-by-side comparison of the cross-mapping strategies on the same synthetic takes.

``python -m facecap.solvers.compare`` prints a Markdown table (weights RMSE and max error against
the ground truth, fit and solve time) of every strategy. The scenario is a *cross* retarget: an
ACTOR with its own proportions and its own shape deltas (``make_actor``) performs; the CHARACTER
is the sample character (``sample_blends/character_basis.npz``). Every marker strategy receives
the same stabilised, neutral-normalised actor deltas; ``parallel`` receives noisy ARKit weights
under Live Link Face names (what a phone capture would give).
"""

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .basis import Basis
from .neutral import neutral_from_frames
from .stabilise import stabilise_rigid
from .synth import performance_weights, synthesize_take

SAMPLE_BASIS = Path(__file__).resolve().parents[1] / "sample_blends" / "character_basis.npz"
STABLE = ("head_forehead_C", "head_forehead_L", "head_forehead_R", "head_temple_L", "head_temple_R",
          "head_nose_bridge_C", "head_side_L", "head_side_R")


def make_actor(character, *, seed=0, upper_scale=(1.04, 1.08, 1.16), lower_scale=(0.93, 1.05, 0.86),
               upper_gain=1.25, lower_gain=0.8, max_rotation_deg=12.0, perturbation=0.15):
    """An actor with its own proportions and its own expressions, from a character basis.

    Proportions: the neutral is scaled about the eye line per region (above / below z = -0.02 m,
    anisotropic ``upper_scale`` / ``lower_scale``). Expressions: every shape's deltas are scaled per
    region (``upper_gain`` / ``lower_gain``), rotated by a random rotation of up to
    ``max_rotation_deg`` and perturbed marker by marker (relative ``perturbation``); shapes that
    do not move a marker still do not move it. Shape names are kept (one-to-one semantics).
    """
    rng = np.random.default_rng(seed)
    pts = character.neutral
    eye_line = np.array([0.0, pts[:, 1].mean(), 0.005])
    upper = pts[:, 2] > -0.02
    scale = np.where(upper[:, None], upper_scale, lower_scale)
    neutral = eye_line + (pts - eye_line) * scale
    gain = np.where(upper, upper_gain, lower_gain)
    deltas = np.empty_like(character.deltas)
    for k in range(character.n_shapes):
        R = Rotation.from_rotvec(rng.normal(size=3) / np.sqrt(3) * np.radians(max_rotation_deg)).as_matrix()
        d = character.deltas[k] * scale * gain[:, None]
        size = np.linalg.norm(d, axis=1, keepdims=True)
        d = d * (1.0 + perturbation * rng.uniform(-1, 1, size=(len(d), 1))) + perturbation * size * rng.normal(size=d.shape) / np.sqrt(3)
        deltas[k] = d @ R.T
    return Basis(character.shape_names, character.marker_names, neutral, deltas)


def calibration_weights(shape_names, *, rest=30, ramp=8, hold=20):
    """A calibration session: neutral, then every shape in turn (ramp up, hold, ramp down).

    Returns (weights (F, K), poses {name: [first, last]} of the holds, neutral [first, last]),
    frame numbers starting at 1.
    """
    K = len(shape_names)
    block = 2 * ramp + hold
    F = rest + K * block + rest
    W = np.zeros((F, K))
    ramp_up = np.linspace(0.0, 1.0, ramp + 2)[1:-1]
    poses = {}
    for k, name in enumerate(shape_names):
        start = rest + k * block
        W[start : start + ramp, k] = ramp_up
        W[start + ramp : start + ramp + hold, k] = 1.0
        W[start + ramp + hold : start + block, k] = ramp_up[::-1]
        poses[name] = [start + ramp + 1 + 2, start + ramp + hold - 2]  # 1-based, skip the settle frames
    return W, poses, [1, rest]


@dataclass(frozen=True, eq=False)
class ActorTake:
    """Stabilised actor-space deltas of a synthetic take and the weights that made them."""

    deltas: np.ndarray  # (F, M, 3) metres, NaN for gaps
    neutral: np.ndarray  # (M, 3)
    names: tuple
    weights: np.ndarray  # (F, K) truth
    markers: object  # raw MarkerSet (capture space, mm)


def actor_take(actor, weights, *, rest=60, noise=0.0003, gaps=0.0, seed=2, max_deg=20.0):
    """Markers of ``actor`` performing ``weights`` (head motion, noise, gaps), stabilised on the
    ``head_*`` markers and normalised on the first ``rest`` frames, as the pipeline would."""
    take = synthesize_take(actor, weights, rest=rest, stable=STABLE, units="mm", actor_scale=1.0,
                           noise_sigma=noise, gap_fraction=gaps, max_deg=max_deg, seed=seed)
    markers = take.markers.to_units("m")
    stab = stabilise_rigid(markers, STABLE, reference_frames=(1, rest))
    neutral = neutral_from_frames(stab.markers, 1, rest)
    return ActorTake(stab.markers.positions - neutral, neutral, markers.names, weights, take.markers)
