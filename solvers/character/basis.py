"""Basis: named shapes sampled at the bound marker points, as deltas from neutral."""

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FacecapError, InputFileError
from ..io.files import atomic_path


@dataclass(frozen=True, eq=False)
class Basis:
    """K shapes sampled at M points.

    Attributes
    ----------
    shape_names : tuple of str, length K
    marker_names : tuple of str, length M
    neutral : ndarray, shape (M, D)
        Rest positions of the bound points.
    deltas : ndarray, shape (K, M, D)
        Displacement of each point when a shape is fully on (weight 1).
    lower, upper : ndarray, shape (K,)
        Weight bounds (a shape key's slider range).
    """

    shape_names: tuple
    marker_names: tuple
    neutral: np.ndarray
    deltas: np.ndarray
    lower: np.ndarray = None
    upper: np.ndarray = None

    def __post_init__(self):
        object.__setattr__(self, "shape_names", tuple(self.shape_names))
        object.__setattr__(self, "marker_names", tuple(self.marker_names))
        neutral = np.asarray(self.neutral, dtype=np.float64)
        deltas = np.asarray(self.deltas, dtype=np.float64)
        K, M = len(self.shape_names), len(self.marker_names)
        if neutral.ndim != 2 or neutral.shape[0] != M:
            raise FacecapError(f"basis: neutral must have shape ({M}, D); got {neutral.shape}")
        if deltas.shape != (K, M, neutral.shape[1]):
            raise FacecapError(f"basis: deltas must have shape ({K}, {M}, {neutral.shape[1]}); got {deltas.shape}")
        if not (np.isfinite(neutral).all() and np.isfinite(deltas).all()):
            raise FacecapError("basis: neutral and deltas must be finite")
        lower = np.zeros(K) if self.lower is None else np.asarray(self.lower, dtype=np.float64)
        upper = np.ones(K) if self.upper is None else np.asarray(self.upper, dtype=np.float64)
        if lower.shape != (K,) or upper.shape != (K,) or np.any(lower > upper):
            raise FacecapError("basis: lower/upper must be (K,) arrays with lower <= upper")
        object.__setattr__(self, "neutral", neutral)
        object.__setattr__(self, "deltas", deltas)
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)

    @property
    def n_shapes(self):
        return len(self.shape_names)

    @property
    def n_markers(self):
        return len(self.marker_names)

    def subset_markers(self, names):
        lookup = {n: i for i, n in enumerate(self.marker_names)}
        missing = [n for n in names if n not in lookup]
        if missing:
            raise FacecapError(f"basis: no bound point for marker(s) {missing}")
        idx = [lookup[n] for n in names]
        return Basis(self.shape_names, names, self.neutral[idx], self.deltas[:, idx], self.lower, self.upper)

    def front_view(self):
        """The basis seen by a camera in front of the face (orthographic): image x = X, image y = -Z.

        The character faces -Y with Z up, so this is a 2D basis in the character's units with the
        image convention of tracked footage (x right, y down). Depth (Y) motion is not observed.
        """
        if self.neutral.shape[1] != 3:
            raise FacecapError("front_view needs a 3D basis")
        flip = np.array([1.0, -1.0])
        return Basis(
            self.shape_names,
            self.marker_names,
            self.neutral[:, [0, 2]] * flip,
            self.deltas[:, :, [0, 2]] * flip,
            self.lower,
            self.upper,
        )

    def camera_view(self, camera, *, linearise="tangent"):
        """The basis seen through a ``solvers.camera.Camera`` (perspective), in pixels (x right, y down).

        Deltas are the projection linearised at the neutral, or with ``linearise="secant"`` each shape
        projected exactly at weight 1 (see ``Camera.project_basis`` for why the tangent is the default).
        """
        return camera.project_basis(self, linearise=linearise)

    def matrix(self):
        """The solve matrix A, shape (M * D, K): column k is shape k's flattened deltas."""
        return self.deltas.reshape(self.n_shapes, -1).T

    def save_npz(self, path):
        """Write the basis as a compressed .npz (atomically: never half a file under ``path``)."""
        with atomic_path(path, suffix=".npz") as tmp:
            np.savez_compressed(tmp, shape_names=np.array(self.shape_names), marker_names=np.array(self.marker_names),
                                neutral=self.neutral, deltas=self.deltas, lower=self.lower, upper=self.upper)

    @classmethod
    def load_npz(cls, path):
        """A basis written by ``save_npz``; InputFileError naming the file when it is not one."""
        try:
            with np.load(path, allow_pickle=False) as z:
                return cls(tuple(str(s) for s in z["shape_names"]), tuple(str(s) for s in z["marker_names"]),
                           z["neutral"], z["deltas"], z["lower"], z["upper"])
        except FileNotFoundError:
            raise InputFileError(path, "file not found") from None
        except FacecapError as exc:
            raise InputFileError(path, f"not a valid stored basis: {exc}") from None
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            reason = "empty file" if Path(path).is_file() and Path(path).stat().st_size == 0 else str(exc) or type(exc).__name__
            raise InputFileError(path, f"not a stored basis (.npz written by facecap): {reason}") from None
