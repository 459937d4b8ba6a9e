"""Video operators: tracking a movie clip's footage (modal: progress, Esc cancels)."""

from pathlib import Path

import bpy

from ..facecap_addon.properties_video import METHOD_ITEMS
from ..solvers.errors import FacecapError

TICK_SECONDS = 0.02  # timer interval
STEP_SECONDS = 0.1  # tracking per timer tick: long enough to make progress, short enough to keep the UI live


class FACECAP_OT_track_clip(bpy.types.Operator):
    """Track the scene's movie clip (Lucas-Kanade or dense flow) from its own track markers at the current frame
    (or features in a region) and add the 2D tracks as a take; progress shows in the status bar, Esc cancels"""

    bl_idname = "facecap.track_clip"
    bl_label = "Track Clip Footage"
    bl_options = {"REGISTER", "UNDO"}

    region: bpy.props.IntVectorProperty(
        name="Region", size=4, default=(0, 0, 0, 0), min=0,
        description="x, y, width, height in pixels for automatic features when the clip has no track markers "
                    "at this frame",
    )
    max_points: bpy.props.IntProperty(name="Max Points", default=100, min=1)
    method: bpy.props.EnumProperty(name="Method", items=METHOD_ITEMS, default="lk")

    @classmethod
    def poll(cls, context):
        return context.scene.active_clip is not None

    def _start(self, context):
        from ..facecap_addon.video_scene import ClipTracking

        scene = context.scene
        return ClipTracking(scene, scene.active_clip, scene.frame_current, region=tuple(self.region),
                            max_points=self.max_points, method=self.method)

    def execute(self, context):
        """Run to completion (bpy.ops from scripts and background mode)."""
        wm = context.window_manager
        try:
            session = self._start(context)
            wm.progress_begin(0, 100)

            def progress(done, total):
                wm.progress_update(int(100 * done / max(total, 1)))
                return True

            try:
                session.run(progress)
            finally:
                wm.progress_end()
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self._write(context, session)
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        try:
            self._session = self._start(context)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        wm = context.window_manager
        self._timer = wm.event_timer_add(TICK_SECONDS, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 100)
        context.workspace.status_text_set(self._session.status())
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            frame = self._session.job.frame
            self._stop(context)
            self.report({"WARNING"}, f"Tracking cancelled at frame {frame}; nothing was added to the scene")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            finished = self._session.step(1, seconds=STEP_SECONDS)
        except FacecapError as exc:
            self._stop(context)
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        context.window_manager.progress_update(int(100 * self._session.job.fraction))
        if not finished:
            context.workspace.status_text_set(self._session.status())
            return {"RUNNING_MODAL"}
        session = self._session
        self._stop(context)
        self._write(context, session)
        return {"FINISHED"}

    def cancel(self, context):
        """Blender ends the operator (file load, window closed): stop without writing."""
        self._stop(context)

    def _stop(self, context):
        wm = context.window_manager
        if getattr(self, "_timer", None) is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        session = getattr(self, "_session", None)
        if session is not None:
            session.cancel()
            wm.progress_end()
            if context.workspace is not None:
                context.workspace.status_text_set(None)

    def _write(self, context, session):
        from ..facecap_addon import import_scene
        from .importers import _remember_take

        scene, result = context.scene, session.result
        markers = result.markers
        name = f"{session.clip_name} tracks"
        coll = import_scene.create_take(scene, markers, name, set_scene_range=False)
        _remember_take(scene, markers, Path(name), coll)
        scene.facecap.take_name = name  # not Path(name).stem: clip names keep their extension ("face.avi")
        self.report({"INFO"}, f"Tracked {markers.n_markers} points over {markers.n_frames} frames into '{coll.name}'; "
                              + result.summary().splitlines()[0])


CLASSES = (FACECAP_OT_track_clip,)
