"""PCA of dense flow over a face region: a markerless basis and per-frame source features.

Each frame's flow (relative to the neutral reference, cropped and subsampled) is one vector of
length D = h * w * 2. ``center="mean"`` centres on the take's mean flow (the thesis);
``center="reference"`` keeps the neutral (zero flow) as the origin, so coefficients 0 = neutral.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError


@dataclass(frozen=True, eq=False)
class FlowPCA:
    """Principal components of flow fields.

    components : (P, D) orthonormal rows; mean : (D,); coefficients : (F, P) of the fitted frames;
    explained_variance, explained_variance_ratio : (P,); shape : (h, w, 2) of one field.
    """

    components: np.ndarray
    mean: np.ndarray
    coefficients: np.ndarray
    explained_variance: np.ndarray
    explained_variance_ratio: np.ndarray
    shape: tuple
    frames: np.ndarray = None

    @property
    def n_components(self):
        return self.components.shape[0]

    def project(self, flows):
        """Coefficients (N, P) of flow fields (N, h, w, 2)."""
        X = np.asarray(flows, np.float64).reshape(len(flows), -1)
        if X.shape[1] != self.mean.size:
            raise FacecapError(f"`flows` must have fields of shape {self.shape}; got {np.shape(flows)[1:]}")
        return (X - self.mean) @ self.components.T

    def reconstruct(self, coefficients):
        """Flow fields (N, h, w, 2) from coefficients (N, P)."""
        c = np.atleast_2d(np.asarray(coefficients, np.float64))
        return (c @ self.components + self.mean).reshape((len(c),) + tuple(self.shape))

    def component_fields(self):
        """The components as fields (P, h, w, 2)."""
        return self.components.reshape((self.n_components,) + tuple(self.shape))


def flow_pca(flows, *, n_components=20, variance=None, center="mean", frames=None):
    """PCA of flow fields (F, h, w, 2) (e.g. ``DenseFlowResult.flows``).

    Parameters
    ----------
    n_components : int
        Components kept (at most F - 1 with ``center="mean"``, F otherwise).
    variance : float, optional
        Instead: the fewest components explaining this fraction (0, 1] of the variance.
    center : "mean" or "reference"
        Subtract the mean flow, or keep the neutral reference (zero flow) as the origin.
    """
    X = np.asarray(flows, np.float64)
    if X.ndim != 4 or X.shape[-1] != 2 or len(X) < 2:
        raise FacecapError(f"`flows` must have shape (F >= 2, h, w, 2); got {X.shape}")
    if not np.isfinite(X).all():
        raise FacecapError("`flows` contain NaN or infinite values")
    if center not in ("mean", "reference"):
        raise FacecapError(f"`center` must be 'mean' or 'reference'; got {center!r}")
    shape = X.shape[1:]
    X = X.reshape(len(X), -1)
    mean = X.mean(axis=0) if center == "mean" else np.zeros(X.shape[1])
    Xc = X - mean
    U, S, Vt = np.linalg.svd(Xc, full_matrices=False)
    var = S**2 / max(len(X) - 1, 1)
    total = var.sum()
    ratio = var / total if total > 0 else np.zeros_like(var)
    rank = int(np.sum(S > S[0] * 1e-10)) if S.size and S[0] > 0 else 0
    if variance is not None:
        if not 0 < variance <= 1:
            raise FacecapError(f"`variance` must be in (0, 1]; got {variance}")
        P = int(np.searchsorted(np.cumsum(ratio), variance - 1e-12) + 1)
    else:
        if int(n_components) < 1:
            raise FacecapError(f"`n_components` must be >= 1; got {n_components}")
        P = int(n_components)
    P = max(1, min(P, rank if rank else 1))
    # Sign convention: the largest-magnitude entry of each component is positive (deterministic).
    comps = Vt[:P]
    signs = np.sign(comps[np.arange(P), np.argmax(np.abs(comps), axis=1)])
    signs[signs == 0] = 1
    comps = comps * signs[:, None]
    coeffs = Xc @ comps.T
    return FlowPCA(comps, mean, coeffs, var[:P], ratio[:P], shape,
                   None if frames is None else np.asarray(frames, float))
