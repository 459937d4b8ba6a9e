"""Tracking a movie clip's footage from its own track markers, as an artist would in the sidebar."""

import bpy
import numpy as np
import pytest

from facecap.facecap_addon import take
from facecap.solvers.video.synthetic import write_synthetic_clip


@pytest.fixture
def clip(empty_scene, tmp_path):
    synth = write_synthetic_clip(tmp_path / "face.avi", 24, 320, 240, seed=3)
    clip = bpy.data.movieclips.load(synth.path)
    bpy.context.scene.active_clip = clip
    bpy.context.scene.frame_current = 1
    return clip, synth


def test_tracks_follow_the_footage(clip):
    clip, synth = clip
    width, height = clip.size
    assert (width, height) == (320, 240)
    seeds = np.array([[120.0, 100.0], [200.0, 110.0], [160.0, 170.0]])
    for i, (x, y) in enumerate(seeds):
        track = clip.tracking.tracks.new(name=f"p{i}", frame=1)
        track.markers.insert_frame(1, co=(x / width, 1.0 - y / height))
    assert bpy.ops.facecap.track_clip() == {"FINISHED"}
    markers = take.markers_from_collection(bpy.context.scene.facecap)
    assert markers.n_markers == 3 and markers.n_frames == 24
    # Empties show pixels in the XZ plane at 1 px = 1 mm (image y down).
    order = [markers.names.index(f"p{i}") for i in range(3)]
    px = np.stack([markers.positions[:, order, 0], -markers.positions[:, order, 2]], axis=2) * 1000.0
    truth = np.stack([synth.motion.forward(t, seeds) for t in range(24)])
    err = np.linalg.norm(px - truth, axis=2)
    assert np.nanmedian(err) <= 0.5


def test_clip_without_markers_needs_a_region(clip):
    with pytest.raises(RuntimeError, match="no enabled track markers at frame 1"):
        bpy.ops.facecap.track_clip()
    assert bpy.ops.facecap.track_clip(region=(80, 60, 160, 120), max_points=20) == {"FINISHED"}
