"""*Download Face Models* (Video panel): MediaPipe's Face Landmarker bundle into facecap's cache, once,
hash-checked (``landmark-models fetch`` on a worker thread), with Blender's online access."""

import bpy
from bpy.props import StringProperty

from ..solvers.tools.landmark_models import bundle_installed, fetch_bundle
from ..solvers.video.landmarker_bundle import BUNDLE_URL, bundle_path
from .downloads import BackgroundDownload, DownloadOperator


class FaceModelsDownload(BackgroundDownload):
    """``fetch_bundle`` on a worker thread (no Blender data), polled by the modal operator."""

    what = "Download Face Models"

    def fetch(self, url):
        return fetch_bundle(url, progress=self.progress("downloading"))


class FACECAP_OT_download_face_models(DownloadOperator, bpy.types.Operator):
    """Download MediaPipe's Face Landmarker (Apache-2.0, 3.8 MB: face detector, 478 landmarks and the blendshape head) into facecap's cache, hash-checked: face-landmark takes then get blendshape scores beside the landmarks. Needs Blender's online access (Preferences > System); Esc cancels"""

    bl_idname = "facecap.download_face_models"
    bl_label = "Download Face Models"
    bl_options = {"REGISTER"}  # writes facecap's cache, not the .blend: nothing to undo

    url: StringProperty(default=BUNDLE_URL, options={"HIDDEN", "SKIP_SAVE"})

    job = FaceModelsDownload
    thing = "The Face Landmarker"

    @property
    def manual(self):
        return f"download {BUNDLE_URL} in a browser and put it at {bundle_path()}"

    @staticmethod
    def installed():
        return bundle_installed()

    @staticmethod
    def where():
        return bundle_path()

    @staticmethod
    def fetch_now(url):
        return fetch_bundle(url)

    @staticmethod
    def installed_message(path):
        return f"Face Landmarker installed: {path}"


CLASSES = (FACECAP_OT_download_face_models,)
