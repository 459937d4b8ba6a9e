"""2D takes solved through a scene camera (perspective) versus the orthographic front view."""

from dataclasses import replace
import json
from pathlib import Path

import numpy as np
import pytest

from facecap.solvers import Basis, FacecapError, MarkerSet, RetargetSettings
from facecap.solvers.character.camera import Camera, look_at
from facecap.solvers.pipeline import retarget
from facecap.solvers.tools.synthetic.synth import performance_weights

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"
CENTRE = np.array([0.0, -0.06, 0.0])  # middle of the sample character's bound points


def camera_at(yaw_deg, *, distance=0.55, lens=50.0, resolution=(1280, 720)):
    """A camera looking at the face from the front (-Y), turned ``yaw_deg`` about Z around the face."""
    a = np.radians(yaw_deg)
    location = CENTRE + distance * np.array([np.sin(a), -np.cos(a), 0.0]) + [0.0, 0.0, 0.02]
    return Camera.from_blender(lens=lens, sensor_width=36.0, resolution=resolution, shift=(0.02, -0.03),
                               matrix_world=look_at(location, CENTRE))


def rendered_tracks(basis, weights, camera, stable, *, noise_px=0.3, seed=2):
    """Pixels of the performed face through ``camera``, then in-image head motion (roll, zoom, shift)."""
    rng = np.random.default_rng(seed)
    F = len(weights)
    face = camera.project(basis.neutral[None] + np.einsum("fk,kmd->fmd", weights, basis.deltas))
    t = np.arange(F) / 60
    ramp = np.clip((t - 1) / 0.8, 0, 1)
    roll = np.radians(6) * np.sin(0.7 * t) * ramp
    zoom = 1 + 0.05 * np.sin(0.3 * t) * ramp
    shift = np.stack([25 * np.sin(0.5 * t), 15 * np.cos(0.4 * t) - 15], 1) * ramp[:, None]
    c, s = np.cos(roll) * zoom, np.sin(roll) * zoom
    A = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    centre = np.array([camera.width / 2, camera.height / 2])
    out = (face - centre) @ A.transpose(0, 2, 1) + centre + shift[:, None]
    out += rng.normal(0, noise_px, out.shape)
    return MarkerSet(basis.marker_names, np.arange(1, F + 1), out, fps=60, units="px", source="camera tracks")


@pytest.fixture(scope="module")
def sample():
    basis = Basis.load_npz(SAMPLES / "character_basis.npz")
    layout = json.loads((SAMPLES / "marker_layout.json").read_text())
    stable = tuple(m["name"] for m in layout["markers"] if m["stable"])
    return basis, stable, performance_weights(basis.shape_names, 480, seed=3)


def rmse(result, truth):
    return float(np.sqrt(np.mean((result.weights - truth) ** 2)))


def test_camera_projection_beats_the_front_view_at_25_degrees(sample):
    basis, stable, W = sample
    cam = camera_at(25.0)
    markers = rendered_tracks(basis, W, cam, stable)
    settings = RetargetSettings(stable, (1, 50))
    through = retarget(markers, basis, replace(settings, projection=cam))
    front = retarget(markers, basis, replace(settings, projection="front"))
    e_cam, e_front = rmse(through, W), rmse(front, W)
    print(f"yaw 25 deg: weights RMSE camera {e_cam:.4f}, front view {e_front:.4f}")
    assert e_cam <= 0.06
    assert e_cam < 0.6 * e_front
    assert any("through the camera" in w for w in through.warnings)
    # Residuals stay in the character's units (metres at the face), not pixels.
    assert np.nanmedian(through.residual_rms) < 2e-3


def test_projected_deltas_tangent_and_secant(sample):
    basis, _, W = sample
    cam = camera_at(30.0)
    k = basis.shape_names.index("jawOpen")
    secant = basis.camera_view(cam, linearise="secant")
    np.testing.assert_allclose(secant.neutral + secant.deltas[k], cam.project(basis.neutral + basis.deltas[k]),
                               atol=1e-9)  # exact for a full shape
    tangent = basis.camera_view(cam)
    eps = 1e-6
    numeric = (cam.project(basis.neutral + eps * basis.deltas[k]) - cam.project(basis.neutral)) / eps
    np.testing.assert_allclose(tangent.deltas[k], numeric, atol=1e-4)  # the Jacobian at the neutral
    assert tangent.neutral[:, 0].min() > 0 and tangent.neutral[:, 1].max() < 720  # the face is in the picture
    assert tangent.deltas[k, basis.marker_names.index("chin_C"), 1] > 5  # the jaw drops: image y grows down
    # Over a performance (partial weights, mixtures) the tangent model predicts the pixels better.
    truth = cam.project(basis.neutral[None] + np.einsum("fk,kmd->fmd", W, basis.deltas))
    err = {name: np.sqrt(np.mean((b.neutral + np.einsum("fk,kmd->fmd", W, b.deltas) - truth) ** 2))
           for name, b in (("tangent", tangent), ("secant", secant))}
    print(f"model pixel RMS over the performance: {err}")
    assert err["tangent"] < err["secant"] < 0.5


def test_camera_errors_name_the_problem(sample):
    basis, stable, W = sample
    behind = Camera.from_blender(matrix_world=look_at(CENTRE + [0, 0.5, 0], CENTRE + [0, 1.0, 0]))
    with pytest.raises(FacecapError, match="behind the camera"):
        behind.project(basis.neutral)
    with pytest.raises(FacecapError, match="sensor_fit"):
        Camera.from_blender(sensor_fit="DIAGONAL")
    markers = rendered_tracks(basis, W[:60], camera_at(0.0), stable)
    with pytest.raises(FacecapError, match="projection must be 'front' or a camera"):
        retarget(markers, basis, RetargetSettings(stable, (1, 50), projection="camera"))


CONFIG = """
[target]
object = "Face"
[source]
markers = "tracks.csv"
units = "px"
[stabilise]
markers = ["a", "b", "c"]
[neutral]
frames = [1, 30]
[solve]
"""


@pytest.mark.parametrize("solve,projection,camera,message", [
    ("", "front", None, None),
    ('projection = "camera"', "camera", None, None),
    ('projection = "camera"\ncamera = "Witness Cam"', "camera", "Witness Cam", None),
    ('projection = "fisheye"', None, None, r"\[solve.projection\] expected one of front, camera; got 'fisheye'"),
    ('camera = "Cam"', None, None, r"\[solve.camera\] a camera is only used with projection = \"camera\""),
    ("projection = 1", None, None, r"\[solve.projection\] expected one of front, camera; got 1"),
])
def test_projection_keys_in_the_take_config(tmp_path, solve, projection, camera, message):
    from facecap.solvers import ConfigError, load_take_config

    path = tmp_path / "take.toml"
    path.write_text(CONFIG + solve + "\n")
    if message:
        with pytest.raises(ConfigError, match=message):
            load_take_config(path)
        return
    cfg = load_take_config(path)
    assert (cfg.projection, cfg.camera_name) == (projection, camera)
