"""2D stabilisation of image tracks (the one implementation, solvers.stabilise.stabilise_2d), and the
video package's import hygiene."""

import subprocess
import sys

import numpy as np
import pytest

from facecap.solvers import FacecapError, MarkerSet
from facecap.solvers.capture.stabilise import stabilise_2d, transforms_2d


def moving_tracks(F=20, seed=0, model="similarity"):
    rng = np.random.default_rng(seed)
    ref = rng.uniform(0, 300, size=(10, 2))
    A = np.empty((F, 2, 2))
    a, s = rng.normal(0, 0.1, F), 1 + rng.normal(0, 0.05, F)
    A[:] = np.stack([[s * np.cos(a), -s * np.sin(a)], [s * np.sin(a), s * np.cos(a)]]).transpose(2, 0, 1)
    if model == "affine":
        A += rng.normal(0, 0.03, size=(F, 2, 2))
    t = rng.normal(0, 8, size=(F, 2))
    A[0], t[0] = np.eye(2), 0
    pos = np.einsum("fij,mj->fmi", A, ref) + t[:, None]
    return MarkerSet([f"m{i}" for i in range(10)], np.arange(1, F + 1), pos, units="px"), ref


@pytest.mark.parametrize("model", ["similarity", "affine"])
def test_head_motion_is_removed_exactly(model):
    mk, ref = moving_tracks(model=model)
    res = stabilise_2d(mk, ["m0", "m1", "m2", "m3", "m4"], mode=model)
    np.testing.assert_allclose(res.markers.positions, np.broadcast_to(ref, mk.positions.shape), atol=1e-9)
    assert transforms_2d(res).shape == (20, 2, 3) and np.nanmax(res.rms) < 1e-9 and not res.flagged.any()


def test_a_moving_stable_point_is_outvoted_and_gaps_are_flagged():
    mk, ref = moving_tracks()
    pos = mk.positions.copy()
    pos[:, 0] += [15.0, -10.0]  # "stable" m0 actually moves
    pos[5, 1:] = np.nan  # frame 6: only m0 left
    res = stabilise_2d(mk.with_positions(pos), ["m0", "m1", "m2", "m3", "m4", "m5"])
    plain = stabilise_2d(mk.with_positions(pos), ["m0", "m1", "m2", "m3", "m4", "m5"], robust=False)
    assert np.nanmax(np.abs(plain.markers.positions[:, 1:] - ref[1:])) > 0.3  # least squares alone is pulled off
    good = ~res.flagged
    assert res.flagged.tolist() == [i == 5 for i in range(20)]
    assert np.isnan(res.markers.positions[5]).all()
    np.testing.assert_allclose(res.markers.positions[good][:, 1:], np.broadcast_to(ref[1:], (19, 9, 2)), atol=1e-6)
    with pytest.raises(FacecapError, match="needs 2D markers"):
        stabilise_2d(MarkerSet(["a"], [1], np.zeros((1, 1, 3))), ["a"])
    with pytest.raises(FacecapError, match="unknown stable marker"):
        stabilise_2d(mk, ["nose", "m1"])
    with pytest.raises(FacecapError, match="need at least 3 stable points"):
        stabilise_2d(mk, ["m0", "m1"], mode="affine")


def test_importing_the_video_package_loads_neither_blender_nor_opencv():
    code = "import sys, facecap.solvers.video; print(sorted(m for m in ('bpy', 'mathutils', 'cv2') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
