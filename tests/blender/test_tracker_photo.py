"""The LK tracker on a real photograph (a studio-light panorama of the bpy wheel, warped, moved and MJPG-coded:
``outside_footage``'s photo kind) beside the plain LK, as tests/core/test_tracker_outside.py does for 1/f noise;
here because the photograph comes with Blender (the core tests run without bpy)."""

import sys
from pathlib import Path

from facecap.solvers.tools.bench.outside_footage import photographs

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
from test_tracker_outside import tracked_beside_plain_lk  # noqa: E402


def test_tracker_at_or_below_plain_lk_on_a_photograph(tmp_path):
    assert photographs(), "the bpy wheel ships its studio-light panoramas"
    tracked_beside_plain_lk("photo_warp_mjpg", tmp_path)  # measured 0.185, 0.207 px vs 0.197, 0.205; none lost
