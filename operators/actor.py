"""What is known of the actor's face: installing the optional human template, from the ICT-FaceKit download
(*Install Human Template*) or downloaded here (*Download Human Template*, with Blender's online access)."""

import threading
import time
from pathlib import Path

import bpy
from bpy.props import StringProperty

from ..solvers.character.ict_release import RELEASE_COMMIT, RELEASE_URL
from ..solvers.character.template import TEMPLATE_DIGEST, HumanTemplate, convert, template_path
from ..solvers.errors import Cancelled, FacecapError
from ..solvers.tools.template import fetch

TICK_SECONDS = 0.2


class FACECAP_OT_install_template(bpy.types.Operator):
    """Install the human template from ICT-FaceKit as downloaded (its GitHub zip, the repository folder or
    FaceXModel; hash-checked): the semantic solve then fits it to the actor when no calibration is given"""

    bl_idname = "facecap.install_template"
    bl_label = "Install Human Template"
    bl_options = {"REGISTER"}  # writes facecap's data folder, not the .blend: nothing to undo

    filepath: StringProperty(subtype="FILE_PATH", description="The ICT-FaceKit zip, or a file in its folder")
    directory: StringProperty(subtype="DIR_PATH")
    filter_glob: StringProperty(default="*.zip;*.obj;*.json;*.npz", options={"HIDDEN"})

    def invoke(self, context, _event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        source = _source(self.filepath, self.directory)
        if source is None:
            self.report({"ERROR"}, f"choose the ICT-FaceKit download (its zip or folder; {RELEASE_URL})")
            return {"CANCELLED"}
        if _installed():
            self.report({"INFO"}, f"The human template is already installed: {template_path()}")
            return {"FINISHED"}
        wm = context.window_manager
        wm.progress_begin(0, 154)
        try:
            out = convert(source, progress=lambda done, _total: wm.progress_update(done))
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        finally:
            wm.progress_end()
        self.report({"INFO"}, f"Human template installed: {out} ([actor] template \"auto\" uses it)")
        return {"FINISHED"}


class FACECAP_OT_download_template(bpy.types.Operator):
    """Download ICT-FaceKit (USC ICT, MIT licence; the release facecap's figures come from) from GitHub and install it as the human template, hash-checked: the semantic solve then fits it to the actor when no calibration is given. Needs Blender's online access (Preferences > System); the status bar shows how far, Esc cancels"""

    bl_idname = "facecap.download_template"
    bl_label = "Download Human Template"
    bl_options = {"REGISTER"}  # writes facecap's cache and data folders, not the .blend: nothing to undo

    url: StringProperty(default=RELEASE_URL, options={"HIDDEN", "SKIP_SAVE"})

    def execute(self, context):
        """Download and install at once (bpy.ops from scripts and background mode)."""
        if not self._may_start():
            return {"FINISHED"} if _installed() else {"CANCELLED"}
        try:
            out = fetch(self.url)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Human template installed: {out}")
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        if not self._may_start():
            return {"FINISHED"} if _installed() else {"CANCELLED"}
        self._job = DownloadJob(self.url)
        wm = context.window_manager
        self._timer = wm.event_timer_add(TICK_SECONDS, window=context.window)
        wm.modal_handler_add(self)
        context.workspace.status_text_set(self._job.status())
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        job = self._job
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            job.cancel()
            self._stop(context)
            self.report({"WARNING"}, "Download Human Template cancelled; nothing was installed")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if not job.finished:
            context.workspace.status_text_set(job.status())
            return {"RUNNING_MODAL"}
        self._stop(context)
        if job.error is not None:
            self.report({"ERROR"}, str(job.error))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Human template installed: {job.result}")
        return {"FINISHED"}

    def cancel(self, context):  # Blender ends the operator (a file is loaded, Blender quits)
        self._job.cancel()
        self._stop(context)

    def _stop(self, context):
        if getattr(self, "_timer", None) is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None
        if context.workspace is not None:
            context.workspace.status_text_set(None)

    def _may_start(self):
        """False (with the reason reported) when there is nothing to do or no download may be made."""
        if _installed():
            self.report({"INFO"}, f"The human template is already installed: {template_path()}")
            return False
        if not _online_access():
            self.report({"ERROR"}, "Blender's online access is off (Preferences > System > Network > Allow Online "
                                   f"Access); or download {RELEASE_URL} in a browser and use Install Human Template")
            return False
        return True


class DownloadJob:
    """``fetch`` on a worker thread (urllib, numpy: no Blender data), polled by the modal operator; ``cancel``
    stops it at the next megabyte or OBJ file (the partial download removed, nothing installed)."""

    def __init__(self, url):
        self.stage, self.done, self.total = "connecting", 0, 0
        self.result = self.error = None
        self._cancel = threading.Event()
        self.started = time.monotonic()
        self.thread = threading.Thread(target=self._run, args=(url,), name="facecap template download", daemon=True)
        self.thread.start()

    def _run(self, url):
        try:
            self.result = fetch(url, progress=self._progress("downloading"),
                                read_progress=self._progress("converting"))
        except Cancelled:
            pass
        except Exception as exc:  # handed to the main thread: reported there
            self.error = exc

    def _progress(self, stage):
        def report(done, total):
            self.stage, self.done, self.total = stage, done, total
            return not self._cancel.is_set()
        return report

    @property
    def finished(self):
        return not self.thread.is_alive()

    def status(self):
        if self.stage == "downloading":
            how = f"{self.done / 1e6:.0f}" + (f" of {self.total / 1e6:.0f} MB" if self.total else " MB")
        elif self.stage == "converting":
            how = f"{self.done}/{self.total} files"
        else:
            how = "connecting"
        return (f"Download Human Template (ICT-FaceKit {RELEASE_COMMIT[:7]}): {self.stage} {how}, "
                f"{time.monotonic() - self.started:.0f} s; Esc cancels")

    def cancel(self):
        self._cancel.set()


def _online_access():
    """Blender's *Allow Online Access* preference (4.2+; earlier Blenders have no such switch)."""
    return getattr(bpy.app, "online_access", True)


def _installed():
    path = template_path()
    return path.is_file() and _installed_digest(path) == TEMPLATE_DIGEST


def _source(filepath, directory):
    """The zip chosen, or the folder (a file chosen inside FaceXModel or the repository stands for its folder)."""
    path = Path(bpy.path.abspath(filepath)) if filepath else None
    if path is not None and path.is_file() and path.suffix.lower() in (".zip", ".npz"):
        return path
    folder = path.parent if path is not None and path.is_file() else path if path is not None and path.is_dir() \
        else Path(bpy.path.abspath(directory)) if directory else None
    return folder if folder is not None and folder.is_dir() else None


def _installed_digest(path):
    try:
        return HumanTemplate.load(path).model.digest
    except FacecapError:
        return None  # unreadable: converted again (atomically) over it


CLASSES = (FACECAP_OT_install_template, FACECAP_OT_download_template)
