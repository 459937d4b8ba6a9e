"""The LK tracker on footage the project's scenario generator does not make (``outside_footage``: a 1/f noise image,
a smooth warp of the whole frame, similarity head motion, MJPG; the stress kind too), against the plain pyramidal LK
that re-registers every frame (``reference_trackers.plain_lk``): at or below it within 0.02 px, at most 0.5 % lost.
Small clips keep the suite quick; ``python -m facecap.solvers.tools.bench.outside_footage`` runs 960x720. The
photograph kind needs the bpy wheel's panoramas: tests/blender/test_tracker_photo.py."""

import numpy as np
import pytest

pytest.importorskip("cv2")

from facecap.solvers.tools.bench.outside_footage import outside_clip  # noqa: E402
from facecap.solvers.tools.bench.reference_trackers import plain_lk  # noqa: E402
from facecap.solvers.video.tracking import track_points  # noqa: E402


def _score(pos, truth):
    err = np.linalg.norm(pos - truth, axis=2)[1:]  # frame 1 is the seeds themselves
    lost = np.isnan(err)
    return float(np.median(np.where(lost, np.inf, err))), 100.0 * float(lost.mean())


def tracked_beside_plain_lk(kind, tmp_path):
    """The tracker and the plain LK on two small clips of ``kind``: the test's assertions on the scores."""
    rows = []
    for seed in (0, 1):
        suffix = ".avi" if kind.endswith("mjpg") else ".mkv"
        clip = outside_clip(tmp_path / f"{kind}-{seed}{suffix}", kind, seed=seed, size=(640, 480), frames=40, points=32)
        ours = _score(track_points(str(clip.path), points=clip.seeds).markers.positions, clip.truth)
        plain = _score(plain_lk(clip.path, clip.seeds), clip.truth)
        rows.append((ours, plain))
        print(f"{kind} seed {seed}: ours {ours[0]:.3f} px, {ours[1]:.2f} % lost; plain {plain[0]:.3f} px, "
              f"{plain[1]:.2f} % lost")
    ours_px, plain_px = np.median([r[0][0] for r in rows]), np.median([r[1][0] for r in rows])
    assert ours_px <= plain_px + 0.02, (ours_px, plain_px)
    assert max(r[0][1] for r in rows) <= 0.5
    assert ours_px < 2.0  # the clips are trackable: a broken generator would fail both trackers alike


def test_tracker_at_or_below_plain_lk_on_footage_the_generator_does_not_make(tmp_path):
    tracked_beside_plain_lk("octaves_warp_mjpg", tmp_path)  # measured 0.352, 0.537 px vs 0.407, 0.587; none lost


def test_tracker_at_or_below_plain_lk_on_the_stress_kind(tmp_path):
    # 12 px warp, 5 degrees, 6 % zoom, MJPG at 60: LK's own eigenvalue status lost 1.36 % (seed 1) here before
    # the second try at a lower floor
    tracked_beside_plain_lk("octaves_strong_warp_mjpg", tmp_path)  # measured 0.650, 0.947 px vs 0.734, 1.048; none lost


def test_tracker_at_or_below_plain_lk_on_the_stress_kind_without_the_codec(tmp_path):
    # what the second try at a lower eigenvalue floor must not spoil where the fine detail is intact
    tracked_beside_plain_lk("octaves_strong_warp_ffv1", tmp_path)  # measured 0.225, 0.299 px vs 0.536, 0.618
