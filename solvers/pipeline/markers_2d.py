"""2D image tracks (video takes): which strategies solve them, and the character as the tracks see it
(the orthographic front view, or the scene camera: ``solvers.character.camera``).

The take itself is prepared like any other (``stages.prepare_take``: a per-frame 2D similarity on
the stable points removes in-plane head motion and distance to the camera; out-of-plane head turns
are not removed).
"""

from ..character.basis import Basis
from ..character.camera import Camera
from ..errors import FacecapError

#: marker strategies that solve 2D image tracks natively (their fits are dimension-free); geometric
#: solves them against the projected character
STRATEGIES_2D = ("geometric", "calibrated", "linear", "rbf", "pca")

NOTE_PIXELS = "2D take: residuals are in pixels of the footage"


def check_2d(settings, inputs):
    """Refuse what 2D tracks cannot be solved with: another strategy, or 3D learning inputs."""
    if settings.strategy not in STRATEGIES_2D:
        raise FacecapError(f"strategy '{settings.strategy}' does not solve 2D image tracks; "
                           f"use one of {', '.join(STRATEGIES_2D)}")
    for what, take in (("[calibration] markers", inputs.calibration),
                       ("[examples] markers", getattr(inputs.examples, "markers", None))):
        if take is not None and take.dim != 2:
            raise FacecapError(f"{what}: a 2D take needs 2D tracks here too; got {take.dim}D markers")


def projected(basis, projection):
    """(2D basis, note) of the character for ``projection``: None / "front" or a Camera.

    ``projection`` a ``solvers.character.camera.Camera`` seeing the basis' coordinates
    (``Camera.relative_to`` the character's world matrix): shape deltas projected through it
    linearised at the neutral (``Camera.project_basis``), scaled by the units a pixel spans at the
    face so residuals read in scene units (metres for a metre-scale rig), as with the front view.
    """

    if projection is None or projection == "front":
        return basis.front_view(), "2D take: solved against the character's front view (depth motion is not observed)"
    if not isinstance(projection, Camera):
        raise FacecapError(f"2D takes: projection must be 'front' or a camera; got {projection!r} "
                           "(projection = \"camera\" needs the scene camera read from the .blend)")
    seen = basis.camera_view(projection)
    unit = projection.units_per_pixel(basis.neutral)
    scaled = Basis(seen.shape_names, seen.marker_names, seen.neutral * unit, seen.deltas * unit, seen.lower, seen.upper)
    return scaled, (f"2D take: solved against the character seen through the camera "
                    f"({unit * 1e3:.3f} mm (scene units x 1000) per pixel at the face; depth motion along the view is "
                    "not observed)")
