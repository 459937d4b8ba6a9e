"""A landmark take's blendshape scores kept in the .blend (on its collection) and read back for a solve."""

import numpy as np


def store_scores(coll, found):
    """Keep a landmark take's blendshape scores (LandmarkResult ``found``) on its collection: the .blend holds what
    a re-solve needs (-1 where no face was found: ID properties hold no NaN)."""
    if found.blendshapes is None:
        return
    coll["facecap_blendshapes"] = np.where(np.isfinite(found.blendshapes), found.blendshapes, -1.0).ravel().tolist()
    coll["facecap_blendshape_names"] = list(found.blendshape_names)
    coll["facecap_blendshape_frames"] = [float(f) for f in found.markers.frames]


def scores_from_collection(coll, frames):
    """(F, S) scores of the collection's take at ``frames`` (NaN where it has none) and their names, or None."""
    if coll is None or "facecap_blendshapes" not in coll:
        return None
    names = tuple(str(n) for n in coll["facecap_blendshape_names"])
    kept = np.asarray(coll["facecap_blendshape_frames"], dtype=np.float64)
    values = np.asarray(coll["facecap_blendshapes"], dtype=np.float64).reshape(len(kept), len(names))
    values[values < 0] = np.nan
    out = np.full((len(frames), len(names)), np.nan)
    at = np.searchsorted(kept, frames)
    hit = (at < len(kept)) & (kept[np.minimum(at, len(kept) - 1)] == frames)
    out[hit] = values[at[hit]]
    return out, names
