"""Cross-mapping strategies: how a performance reaches a *different* character's shape keys.

The common interface
--------------------
Every strategy is a class with

- ``name`` (the ``[solve] strategy`` value) and ``source_kind``: ``"markers"`` (stabilised,
  neutral-normalised actor marker deltas, (F, M, 3) metres, NaN for gaps, in actor space — what
  the pipeline has after ``stabilise`` and ``neutral``) or ``"weights"`` (already-solved channel
  values, (F, S), for ``parallel``);
- ``__init__(*, **options)``: keyword-only options with documented defaults, validated at once
  (a ``FacecapError`` names the bad option);
- ``fit(character, *, ...) -> self``: everything the strategy learns. ``character`` is the
  character ``Basis`` (or, where no geometry is needed, just its shape names); the keyword
  arguments are the strategy's learning inputs (calibration take + pose frame ranges, example
  pairs, a training take, source channel names). Fitting never modifies its inputs;
- ``solve(source, *, names=None, neutral=None, confidence=None) -> StrategyResult``:
  ``names`` labels the source's second axis (marker or channel names; matched to what was
  fitted, missing markers become gaps), ``neutral`` (M, 3) is the take's neutral in the same
  space as ``source``; strategies fitted in another head frame (a calibration take) align it onto
  their own neutral (rigid by default: Sony's master T-pose alignment), ``geometric`` aligns it
  onto the character by a similarity. ``confidence`` (F, M) is per-sample trust where a weight
  solve runs. A strategy that predicts the markers themselves (``PredictsMarkers``: geometric)
  also takes ``start``, ``quick`` and ``overwrite`` (the caller gives ``source`` up, so the
  solve may work in its memory: one (F, M, D) array less on a long take).

``StrategyResult`` (``base.py``) carries ``weights`` (F, K) for the CHARACTER's shapes
(``shape_names``, NaN where unsolved), ``solved`` (F,), ``warnings`` (legal but doubtful input or
output: under-determined maps, extrapolated frames, unmapped channels), the intermediate
``source_weights`` / ``source_names`` (actor poses, basis-frame or component coefficients),
``residual_rms`` (F,) of the marker fit where there is one, ``clamped`` (F,) counts, ``info``
and the engine's ``SolveResult`` (``solve``) where ``solve_bounded`` ran.

Every weight solve goes through ``engine.solve_bounded`` with ``relative=True`` (unit-free priors).

The strategies
--------------
=============  ====================  ===============================================================
name           class                 learns from (``fit`` keywords)
=============  ====================  ===============================================================
semantic       SemanticStrategy      what is known of the actor (``actor_model``): calibration poses, a
                                     profile, a human template, else the character normalised
geometric      GeometricStrategy     nothing (the character's shape keys at the bound points)
calibrated     CalibratedStrategy    ``calibration`` MarkerSet + ``poses`` + ``neutral`` (or ``actor_basis``)
parallel       ParallelStrategy      ``source_names`` (+ ``neutral`` segment of source values)
linear         LinearStrategy        ``examples`` (N, M, 3) + ``weights`` (N, K)
rbf            RBFStrategy           ``examples`` + ``weights`` (+ ``training`` for the PCA features)
pca            PCAStrategy           ``training`` take + ``example_frames`` / ``example_weights``
refine         RefineStrategy        as calibrated, plus a ``training`` take
=============  ====================  ===============================================================

Name matching (ARKit, Live Link Face, MediaPipe, FACS action units) lives in ``solvers.aliases``;
mapping tables (one-to-one by name or many-to-many with gains) in ``mapping.Mapping``.
``solvers.tools.compare`` measures every strategy on the same synthetic cross-retarget takes.
"""

import importlib

from ..errors import FacecapError

#: strategy name -> (module, class), imported on first use (``get_strategy``)
STRATEGY_CLASSES = {
    "semantic": ("semantic", "SemanticStrategy"),
    "geometric": ("geometric", "GeometricStrategy"),
    "calibrated": ("calibrated", "CalibratedStrategy"),
    "parallel": ("parallel", "ParallelStrategy"),
    "linear": ("linear", "LinearStrategy"),
    "rbf": ("rbf", "RBFStrategy"),
    "pca": ("pca", "PCAStrategy"),
    "refine": ("refine", "RefineStrategy"),
}
STRATEGY_NAMES = tuple(STRATEGY_CLASSES)


def get_strategy(name):
    """The strategy class called ``name``."""

    if name not in STRATEGY_CLASSES:
        raise FacecapError(f"unknown strategy '{name}'; available: {', '.join(STRATEGY_NAMES)}")
    module, cls = STRATEGY_CLASSES[name]
    return getattr(importlib.import_module(f"{__name__}.{module}"), cls)


def make_strategy(name, **options):
    """An unfitted strategy ``name`` with keyword ``options``."""
    return get_strategy(name)(**options)
