"""What the semantic solve knows of the actor, carried into the take's actor space: the character's shapes at the
take's markers (through the actor -> character alignment) and the human template fitted to the take's neutral."""

import numpy as np

from ..capture.align import align_actor
from ..character.basis import Basis
from ..errors import FacecapError


def character_in_actor_space(character, names, neutral, settings):
    """(the character's shapes at the take's markers in actor space (K, M, 3), NaN rows for markers not bound
    on the character; the actor -> character Alignment; the bound markers it aligns), or (None, None, ()) when
    ``character`` has no geometry."""
    if not isinstance(character, Basis):
        return None, None, ()
    bound = [n for n in character.marker_names if n in set(names)]
    if len(bound) < 3:
        return None, None, ()
    idx = [names.index(n) for n in bound]
    align = align_actor(neutral[idx], character.subset_markers(bound).neutral, tuple(bound),
                        regions=settings.align_regions, flag_mm=settings.align_flag_mm)
    out = np.full((character.n_shapes, len(names), 3), np.nan)
    cols = [character.marker_names.index(n) for n in bound]
    out[:, idx] = align.inverse_vectors(character.deltas[:, cols])
    return out, align, tuple(bound)


def fit_template(template, names, neutral, align):
    """The human template fitted to the take's neutral (actor space): a TemplateFit. Fitted from two starts, the
    markers turned upright by the actor -> character alignment and the automatic multi-start search (when it
    does not refuse), and the fit of lower cost kept: each is fitted to convergence, so the choice does not
    move with the arithmetic's rounding (a threshold on an unconverged fit's residual did)."""
    fits = []
    if align is not None:
        fits.append(template.fit(names, neutral, orientation=align.rotation))
    try:
        fits.append(template.fit_automatic(names, neutral))
    except FacecapError:
        if not fits:
            raise
    return min(fits, key=lambda f: f.objective)
