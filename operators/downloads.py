"""What the sidebar's download buttons share (*Download Human Template*, *Download Face Models*): the download
on a worker thread polled by a modal operator (status bar, Esc cancels, nothing installed), at once from scripts
and in background mode, refused with the manual route when Blender's online access is off."""

import threading
import time

import bpy

from ..solvers.errors import Cancelled, FacecapError

TICK_SECONDS = 0.2


def online_access():
    """Blender's *Allow Online Access* preference (4.2+; earlier Blenders have no such switch)."""
    return getattr(bpy.app, "online_access", True)


class BackgroundDownload:
    """``fetch(url)`` on a worker thread (no Blender data); its progress calls (``progress(stage)``) say how far and
    stop it at the next one once cancelled. ``what``: the button's label, for messages."""

    what = "Download"

    def __init__(self, url):
        self.stage, self.done, self.total = "connecting", 0, 0
        self.result = self.error = None
        self._cancel = threading.Event()
        self.started = time.monotonic()
        self.thread = threading.Thread(target=self._run, args=(url,), name=f"facecap {self.what}", daemon=True)
        self.thread.start()

    def fetch(self, url):
        raise NotImplementedError

    def _run(self, url):
        try:
            self.result = self.fetch(url)
        except Cancelled:
            pass
        except Exception as exc:  # handed to the main thread: reported there
            self.error = exc

    def progress(self, stage):
        def report(done, total):
            self.stage, self.done, self.total = stage, done, total
            return not self._cancel.is_set()
        return report

    @property
    def finished(self):
        return not self.thread.is_alive()

    def status(self):
        how = f"{self.done / 1e6:.1f}" + (f" of {self.total / 1e6:.1f} MB" if self.total else " MB")
        return f"{self.what}: {how}, {time.monotonic() - self.started:.0f} s; Esc cancels"

    def cancel(self):
        self._cancel.set()


class DownloadOperator:
    """The download button's behaviour; a subclass (with ``bpy.types.Operator``) gives ``url``, ``job``
    (a BackgroundDownload class), ``thing`` (what is installed), ``installed()``, ``where()`` (the installed
    file), ``manual`` (how to do it by hand), ``fetch_now(url)`` (at once) and ``installed_message(path)``."""

    job = BackgroundDownload
    thing, manual = "", ""

    def execute(self, context):
        """Download at once (bpy.ops from scripts and background mode)."""
        if not self._may_start():
            return {"FINISHED"} if self.installed() else {"CANCELLED"}
        try:
            out = self.fetch_now(self.url)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, self.installed_message(out))
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        if not self._may_start():
            return {"FINISHED"} if self.installed() else {"CANCELLED"}
        self._job = self.job(self.url)
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
            self.report({"WARNING"}, f"{job.what} cancelled; nothing was installed")
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
        self.report({"INFO"}, self.installed_message(job.result))
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
        if self.installed():
            self.report({"INFO"}, f"{self.thing} is already installed: {self.where()}")
            return False
        if not online_access():
            self.report({"ERROR"}, "Blender's online access is off (Preferences > System > Network > Allow Online "
                                   f"Access); or {self.manual}")
            return False
        return True
