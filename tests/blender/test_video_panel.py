"""The Video panel and its settings (registered here: the add-on hooks them as Scene.facecap.video)."""

from types import SimpleNamespace

import bpy
import pytest
from scene_fixtures import LayoutStub

from facecap.facecap_addon.ui import panels_video, properties_video
from facecap.facecap_addon.scene.scene_camera import projection_for
from facecap.solvers.character.camera import Camera


@pytest.fixture
def video_settings(empty_scene):
    registered = "video" not in empty_scene.facecap.bl_rna.properties  # not yet hooked by the add-on
    if registered:
        for cls in properties_video.CLASSES + panels_video.CLASSES:
            bpy.utils.register_class(cls)
        bpy.types.Scene.facecap_video_test = bpy.props.PointerProperty(type=properties_video.FACECAP_PG_video)
        settings = empty_scene.facecap_video_test
    else:  # the add-on already hooks Scene.facecap.video
        settings = empty_scene.facecap.video
    yield empty_scene, settings
    if registered:
        del bpy.types.Scene.facecap_video_test
        for cls in reversed(properties_video.CLASSES + panels_video.CLASSES):
            bpy.utils.unregister_class(cls)


def draw(scene, settings):
    layout = LayoutStub()
    context = SimpleNamespace(scene=SimpleNamespace(facecap=SimpleNamespace(video=settings), camera=scene.camera))
    panels_video.FACECAP_PT_video.draw(SimpleNamespace(layout=layout), context)
    return layout.calls


def test_panel_draws_projection_and_camera(video_settings):
    scene, v = video_settings
    calls = draw(scene, v)
    assert ("operator", "facecap.track_clip") in calls and ("prop", "projection") in calls
    assert ("prop", "camera") not in calls
    v.projection = "camera"
    calls = draw(scene, v)
    assert ("prop", "camera") in calls and any("no camera" in str(c[1]) for c in calls if c[0] == "label")


def test_sidebar_camera_feeds_the_solve_projection(video_settings):
    scene, v = video_settings
    cam = bpy.data.objects.new("Witness", bpy.data.cameras.new("Witness"))
    face = bpy.data.objects.new("Face", None)
    for obj in (cam, face):
        scene.collection.objects.link(obj)
    cam.location = (0.0, -1.0, 0.0)
    v.projection, v.camera = "camera", cam
    assert properties_video._is_camera(v, cam) and not properties_video._is_camera(v, face)  # the picker's filter
    bpy.context.view_layer.update()
    model = projection_for(scene, face, v.projection, v.camera.name)
    assert isinstance(model, Camera) and (model.width, model.height) == (1920, 1080)
    assert projection_for(scene, face) == "front"
