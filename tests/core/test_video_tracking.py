"""Sparse LK tracking on synthetic footage written as real video files (known ground truth)."""

import numpy as np
import pytest

pytest.importorskip("cv2")

from facecap.solvers import FacecapError, InputFileError  # noqa: E402
from facecap.solvers.video.reading import Cancelled, Footage  # noqa: E402
from facecap.solvers.video.synthetic import write_synthetic_clip  # noqa: E402
from facecap.solvers.video.tracking import read_seed_points, track_points  # noqa: E402

W, H = 320, 240
FACE = [70, 40, 180, 170]  # x, y, w, h


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return write_synthetic_clip(tmp_path_factory.mktemp("trk") / "face.avi", 60, W, H, noise=2.0)


@pytest.fixture(scope="module")
def mjpg_clip(tmp_path_factory):
    return write_synthetic_clip(tmp_path_factory.mktemp("trk") / "face_mjpg.avi", 40, W, H, codec="MJPG", seed=3)


def errors(result, clip, reference=1):
    """Per-sample distance (px) between tracks and the truth of the same reference points (frame 1 =
    the clip's first frame = motion time 0)."""
    m = clip.motion
    ref_pts = m.inverse(reference - 1, result.markers.positions[list(result.markers.frames).index(reference)])
    rows = result.markers.frames.astype(int) - 1
    truth = np.stack([m.forward(t, ref_pts) for t in rows])
    return np.linalg.norm(result.markers.positions - truth, axis=2)


def seed_file(tmp_path, clip, n=5):
    xs, ys = np.meshgrid(np.linspace(100, 220, n), np.linspace(60, 190, n))
    path = tmp_path / "points2d.csv"
    lines = ["name,x,y"] + [f"pt{i},{x:.2f},{y:.2f}" for i, (x, y) in enumerate(zip(xs.ravel(), ys.ravel()))]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_named_points_from_file_track_within_half_a_pixel(tmp_path, clip):
    res = track_points(clip.path, points=seed_file(tmp_path, clip))
    mk = res.markers
    assert mk.names[:2] == ("pt0", "pt1") and mk.units == "px" and mk.fps == 30.0 and mk.dim == 2
    assert mk.visible.all() and res.confidence.shape == (60, 25)
    assert mk.frames[0] == 1 and mk.frames[-1] == 60 and res.reference == 1  # frame 1 = the first frame
    assert ((res.confidence >= 0) & (res.confidence <= 1)).all() and res.confidence.mean() > 0.8
    err = errors(res, clip)
    assert np.median(err) <= 0.5, np.median(err)  # measured ~0.07 px
    assert np.percentile(err, 95) <= 1.0


def test_auto_features_in_a_region_from_a_middle_reference(clip):
    res = track_points(Footage(clip.path), region=FACE, reference=25, max_points=60)
    mk = res.markers
    assert 30 <= mk.n_markers <= 60 and mk.names[0] == "p000"
    x, y = mk.positions[24, :, 0], mk.positions[24, :, 1]  # frame 25 = row 24
    assert ((x >= 70) & (x < 250) & (y >= 40) & (y < 210)).all()
    err = errors(res, clip, reference=25)
    assert np.median(err) <= 0.5  # tracked backward to frame 0 and forward to 59


def test_compressed_mjpg_footage(mjpg_clip):
    res = track_points(mjpg_clip.path, region=FACE, max_points=50)
    assert np.median(errors(res, mjpg_clip)) <= 0.5


def test_downscaled_tracking_reports_source_pixels(clip):
    res = track_points(Footage(clip.path, scale=0.5), region=FACE, max_points=40)
    assert np.median(errors(res, clip)) <= 0.5


def test_occluded_points_are_lost_reported_and_reseeded(tmp_path):
    box = (60, 120, 110, 70)
    clip = write_synthetic_clip(tmp_path / "occluded.avi", 50, W, H, occlusions=[(15, 24, box)], seed=1)
    res = track_points(clip.path, region=FACE, max_points=60)
    assert res.lost and res.reseeded
    assert set(res.reseeded) <= set(res.lost)
    vis = res.markers.visible
    assert not vis[15:25].all()  # gaps while hidden, never silently wrong positions
    assert vis[-1].all()  # every lost point came back
    err = errors(res, clip)
    assert np.nanmedian(err[25:]) <= 0.5 and np.nanmax(err[30:]) <= 1.5
    assert "losses" in res.summary() and "re-acquisitions" in res.summary()


def test_drift_over_600_frames_is_bounded_by_reregistration(tmp_path):
    clip = write_synthetic_clip(tmp_path / "long.avi", 600, 160, 120, noise=10.0, seed=2)
    region = [40, 20, 80, 85]
    fused = track_points(clip.path, region=region, max_points=30, reregister=True)
    plain = track_points(clip.path, region=region, max_points=30, reregister=False)
    drift_fused = np.nanmedian(errors(fused, clip)[-100:], axis=1).max()
    drift_plain = np.nanmedian(errors(plain, clip)[-100:], axis=1).max()
    print(f"drift over 600 frames: re-registered {drift_fused:.3f} px, continuous only {drift_plain:.3f} px")
    assert drift_fused <= 1.0
    assert drift_plain >= 2.5 * drift_fused


def test_progress_cancels_tracking(clip):
    with pytest.raises(Cancelled):
        track_points(clip.path, region=FACE, progress=lambda done, total: done < 5)


def test_seed_errors_name_the_problem(tmp_path, clip):
    bad = tmp_path / "bad.csv"
    bad.write_text("name,x,y\na,1,2\nb,one,2\n")
    with pytest.raises(InputFileError, match="line 3"):
        read_seed_points(bad)
    bad.write_text("a,1,2\na,3,4\n")
    with pytest.raises(InputFileError, match="duplicate point name 'a'"):
        read_seed_points(bad)
    with pytest.raises(FacecapError, match="outside the 320x240 frame"):
        track_points(clip.path, points=[[10, 10], [400, 10]])
    with pytest.raises(FacecapError, match="exactly one of"):
        track_points(clip.path)
    with pytest.raises(FacecapError, match="region"):
        track_points(clip.path, region=[300, 200, 100, 100])
