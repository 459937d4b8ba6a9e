"""What is known of the actor's face: installing the optional human template, from the ICT-FaceKit download
(*Install Human Template*) or downloaded here (*Download Human Template*, with Blender's online access)."""

import time
from pathlib import Path

import bpy
from bpy.props import StringProperty

from ..solvers.character.ict_release import RELEASE_COMMIT, RELEASE_URL
from ..solvers.character.template import TEMPLATE_DIGEST, HumanTemplate, convert, template_path
from ..solvers.errors import FacecapError
from ..solvers.tools.template import fetch
from .downloads import BackgroundDownload, DownloadOperator


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


class DownloadJob(BackgroundDownload):
    """``fetch`` on a worker thread (urllib, numpy: no Blender data); ``cancel`` stops it at the next megabyte or OBJ
    file (the partial download removed, nothing installed)."""

    what = "Download Human Template"

    def fetch(self, url):
        return fetch(url, progress=self.progress("downloading"), read_progress=self.progress("converting"))

    def status(self):
        if self.stage == "downloading":
            how = f"{self.done / 1e6:.0f}" + (f" of {self.total / 1e6:.0f} MB" if self.total else " MB")
        elif self.stage == "converting":
            how = f"{self.done}/{self.total} files"
        else:
            how = "connecting"
        return (f"{self.what} (ICT-FaceKit {RELEASE_COMMIT[:7]}): {self.stage} {how}, "
                f"{time.monotonic() - self.started:.0f} s; Esc cancels")


class FACECAP_OT_download_template(DownloadOperator, bpy.types.Operator):
    """Download ICT-FaceKit (USC ICT, MIT licence; the release facecap's figures come from) from GitHub and install it as the human template, hash-checked: the semantic solve then fits it to the actor when no calibration is given. Needs Blender's online access (Preferences > System); the status bar shows how far, Esc cancels"""

    bl_idname = "facecap.download_template"
    bl_label = "Download Human Template"
    bl_options = {"REGISTER"}  # writes facecap's cache and data folders, not the .blend: nothing to undo

    url: StringProperty(default=RELEASE_URL, options={"HIDDEN", "SKIP_SAVE"})

    thing, manual = "The human template", f"download {RELEASE_URL} in a browser and use Install Human Template"

    job = DownloadJob

    @staticmethod
    def installed():
        return _installed()

    @staticmethod
    def where():
        return template_path()

    @staticmethod
    def fetch_now(url):
        return fetch(url)

    @staticmethod
    def installed_message(path):
        return f"Human template installed: {path}"


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
