"""Download Face Models (Video panel): MediaPipe's Face Landmarker bundle into facecap's cache from a local server
(the shared copy of the bundle is served: no test reaches the network)."""

import time
from types import SimpleNamespace

import bpy
import pytest
from ict_release_copy import serve_release
from scene_fixtures import draw_panel
from shared_data import FACE_LANDMARKER, require

from facecap.operators import downloads, video_models
from facecap.solvers.video.landmarker_bundle import bundle_path


def test_download_face_models_beside_the_interface(empty_scene, tmp_path, monkeypatch):
    """Refused, naming the preference and the manual route, with Blender's online access off; from the sidebar it
    downloads on a worker thread and Esc leaves nothing installed; from a script it installs at once, hash-checked,
    and the panel's button goes away."""
    monkeypatch.setenv("FACECAP_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("FACECAP_FACE_LANDMARKER", raising=False)
    assert ("operator", "facecap.download_face_models") in draw_panel("FACECAP_PT_video").calls
    with serve_release(require(FACE_LANDMARKER)) as url:
        monkeypatch.setattr(downloads, "online_access", lambda: False)
        with pytest.raises(RuntimeError, match="online access is off.*in a browser"):
            bpy.ops.facecap.download_face_models(url=f"{url}/ict.zip")
        monkeypatch.setattr(downloads, "online_access", lambda: True)

        op = video_models.FACECAP_OT_download_face_models

        class Driver:  # the operator's modal methods on a plain object, as Blender would call them
            modal, cancel, _stop = op.modal, op.cancel, op._stop

            def __init__(self, job):
                self._job, self._timer, self.reports = job, None, []

            def report(self, kind, message):
                self.reports.append((kind.pop(), message))

        tick, esc = SimpleNamespace(type="TIMER", value="NOTHING"), SimpleNamespace(type="ESC", value="PRESS")
        driver = Driver(video_models.FaceModelsDownload(f"{url}/slow.zip"))
        while driver._job.done == 0:
            time.sleep(0.05)
        assert driver.modal(bpy.context, tick) == {"RUNNING_MODAL"}
        assert driver.modal(bpy.context, esc) == {"CANCELLED"}
        driver._job.thread.join(30)
        assert driver.reports == [("WARNING", "Download Face Models cancelled; nothing was installed")]
        assert not bundle_path().exists() and not any((tmp_path / "cache").rglob("*.part-*"))

        assert bpy.ops.facecap.download_face_models(url=f"{url}/ict.zip") == {"FINISHED"}
    assert bundle_path().read_bytes() == FACE_LANDMARKER.read_bytes()
    assert ("operator", "facecap.download_face_models") not in draw_panel("FACECAP_PT_video").calls
