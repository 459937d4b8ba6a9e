"""*Download Face Models* (Video panel): MediaPipe's Face Landmarker bundle into facecap's cache, once,
hash-checked (``landmark-models fetch`` on a worker thread), with Blender's online access."""

import threading
import time

import bpy
from bpy.props import StringProperty

from ..solvers.errors import Cancelled, FacecapError
from ..solvers.tools.landmark_models import bundle_installed, fetch_bundle
from ..solvers.video.landmarker_bundle import BUNDLE_URL, bundle_path
from . import actor

TICK_SECONDS = 0.2


class FACECAP_OT_download_face_models(bpy.types.Operator):
    """Download MediaPipe's Face Landmarker (Apache-2.0, 3.8 MB: face detector, 478 landmarks and the blendshape head) into facecap's cache, hash-checked: face-landmark takes then get blendshape scores beside the landmarks. Needs Blender's online access (Preferences > System); Esc cancels"""

    bl_idname = "facecap.download_face_models"
    bl_label = "Download Face Models"
    bl_options = {"REGISTER"}  # writes facecap's cache, not the .blend: nothing to undo

    url: StringProperty(default=BUNDLE_URL, options={"HIDDEN", "SKIP_SAVE"})

    def execute(self, context):
        """Download at once (bpy.ops from scripts and background mode)."""
        if not self._may_start():
            return {"FINISHED"} if bundle_installed() else {"CANCELLED"}
        try:
            out = fetch_bundle(self.url)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Face Landmarker installed: {out}")
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        if not self._may_start():
            return {"FINISHED"} if bundle_installed() else {"CANCELLED"}
        self._job = _FetchJob(self.url)
        wm = context.window_manager
        self._timer = wm.event_timer_add(TICK_SECONDS, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        job = self._job
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            job.cancel.set()
            self._stop(context)
            self.report({"WARNING"}, "Download Face Models cancelled; nothing was installed")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if job.thread.is_alive():
            context.workspace.status_text_set(f"Download Face Models: {job.done / 1e6:.1f} MB, "
                                              f"{time.monotonic() - job.started:.0f} s; Esc cancels")
            return {"RUNNING_MODAL"}
        self._stop(context)
        if job.error is not None:
            self.report({"ERROR"}, str(job.error))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Face Landmarker installed: {job.result}")
        return {"FINISHED"}

    def cancel(self, context):  # Blender ends the operator (a file is loaded, Blender quits)
        self._job.cancel.set()
        self._stop(context)

    def _stop(self, context):
        if getattr(self, "_timer", None) is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None
        if context.workspace is not None:
            context.workspace.status_text_set(None)

    def _may_start(self):
        """False (with the reason reported) when there is nothing to do or no download may be made."""
        if bundle_installed():
            self.report({"INFO"}, f"The Face Landmarker is already installed: {bundle_path()}")
            return False
        if not actor._online_access():
            self.report({"ERROR"}, "Blender's online access is off (Preferences > System > Network > Allow Online "
                                   f"Access); or download {BUNDLE_URL} in a browser and put it at {bundle_path()}")
            return False
        return True


class _FetchJob:
    """``fetch_bundle`` on a worker thread (no Blender data), polled by the modal operator."""

    def __init__(self, url):
        self.done, self.result, self.error = 0, None, None
        self.cancel = threading.Event()
        self.started = time.monotonic()
        self.thread = threading.Thread(target=self._run, args=(url,), name="facecap face models", daemon=True)
        self.thread.start()

    def _run(self, url):
        try:
            self.result = fetch_bundle(url, progress=self._progress)
        except Cancelled:
            pass
        except Exception as exc:  # handed to the main thread: reported there
            self.error = exc

    def _progress(self, done, _total):
        self.done = done
        return not self.cancel.is_set()


CLASSES = (FACECAP_OT_download_face_models,)
