"""Neutral (T-pose) estimation: the rest positions that marker deltas are measured from."""

import numpy as np

from ..errors import FacecapError


def neutral_from_frames(markers, first, last):
    """Per-marker median position over the inclusive frame range [first, last].

    The median ignores gaps and is robust to a few bad samples (a blink during the T-pose).

    Returns
    -------
    ndarray, shape (M, D)
    """
    if last < first:
        raise FacecapError(f"neutral: frame range {first}-{last} is empty (last < first)")
    sel = markers.frame_range_mask(first, last)
    if not sel.any():
        raise FacecapError(
            f"neutral: frames {first}-{last} are outside the take "
            f"({markers.frames[0]:g}-{markers.frames[-1]:g})"
        )
    block = markers.positions[sel]
    never = ~(~np.isnan(block[:, :, 0])).any(axis=0)
    if never.any():
        names = [markers.names[i] for i in np.flatnonzero(never)]
        raise FacecapError(f"neutral: marker(s) {names} have no sample in frames {first}-{last}")
    return np.nanmedian(block, axis=0)
