"""A pinhole (or orthographic) camera model matching Blender's camera, in image pixels.

Pixels have their origin at the top-left corner of the image and y growing downwards, like the
2D tracks of footage (``solvers.video``) and a movie clip's markers converted by
``facecap_addon.scene.video_scene``. The model follows Blender's view plane
(``BKE_camera_params_compute_viewplane``): the sensor fit picks the image dimension the sensor
size spans (``AUTO``: the larger one, with the sensor *width*), and the lens shift is a fraction
of that dimension. Blender's camera looks down its local -Z with +Y up.

Never imports Blender: ``facecap_addon.scene.scene_camera.camera_from_scene`` reads a camera object into
:meth:`Camera.from_blender`.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError
from .basis import Basis

SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")


@dataclass(frozen=True, eq=False)
class Camera:
    """Pixels ``u = cx + fx * x / z``, ``v = cy - fy * y / z`` of a camera-space point (x, y, -z).

    Attributes
    ----------
    fx, fy : float
        Focal lengths in pixels (orthographic: pixels per unit).
    cx, cy : float
        Principal point in pixels (origin top-left, y down).
    width, height : int
        Image size in pixels.
    world_to_camera : ndarray (4, 4)
        Rigid map from world (or, after :meth:`relative_to`, object) coordinates to camera space.
    orthographic : bool
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    world_to_camera: np.ndarray
    orthographic: bool = False

    @classmethod
    def from_blender(cls, *, lens=50.0, sensor_width=36.0, sensor_height=24.0, sensor_fit="AUTO",
                     resolution=(1920, 1080), shift=(0.0, 0.0), matrix_world=None, pixel_aspect=(1.0, 1.0),
                     orthographic=False, ortho_scale=6.0):
        """The camera as Blender defines it.

        Parameters
        ----------
        lens : float
            Focal length (mm), ``Camera.lens``.
        sensor_width, sensor_height : float
            Sensor size (mm); ``sensor_height`` only counts for ``sensor_fit = "VERTICAL"``.
        sensor_fit : "AUTO", "HORIZONTAL" or "VERTICAL"
        resolution : (width, height)
            Image size in pixels (the render resolution times its percentage, or the footage's).
        shift : (shift_x, shift_y)
            Lens shift as a fraction of the fitted image dimension.
        matrix_world : array (4, 4)
            The camera object's world matrix (scale is ignored, as Blender's projection does).
        pixel_aspect : (x, y)
            ``render.pixel_aspect_x`` / ``_y``.
        orthographic, ortho_scale : an orthographic camera and its view width (units).
        """
        if sensor_fit not in SENSOR_FITS:
            raise FacecapError(f"camera: `sensor_fit` must be one of {SENSOR_FITS}; got {sensor_fit!r}")
        width, height = (int(v) for v in resolution)
        if width < 1 or height < 1:
            raise FacecapError(f"camera: `resolution` must be positive; got {tuple(resolution)}")
        if orthographic:
            if not ortho_scale > 0:
                raise FacecapError(f"camera: `ortho_scale` must be positive; got {ortho_scale}")
        elif not (lens > 0 and sensor_width > 0 and sensor_height > 0):
            raise FacecapError(f"camera: lens and sensor size must be positive; got lens {lens}, "
                               f"sensor {sensor_width} x {sensor_height}")
        xasp, yasp = (float(v) for v in pixel_aspect)
        ycor = yasp / xasp
        fit = sensor_fit
        if fit == "AUTO":
            fit = "HORIZONTAL" if width * xasp >= height * yasp else "VERTICAL"
        viewfac = width if fit == "HORIZONTAL" else ycor * height  # pixels the sensor spans
        if orthographic:
            fx = viewfac / ortho_scale
        else:
            sensor = sensor_height if sensor_fit == "VERTICAL" else sensor_width  # AUTO always uses the width
            fx = lens / sensor * viewfac
        cx = 0.5 * width - shift[0] * viewfac
        cy = 0.5 * height + shift[1] * viewfac / ycor
        M = np.eye(4) if matrix_world is None else np.asarray(matrix_world, dtype=np.float64)
        if M.shape != (4, 4) or not np.isfinite(M).all():
            raise FacecapError(f"camera: `matrix_world` must be a finite 4x4 matrix; got shape {M.shape}")
        R = M[:3, :3] / np.linalg.norm(M[:3, :3], axis=0)  # drop scale, as matrix_world.normalized()
        w2c = np.eye(4)
        w2c[:3, :3] = R.T
        w2c[:3, 3] = -R.T @ M[:3, 3]
        return cls(float(fx), float(fx / ycor), float(cx), float(cy), width, height, w2c, bool(orthographic))

    def relative_to(self, object_matrix):
        """The same camera seeing coordinates local to an object with world matrix ``object_matrix``."""
        M = np.asarray(object_matrix, dtype=np.float64)
        if M.shape != (4, 4):
            raise FacecapError(f"camera: `object_matrix` must be 4x4; got shape {M.shape}")
        return Camera(self.fx, self.fy, self.cx, self.cy, self.width, self.height, self.world_to_camera @ M,
                      self.orthographic)

    def to_camera(self, points):
        """Camera-space coordinates (..., 3) of points (..., 3)."""
        p = np.asarray(points, dtype=np.float64)
        return p @ self.world_to_camera[:3, :3].T + self.world_to_camera[:3, 3]

    def depth(self, points):
        """Distance in front of the camera along its view axis (..., ); positive = visible."""
        return -self.to_camera(points)[..., 2]

    def project(self, points):
        """Pixels (..., 2) of points (..., 3); raises if a point is not in front of the camera."""
        c = self.to_camera(points)
        z = -c[..., 2]
        if self.orthographic:
            z = np.ones_like(z)
        elif np.any(z <= 1e-9):
            raise FacecapError(f"camera: {int(np.sum(z <= 1e-9))} point(s) are behind the camera or on its plane")
        return np.stack([self.cx + self.fx * c[..., 0] / z, self.cy - self.fy * c[..., 1] / z], axis=-1)

    def units_per_pixel(self, points):
        """Scene units one pixel spans at the points' mean depth (1 / fx for an orthographic camera)."""
        if self.orthographic:
            return 1.0 / self.fx
        return float(np.mean(self.depth(points))) / self.fx

    def project_basis(self, basis, *, linearise="tangent"):
        """A 2D Basis in pixels: ``neutral = P(x0)`` and per-shape image deltas.

        ``linearise="tangent"`` (default): ``deltas[k] = J(x0) d_k``, the projection linearised at
        the neutral; ``"secant"``: ``P(x0 + d_k) - P(x0)``, each shape exact at weight 1. The solve
        model is linear in the weights, so one of them is off by second-order perspective terms:
        the secant is exact for a lone shape at full weight but wrong at half weight, the tangent
        exact near the neutral. Performances live mostly at partial weights and in mixtures, so the
        tangent is the default: on the sample character's synthetic performance seen at 25 degrees
        yaw from 0.55 m (noise-free, no priors) weights RMSE 0.0010 (tangent) vs 0.0040 (secant).
        ``basis`` is in the coordinates the camera sees (world, or object-local after :meth:`relative_to`).
        """

        if basis.neutral.shape[1] != 3:
            raise FacecapError("camera: project_basis needs a 3D basis")
        if linearise not in ("tangent", "secant"):
            raise FacecapError(f"camera: `linearise` must be 'tangent' or 'secant'; got {linearise!r}")
        p0 = self.project(basis.neutral)
        if linearise == "secant":
            deltas = self.project(basis.neutral[None] + basis.deltas) - p0[None]
        else:
            c = self.to_camera(basis.neutral)  # (M, 3)
            dc = basis.deltas @ self.world_to_camera[:3, :3].T  # (K, M, 3) camera-space deltas
            if self.orthographic:
                deltas = np.stack([self.fx * dc[..., 0], -self.fy * dc[..., 1]], axis=-1)
            else:
                z = -c[:, 2]
                du = self.fx * (dc[..., 0] / z + c[:, 0] * dc[..., 2] / z**2)
                dv = -self.fy * (dc[..., 1] / z + c[:, 1] * dc[..., 2] / z**2)
                deltas = np.stack([du, dv], axis=-1)
        return Basis(basis.shape_names, basis.marker_names, p0, deltas, basis.lower, basis.upper)


def look_at(location, target, *, up=(0.0, 0.0, 1.0)):
    """A Blender camera world matrix at ``location`` looking at ``target`` (camera +Y towards ``up``)."""
    location, target = np.asarray(location, float), np.asarray(target, float)
    back = location - target  # the camera's +Z points away from what it sees
    n = np.linalg.norm(back)
    if n == 0:
        raise FacecapError("look_at: location and target coincide")
    z = back / n
    x = np.cross(np.asarray(up, float), z)
    if np.linalg.norm(x) < 1e-9:
        raise FacecapError("look_at: the view direction is parallel to `up`")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = x, y, z, location
    return M
