"""MarkerSet: named marker trajectories, the common currency of every reader and solver step."""

import copy
from dataclasses import dataclass, field, replace

import numpy as np

from .errors import FacecapError

UNIT_SCALE = {"m": 1.0, "cm": 0.01, "mm": 0.001}


@dataclass(frozen=True, eq=False)
class MarkerSet:
    """Marker positions over frames.

    Attributes
    ----------
    names : tuple of str, length M
        Unique marker names.
    frames : ndarray, shape (F,)
        Frame numbers (integers stored as float64 to allow sub-frame timestamps).
    positions : ndarray, shape (F, M, D)
        D = 2 or 3; NaN marks a gap (all D coordinates of a sample are NaN together).
    fps : float
        Frames per second.
    units : str
        Length unit of ``positions`` ("m", "cm", "mm" or "px" for 2D tracks).
    source : str
        Where the data came from (file path or description), for messages.
    segments : dict
        Optional frame labels, ``{label: [(first_frame, last_frame), ...]}``.
    """

    names: tuple
    frames: np.ndarray
    positions: np.ndarray
    fps: float = 60.0
    units: str = "m"
    source: str = ""
    segments: dict = field(default_factory=dict)

    def __post_init__(self):
        names = tuple(str(n) for n in self.names)
        object.__setattr__(self, "names", names)
        pos = np.asarray(self.positions, dtype=np.float64)
        frames = np.asarray(self.frames, dtype=np.float64)
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "frames", frames)
        where = self.source or "marker set"
        if pos.ndim != 3 or pos.shape[2] not in (2, 3):
            raise FacecapError(f"{where}: positions must have shape (F, M, 2 or 3); got {pos.shape}")
        if pos.shape[0] == 0:
            raise FacecapError(f"{where}: no frames")
        if pos.shape[1] != len(names):
            raise FacecapError(f"{where}: {len(names)} names for {pos.shape[1]} markers")
        if frames.shape != (pos.shape[0],):
            raise FacecapError(f"{where}: frames must have shape ({pos.shape[0]},); got {frames.shape}")
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise FacecapError(f"{where}: duplicate marker names {dup}")
        if np.any(np.diff(frames) <= 0):
            raise FacecapError(f"{where}: frame numbers must increase strictly")
        if not np.isfinite(self.fps) or self.fps <= 0:
            raise FacecapError(f"{where}: fps must be positive; got {self.fps}")
        # One pass over the coordinates finds every sample with a NaN or inf (it poisons the
        # sum; so does an overflowing sum of finite values, which the checks below leave alone);
        # only those few samples are looked at again.
        with np.errstate(over="ignore", invalid="ignore"):
            total = pos[..., 0] + pos[..., 1]
            for d in range(2, pos.shape[2]):
                total += pos[..., d]
        odd = ~np.isfinite(total)
        if odd.any():
            samples = pos[odd]
            if np.isinf(samples).any():
                raise FacecapError(f"{where}: positions contain infinite values")
            # A sample is a gap as a whole: never keep half-missing coordinates.
            nan = np.isnan(samples)
            if (nan.any(axis=1) & ~nan.all(axis=1)).any():
                pos = pos.copy()
                pos[np.isnan(pos).any(axis=2)] = np.nan
                object.__setattr__(self, "positions", pos)

    @property
    def n_frames(self):
        return self.positions.shape[0]

    @property
    def n_markers(self):
        return self.positions.shape[1]

    @property
    def dim(self):
        return self.positions.shape[2]

    @property
    def visible(self):
        """Boolean array (F, M): True where the sample is present."""
        return ~np.isnan(self.positions[:, :, 0])

    def index(self, names, *, what="marker"):
        """Indices of ``names``; raises naming every unknown one."""
        lookup = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in names if n not in lookup]
        if missing:
            raise FacecapError(
                f"{self.source or 'marker set'}: unknown {what}(s) {missing}; "
                f"available: {', '.join(self.names)}"
            )
        return np.array([lookup[n] for n in names], dtype=np.intp)

    def frame_range_mask(self, first, last):
        """Boolean (F,) mask of frames in the inclusive range [first, last]."""
        return (self.frames >= first) & (self.frames <= last)

    def subset(self, names):
        """A MarkerSet with only ``names``, in that order."""
        idx = self.index(names)
        return replace(self, names=tuple(names), positions=self.positions[:, idx])

    def with_positions(self, positions, **changes):
        return replace(self, positions=positions, **changes)

    def _with_mapped_positions(self, positions):
        """``with_positions`` for float64 positions of the same shape computed from these by a
        per-frame affine map (stabilisation): a gap stays a whole gap (NaN spreads to every output
        coordinate) and finite stays finite, so the O(F M) checks are skipped."""
        if positions.shape != self.positions.shape or positions.dtype != np.float64:
            return self.with_positions(positions)
        out = copy.copy(self)
        object.__setattr__(out, "positions", positions)
        return out

    def to_units(self, units):
        """The same data expressed in ``units`` (m, cm or mm)."""
        if units == self.units:
            return self
        if self.units not in UNIT_SCALE or units not in UNIT_SCALE:
            raise FacecapError(f"cannot convert marker units from '{self.units}' to '{units}'")
        factor = UNIT_SCALE[self.units] / UNIT_SCALE[units]
        if factor > 1.0:  # a huge coordinate could overflow: validate as usual
            return replace(self, positions=self.positions * factor, units=units)
        # Scaling down keeps what __post_init__ checks (whole gaps, finite samples): skip its O(F M) passes.
        out = self._with_mapped_positions(self.positions * factor)
        object.__setattr__(out, "units", units)
        return out

    def gap_counts(self):
        """Number of missing samples per marker, as {name: count}."""
        counts = (~self.visible).sum(axis=0)
        return {n: int(c) for n, c in zip(self.names, counts)}
