"""A performer's response on a camera, per blendshape score: ``w = max(gain * c + offset, 0)`` of the
neutral-corrected score ``c`` (fitted from a ROM clip by ``response.fit_response``; applied by ``fusion.fuse``)."""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError

#: What a score response is saved under in a performer profile.
PROFILE_KEYS = ("response_names", "response_gain", "response_offset", "response_sheet")


@dataclass(frozen=True, eq=False)
class ScoreResponse:
    """Per score name, ``gain`` and ``offset`` (S,): ``w = max(gain * c + offset, 0)``; a callable
    ``(corrected (F, S), names) -> (F, S)`` as ``FaceScores.response`` wants it. Scores it does not name pass
    unchanged; ``sheet`` says what it was measured with."""

    names: tuple
    gain: np.ndarray
    offset: np.ndarray
    sheet: str = ""

    def __post_init__(self):
        gain, offset = np.asarray(self.gain, dtype=np.float64), np.asarray(self.offset, dtype=np.float64)
        if gain.shape != (len(self.names),) or offset.shape != (len(self.names),):
            raise FacecapError(f"a score response needs a gain and an offset per name ({len(self.names)}); got "
                               f"{gain.shape} and {offset.shape}")
        if not (np.isfinite(gain).all() and np.isfinite(offset).all()) or (gain <= 0).any():
            raise FacecapError("a score response's gains must be positive and its offsets finite")
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))
        object.__setattr__(self, "gain", gain)
        object.__setattr__(self, "offset", offset)

    def __call__(self, corrected, names):
        c = np.array(corrected, dtype=np.float64)
        mine = {n: j for j, n in enumerate(self.names)}
        for k, name in enumerate(names):
            j = mine.get(str(name))
            if j is not None:
                with np.errstate(invalid="ignore"):  # NaN (no face) stays NaN
                    c[:, k] = np.maximum(self.gain[j] * c[:, k] + self.offset[j], 0.0)
        return c

    def changed(self, tol=1e-9):
        """The names whose response is not the identity."""
        return tuple(n for n, g, o in zip(self.names, self.gain, self.offset) if abs(g - 1) > tol or abs(o) > tol)

    def to_arrays(self):
        """{key: array} for a performer profile (``PROFILE_KEYS``)."""
        return {"response_names": np.array(self.names, dtype=str), "response_gain": self.gain,
                "response_offset": self.offset, "response_sheet": np.array(self.sheet)}

    @classmethod
    def from_arrays(cls, data, *, where="the performer profile"):
        """The response saved by ``to_arrays`` in ``data`` (a mapping), or None when it holds none."""
        if "response_gain" not in data:
            return None
        try:
            return cls(tuple(str(n) for n in data["response_names"]), data["response_gain"],
                       data["response_offset"], str(data["response_sheet"]) if "response_sheet" in data else "")
        except (KeyError, ValueError, TypeError) as exc:
            raise FacecapError(f"{where}: its score response is damaged ({exc})") from None
