"""Takes of the sample character's actor with and without occlusion gaps (same performance, noise
and head motion), with posed examples, for the example strategies' tests."""

from types import SimpleNamespace

import numpy as np


def example_takes(frames=600, n_examples=30):
    """600 frames with and without 5 % gaps and ``n_examples`` posed frames (farthest frames of the
    gap-free take). With 60 occludable markers ~80 % of the frames have a gap and the gap-free ones
    are mostly the neutral holds. ``gap`` (F,) marks the frames of the gappy take with a gap."""
    from facecap.solvers.character.basis import Basis
    from facecap.solvers.tools.compare import SAMPLE_BASIS, actor_take, make_actor
    from facecap.solvers.strategies.options import ExamplePairs, StrategyInputs
    from facecap.solvers.strategies.pca import farthest_frames
    from facecap.solvers.tools.synthetic.synth import performance_weights

    character = Basis.load_npz(SAMPLE_BASIS)
    actor = make_actor(character, seed=0)
    W = performance_weights(character.shape_names, frames, seed=0)
    clean, gappy = actor_take(actor, W, gaps=0.0, seed=2), actor_take(actor, W, gaps=0.05, seed=2)
    ex = farthest_frames(clean.deltas, n_examples)
    inputs = StrategyInputs(examples=ExamplePairs(clean.markers.frames[ex], W[ex], character.shape_names))
    gap = np.isnan(gappy.markers.positions).any(axis=(1, 2))
    return SimpleNamespace(character=character, clean=clean, gappy=gappy, W=W, inputs=inputs, gap=gap)


def weight_errors(takes, **settings):
    """{"clean": errors, "gappy": errors} (F, K) of ``retarget`` with ``RetargetSettings(**settings)``
    on both takes (unsolved weights count as an error of 1)."""
    from facecap.solvers.tools.compare import STABLE
    from facecap.solvers.pipeline import RetargetSettings, retarget

    rs = RetargetSettings(stable_markers=STABLE, neutral_frames=(1, 60), **settings)
    return {label: np.nan_to_num(retarget(t.markers, takes.character, rs, inputs=takes.inputs).weights - takes.W, nan=1.0)
            for label, t in (("clean", takes.clean), ("gappy", takes.gappy))}
