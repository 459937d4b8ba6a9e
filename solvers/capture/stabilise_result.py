"""The result of a stabilisation (3D rigid/similarity or 2D image tracks): stabilised markers and
the head motion removed."""

from dataclasses import dataclass, field, replace

import numpy as np

from ..markers import MarkerSet


class LazyMarkers:
    """Descriptor of the ``markers`` field: accepts an object with a ``compute()`` method (the
    stabilised markers not computed yet, e.g. ``stabilise._MovedMarkers``) and computes it once;
    the computation is kept, so that the computed markers can be let go (``release_markers``)."""

    def __set_name__(self, owner, name):
        self.slot = "_" + name

    def __get__(self, obj, owner=None):
        if obj is None:
            raise AttributeError(self.slot)  # tells dataclass the field has no default
        value = obj.__dict__[self.slot]
        if not isinstance(value, MarkerSet):
            value = value.compute()
            obj.__dict__[self.slot] = value
        return value

    def __set__(self, obj, value):
        obj.__dict__[self.slot] = value
        if not isinstance(value, MarkerSet):
            obj.__dict__[self.slot + "_source"] = value

    def release(self, obj):
        """Forget the computed markers of ``obj`` if they can be computed again."""
        source = obj.__dict__.get(self.slot + "_source")
        if source is not None:
            obj.__dict__[self.slot] = source


@dataclass(frozen=True, eq=False)
class StabiliseResult:
    """Stabilised markers plus the head motion that was removed.

    ``markers`` holds every marker in the reference head frame; frames whose fit is not
    determined (``flagged``) are all gaps there, never silently wrong.
    The head pose of frame f is ``x_raw = R_f^T (x_stab - t_f)``, i.e. the inverse of
    (``rotations[f]``, ``translations[f]``).
    """

    markers: MarkerSet = LazyMarkers()  # computed on first access when given as a deferred computation
    stable_names: tuple
    reference: np.ndarray  # (S, 3) stable markers in the reference head frame
    rotations: np.ndarray  # (F, 3, 3) raw -> stabilised
    translations: np.ndarray  # (F, 3)
    rms: np.ndarray  # (F,) residual of the stable markers after the fit (NaN where flagged)
    flagged: np.ndarray  # (F,) bool
    flag_reasons: dict = field(default_factory=dict)  # frame number -> reason
    unreliable: np.ndarray = None  # (F,) bool: fitted, but too few stable markers agreed (robust fit)
    marker_trust: dict = field(default_factory=dict)  # stable marker -> mean robust weight (1 = rigid)
    scales: np.ndarray = None  # (F,) uniform scale raw -> stabilised (mode "similarity"); None = 1
    mode: str = "rigid"

    def scale_array(self):
        """(F,) per-frame scale raw -> stabilised (ones for a rigid fit)."""
        return np.ones(len(self.rotations)) if self.scales is None else self.scales

    def head_rotations(self):
        """Head rotation per frame relative to the reference (raw = R_head @ stabilised + ...)."""
        return self.rotations.transpose(0, 2, 1)

    def release_markers(self):
        """Let the computed stabilised markers go: they are computed again (the same numbers, bit for
        bit) if read later. Their (F, M, 3) floats are, with the raw take, a long take's largest
        arrays; a caller that has taken what it needs from them frees them with this (results made
        from a per-frame pose keep how to compute them; others keep their markers)."""
        type(self).__dict__["markers"].release(self)

    def without_markers(self):
        """This result without its stabilised markers (their (F, M, 3) floats, or the raw take a
        deferred computation of them holds, can then be freed): the head poses, flags and
        diagnostics only. Reading ``markers`` afterwards raises RuntimeError."""
        return replace(self, markers=_Released())


class _Released:
    """The ``markers`` of a result that let them go (``StabiliseResult.without_markers``)."""

    def compute(self):
        raise RuntimeError("the stabilised markers of this result were released (only its head poses were kept)")


def frame_label(frame):
    """A frame number as a report key: an int when whole."""
    return int(frame) if float(frame).is_integer() else float(frame)


def frame_rms(err):
    """Root mean square of each frame's (row's) finite values; NaN for a frame with none (a flagged
    frame), without numpy's empty-slice warning. The same numbers as ``nanmean``'s."""
    finite = np.isfinite(err)
    total = (np.where(finite, err, 0.0) ** 2).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(total / finite.sum(axis=1))
