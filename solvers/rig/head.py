"""Hierarchical stabilisation of a rig take against the rig's own prediction.

The pipeline refits the head on every marker against what its solve predicts (``[stabilise]
fine_iterations``). Onto a rig that solve is the linear one, whose secant columns miss what the
rig's curves, correctives and in-betweens do: where they fire, the prediction is off by a
millimetre or more and the refit tilts the head to make up for it, which no later solve undoes.
So a nonlinear rig solve takes the gross stabilisation from the pipeline and refits the head here
against the rig model at the nonlinear solution (``predicted``), then solves again.
"""

import numpy as np

from ..pipeline import refit_head, stages


def predicted(model, u, result, stab, settings):
    """Where the rig ``model`` (in character space, at ``result.marker_names``) puts those markers
    in the head frame of ``stab`` for offsets ``u`` (F, C): (F, U, 3), NaN on unsolved frames."""
    take, _ = stages.normalised(stab, settings, [])
    idx = [take.names.index(n) for n in result.marker_names]
    out = take.neutral[idx][None] + result.alignment.inverse_vectors(model.deltas(np.nan_to_num(u)))
    if take.offsets is not None:  # back to where the (un-normalised) markers are
        out -= np.take(take.offsets, idx, axis=1)
    out[~np.isfinite(u).all(axis=1)] = np.nan
    return out


def refit(model, u, result, stab, markers, settings):
    """``stab`` refitted on ``result.marker_names`` against the rig's prediction at ``u``;
    ``markers``: the raw take (MarkerSet)."""
    names = list(stab.markers.names)  # the take's usable markers, as the pipeline stabilised them
    metres = markers.subset(names) if list(markers.names) != names else markers
    metres = metres.to_units("m") if metres.units != "m" else metres
    return refit_head(stab, list(result.marker_names), [predicted(model, u, result, stab, settings)], metres,
                      settings)
