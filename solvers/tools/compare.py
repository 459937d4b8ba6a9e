"""Side-by-side comparison of the cross-mapping strategies on the same synthetic takes.

``python -m facecap compare`` prints a Markdown table (weights RMSE and max error against
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

from ..capture.neutral import neutral_from_frames
from ..capture.stabilise import stabilise_rigid
from ..character.basis import Basis
from ..strategies import make_strategy
from ..strategies.pca import farthest_frames
from ..strategies.wiring import filled_frames
from .synthetic.synth import performance_weights, synthesize_take

SAMPLE_BASIS = Path(__file__).resolve().parents[2] / "sample_blends" / "character_basis.npz"
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


@dataclass(frozen=True, eq=False)
class Scenario:
    """The shared inputs of a comparison."""

    character: Basis
    actor: Basis
    calibration: object  # MarkerSet (capture space, mm)
    poses: dict
    calibration_neutral: list
    training: ActorTake
    test: ActorTake
    example_frames: np.ndarray  # indices into the training take with known character weights


def build_scenario(*, frames=720, noise=0.0003, gaps=0.05, n_examples=60, seed=0, character=None):
    """Actor (``make_actor``) calibration session, a training take and a test take (different
    performances, head motion, noise, gaps), and ``n_examples`` training frames covering its
    expressions (``farthest_frames``; they may have gaps) whose true weights play the animator's
    posed examples."""
    character = Basis.load_npz(SAMPLE_BASIS) if character is None else character
    actor = make_actor(character, seed=seed)
    Wc, poses, neutral = calibration_weights(actor.shape_names, hold=30)
    calib = synthesize_take(actor, Wc, rest=30, stable=STABLE, units="mm", actor_scale=1.0, noise_sigma=noise,
                            gap_fraction=0.0, max_deg=10.0, seed=seed + 5)
    train = actor_take(actor, performance_weights(character.shape_names, frames, seed=seed + 1), noise=noise,
                       gaps=gaps, seed=seed + 3)
    test = actor_take(actor, performance_weights(character.shape_names, frames, seed=seed), noise=noise,
                      gaps=gaps, seed=seed + 2)
    examples = farthest_frames(train.deltas, n_examples)
    return Scenario(character, actor, calib.markers, poses, neutral, train, test, examples)


def _phone_weights(truth, names, *, noise=0.02, seed=0):
    """What a phone tracker would give: noisy weights under Live Link Face names with a neutral bias."""
    rng = np.random.default_rng(seed)
    bias = rng.uniform(0.0, 0.08, size=truth.shape[1])
    values = np.clip(truth + bias + rng.normal(0.0, noise, size=truth.shape), 0.0, 1.0)
    return values, tuple(n[0].upper() + n[1:] for n in names)


def run_comparison(scenario=None, *, strategies=None):
    """Fit and solve every strategy on ``scenario``; returns a list of row dicts."""

    sc = build_scenario() if scenario is None else scenario
    char, tr, te = sc.character, sc.training, sc.test
    ex = sc.example_frames
    # the posed frames may have gaps: filled through the training take's subspace, as the pipeline does
    ex_deltas = filled_frames(tr.deltas, ex)[0].reshape(len(ex), *tr.deltas.shape[1:])
    cb = dict(calibration=sc.calibration, poses=sc.poses, stable_markers=STABLE)
    phone, phone_names = _phone_weights(te.weights, char.shape_names)
    cases = {
        "geometric": (dict(), lambda s: s.fit(char), te.deltas),
        "calibrated": (dict(), lambda s: s.fit(char, neutral=sc.calibration_neutral, **cb), te.deltas),
        "refine": (dict(), lambda s: s.fit(char, training=tr.deltas, names=tr.names, neutral=tr.neutral,
                                           calibration_neutral=sc.calibration_neutral, **cb), te.deltas),
        "linear": (dict(ridge=1e-3), lambda s: s.fit(char, examples=ex_deltas, weights=tr.weights[ex]), te.deltas),
        "rbf": (dict(), lambda s: s.fit(char, examples=ex_deltas, weights=tr.weights[ex], training=tr.deltas), te.deltas),
        "pca (related)": (dict(mode="related"), lambda s: s.fit(char, training=tr.deltas, example_frames=ex,
                                                                 example_weights=tr.weights[ex]), te.deltas),
        "pca (posed)": (dict(mode="posed", n_basis=12), None, te.deltas),
        "parallel": (dict(), lambda s: s.fit(char, source_names=phone_names, neutral=phone[:50]), phone),
    }
    rows = []
    for label, (options, fit, source) in cases.items():
        name = label.split(" ")[0]
        if strategies is not None and name not in strategies and label not in strategies:
            continue
        strategy = make_strategy(name, **options)
        t0 = time.perf_counter()
        if label == "pca (posed)":
            strategy.learn_basis(tr.deltas)
            frames = np.array(strategy.frames_to_pose())
            strategy.fit(char, training=tr.deltas, example_frames=frames, example_weights=tr.weights[frames])
        else:
            fit(strategy)
        t1 = time.perf_counter()
        names = phone_names if name == "parallel" else te.names
        neutral = None if name == "parallel" else te.neutral
        result = strategy.solve(source, names=names, neutral=neutral)
        t2 = time.perf_counter()
        err = np.nan_to_num(result.weights - te.weights, nan=1.0)
        rows.append({
            "strategy": label, "rmse": float(np.sqrt(np.mean(err**2))), "max": float(np.abs(err).max()),
            "fit_s": t1 - t0, "solve_s": t2 - t1, "warnings": len(result.warnings), "strategy_object": strategy,
        })
    return rows


def markdown_table(rows):
    """The comparison rows as a Markdown table."""
    lines = ["| strategy | weights RMSE | max error | fit time (s) | solve time (s) |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['strategy']} | {r['rmse']:.4f} | {r['max']:.3f} | {r['fit_s']:.2f} | {r['solve_s']:.2f} |")
    return "\n".join(lines)


DESCRIPTION = ("Measure every strategy on the same synthetic cross-retarget takes (an actor with its own "
               "proportions onto the sample character) and print weights error and times as a Markdown table.")


def main(argv=None, *, parents=()):
    """Print the comparison table (Markdown) to stdout."""
    parser = argparse.ArgumentParser(prog="facecap compare", description=DESCRIPTION, parents=list(parents))
    parser.add_argument("--frames", type=int, default=720, help="frames per synthetic take (default 720)")
    parser.add_argument("--examples", type=int, default=60, help="posed example frames for linear/rbf/pca (default 60)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the actor, the takes and the noise (default 0)")
    parser.add_argument("--strategy", action="append", help="only these strategies (repeatable)")
    args = parser.parse_args(argv)
    sc = build_scenario(frames=args.frames, n_examples=args.examples, seed=args.seed)
    rows = run_comparison(sc, strategies=args.strategy)
    print(f"Cross-retarget: actor with its own proportions and expressions (make_actor, seed {args.seed}) -> "
          f"sample character; {args.frames}-frame takes, 0.3 mm noise, 5% gaps, head motion up to 20 deg; "
          f"{args.examples} posed example frames from a separate training take.\n")
    print(markdown_table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
