"""Tracking a movie clip's footage from its own track markers, as an artist would in the sidebar."""

from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from facecap.facecap_addon.scene import take
from facecap.solvers.video.synthetic import write_synthetic_clip
from scene_fixtures import modal_driver


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
    assert markers.dim == 2 and markers.units == "px"  # drawn in the XZ plane, read back as pixels
    px = markers.positions[:, order]
    truth = np.stack([synth.motion.forward(t, seeds) for t in range(24)])
    err = np.linalg.norm(px - truth, axis=2)
    assert np.nanmedian(err) <= 0.5


def test_clip_without_markers_needs_a_region(clip):
    with pytest.raises(RuntimeError, match="no enabled track markers at frame 1"):
        bpy.ops.facecap.track_clip()
    assert bpy.ops.facecap.track_clip(region=(80, 60, 160, 120), max_points=20) == {"FINISHED"}


def test_cancelling_after_a_chunk_leaves_the_scene_untouched(clip):
    """The modal operator's steps, driven directly: track a chunk, cancel, nothing written."""
    from facecap.facecap_addon.scene.video_scene import ClipTracking
    from facecap.solvers.video import Cancelled

    clip, _ = clip
    scene = bpy.context.scene
    before = (set(bpy.data.collections.keys()), set(bpy.data.objects.keys()), set(bpy.data.actions.keys()),
              scene.facecap.take_name, len(scene.facecap.markers), scene.frame_start, scene.frame_end)
    session = ClipTracking(scene, clip, 1, region=(80, 60, 160, 120), max_points=20)
    assert session.step(5) is False
    assert session.job.done == 5 and session.job.frame == 5 and session.result is None
    assert "frame 5 (5/24)" in session.status()
    session.cancel()
    session.cancel()  # Esc twice is harmless
    with pytest.raises(Cancelled, match="cancelled at frame 5"):
        session.step()
    after = (set(bpy.data.collections.keys()), set(bpy.data.objects.keys()), set(bpy.data.actions.keys()),
             scene.facecap.take_name, len(scene.facecap.markers), scene.frame_start, scene.frame_end)
    assert after == before


def test_stepping_to_the_end_gives_the_same_tracks_as_one_run(clip):
    from facecap.facecap_addon.scene.video_scene import ClipTracking

    clip, _ = clip
    scene = bpy.context.scene
    stepped = ClipTracking(scene, clip, 1, region=(80, 60, 160, 120), max_points=20)
    ticks = 0
    while not stepped.step(4):
        ticks += 1
    whole = ClipTracking(scene, clip, 1, region=(80, 60, 160, 120), max_points=20).run()
    assert ticks == 6 and stepped.job.done == 24
    np.testing.assert_array_equal(stepped.result.markers.positions, whole.markers.positions)
    # Background mode: INVOKE falls back to running to completion.
    assert bpy.ops.facecap.track_clip("INVOKE_DEFAULT", region=(80, 60, 160, 120), max_points=20) == {"FINISHED"}


def _driver():
    from facecap.operators.video import FACECAP_OT_track_clip

    return modal_driver(FACECAP_OT_track_clip)


def scene_state(scene):
    return (set(bpy.data.collections.keys()), set(bpy.data.objects.keys()), set(bpy.data.actions.keys()),
            scene.facecap.take_name, len(scene.facecap.markers))


def test_modal_timer_ticks_then_esc_cancels_with_nothing_written(clip, monkeypatch):
    from facecap.facecap_addon.scene.video_scene import ClipTracking
    from facecap.operators import video as video_ops

    monkeypatch.setattr(video_ops, "STEP_SECONDS", 0.0)  # one frame per tick
    clip, _ = clip
    context, scene = bpy.context, bpy.context.scene
    before = scene_state(scene)
    driver = _driver()(ClipTracking(scene, clip, 1, region=(80, 60, 160, 120), max_points=20))
    tick, esc = SimpleNamespace(type="TIMER", value="NOTHING"), SimpleNamespace(type="ESC", value="PRESS")
    assert [driver.modal(context, tick) for _ in range(3)] == [{"RUNNING_MODAL"}] * 3
    assert driver.modal(context, SimpleNamespace(type="MOUSEMOVE", value="NOTHING")) == {"PASS_THROUGH"}
    assert driver._session.job.done == 3
    assert driver.modal(context, esc) == {"CANCELLED"}
    assert driver.reports == [("WARNING", "Tracking cancelled at frame 3; nothing was added to the scene")]
    assert scene_state(scene) == before


def test_modal_timer_ticks_to_the_end_and_adds_the_take(clip, monkeypatch):
    from facecap.facecap_addon.scene.video_scene import ClipTracking
    from facecap.operators import video as video_ops

    monkeypatch.setattr(video_ops, "STEP_SECONDS", 0.0)
    clip, _ = clip
    context, scene = bpy.context, bpy.context.scene
    driver = _driver()(ClipTracking(scene, clip, 1, region=(80, 60, 160, 120), max_points=20))
    tick = SimpleNamespace(type="TIMER", value="NOTHING")
    results = [driver.modal(context, tick) for _ in range(25)]
    assert results[:24] == [{"RUNNING_MODAL"}] * 24 and results[24] == {"FINISHED"}
    assert scene.facecap.take_name == f"{clip.name} tracks" and len(scene.facecap.markers) >= 5
    assert driver.reports[-1][0] == "INFO" and "over 24 frames" in driver.reports[-1][1]


def test_dense_flow_tracking_of_the_clip(clip):
    clip, synth = clip
    width, height = clip.size
    seeds = np.array([[120.0, 100.0], [200.0, 110.0], [160.0, 170.0]])
    for i, (x, y) in enumerate(seeds):
        track = clip.tracking.tracks.new(name=f"p{i}", frame=1)
        track.markers.insert_frame(1, co=(x / width, 1.0 - y / height))
    assert bpy.ops.facecap.track_clip(method="dis") == {"FINISHED"}
    markers = take.markers_from_collection(bpy.context.scene.facecap)
    order = [markers.names.index(f"p{i}") for i in range(3)]
    assert markers.dim == 2 and markers.units == "px"  # drawn in the XZ plane, read back as pixels
    px = markers.positions[:, order]
    truth = np.stack([synth.motion.forward(t, seeds) for t in range(24)])
    assert np.nanmedian(np.linalg.norm(px - truth, axis=2)) <= 0.5
