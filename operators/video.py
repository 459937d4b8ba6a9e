"""Video operators on the scene's movie clip: tracking its footage, and solving the character from its dense
flow (modal: a few frames per timer tick, progress in the status bar, Esc cancels with the scene untouched)."""

from pathlib import Path

import bpy

from ..facecap_addon.scene import import_scene
from ..facecap_addon.ui.properties_video import METHOD_ITEMS
from ..facecap_addon.scene.landmark_scores import store_eye_points, store_scores
from ..facecap_addon.scene.video_scene import ClipFlowSolving, ClipLandmarks, ClipTracking, use_landmark_defaults
from ..facecap_addon.ui.greyed import unless
from ..solvers.errors import FacecapError

TICK_SECONDS = 0.02  # timer interval
STEP_SECONDS = 0.1  # work per timer tick: long enough to make progress, short enough to keep the UI live


class ClipJobOperator:
    """Shared modal machinery: ``_start(context)`` builds a stepping session (``step``, ``run``, ``cancel``,
    ``status``, ``job``, ``what``), ``_write(context, session)`` puts its finished result in the scene."""

    @classmethod
    def poll(cls, context):
        return unless(cls, context.scene.active_clip is not None,
                      "Open the footage first: the scene's active clip (Movie Clip Editor: Open)")

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
            self._write(context, session)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
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
            session = self._session
            self._stop(context)
            self.report({"WARNING"}, f"{session.what} cancelled at frame {session.job.frame}; "
                                     "nothing was added to the scene")
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
        try:
            self._write(context, session)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
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


class FACECAP_OT_track_clip(ClipJobOperator, bpy.types.Operator):
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

    def _start(self, context):
        scene = context.scene
        return ClipTracking(scene, scene.active_clip, scene.frame_current, region=tuple(self.region),
                            max_points=self.max_points, method=self.method)

    def _write(self, context, session):
        scene, result = context.scene, session.result
        markers = result.markers
        name = f"{session.clip_name} tracks"
        coll = import_scene.create_take(scene, markers, name, set_scene_range=False)
        import_scene.remember_take(scene, markers, Path(name), coll)
        scene.facecap.take_name = name  # not Path(name).stem: clip names keep their extension ("face.avi")
        self.report({"INFO"}, f"Tracked {markers.n_markers} points over {markers.n_frames} frames into '{coll.name}'; "
                              + result.summary().splitlines()[0])


class FACECAP_OT_track_face_landmarks(ClipJobOperator, bpy.types.Operator):
    """Find the face in every frame of the scene's movie clip (no markers, no seeds) and add its 468 skin
    landmarks as a 3D take, set up to solve: the head-rigid landmarks stable, the neutral detected, the
    binding automatic; progress shows in the status bar, Esc cancels"""

    bl_idname = "facecap.track_face_landmarks"
    bl_label = "Track Face Landmarks"
    bl_options = {"REGISTER", "UNDO"}

    smoothing: bpy.props.BoolProperty(name="Smoothing", default=True,
                                      description="Filter the detector's jitter (zero lag, fast lip motion kept)")
    solve: bpy.props.BoolProperty(name="Solve After", default=False,
                                  description="Then solve the landmarks onto the Solve panel's character and key "
                                              "them (Solve and Key), as the four-section config does")

    def _start(self, context):
        scene = context.scene
        return ClipLandmarks(scene, scene.active_clip, smoothing=self.smoothing)

    def _write(self, context, session):
        scene, take = context.scene, session.take
        name = f"{session.clip_name} landmarks"
        coll = import_scene.create_take(scene, take, name, set_scene_range=False)
        import_scene.remember_take(scene, take, Path(name), coll)
        store_scores(coll, session.result)
        store_eye_points(coll, session.result)
        scene.facecap.take_name = name
        use_landmark_defaults(scene.facecap)
        self.report({"INFO"}, f"{session.result.summary()}; added as '{coll.name}' (stable: the head-rigid landmarks, "
                              "neutral: detected, binding: nearest, human template: none)")
        if self.solve:
            self._solve(context)

    def _solve(self, context):
        """Solve and Key the new take: run to completion from scripts, modal (its own progress, Esc) in the UI.
        The landmarks stay in the scene whatever the solve says."""
        if not bpy.ops.facecap.solve.poll():
            self.report({"WARNING"}, "Tracked, not solved: choose the character in the Solve panel, then Solve and "
                                     "Key")
            return
        ui = not bpy.app.background and context.window is not None
        try:  # an operator that reports an error raises here when called from Python
            done = bpy.ops.facecap.solve("INVOKE_DEFAULT" if ui else "EXEC_DEFAULT")
        except RuntimeError as exc:
            done, why = {"CANCELLED"}, str(exc).strip()
        else:
            why = "its message above"
        if done == {"CANCELLED"}:
            self.report({"WARNING"}, f"Tracked; the solve stopped ({why}): the landmark take is kept")


class FACECAP_OT_solve_clip_flow(ClipJobOperator, bpy.types.Operator):
    """Solve the character from the scene's movie clip without markers: dense flow over the face region
    (Video panel) relative to the current frame (neutral), reduced to a few PCA features per frame and mapped
    to the weights posed in the Solve panel's Examples action; keys a new solve layer. Esc cancels"""

    bl_idname = "facecap.solve_clip_flow"
    bl_label = "Solve from Clip Flow"
    bl_options = {"REGISTER", "UNDO"}

    def _start(self, context):
        scene = context.scene
        return ClipFlowSolving(scene, scene.active_clip, scene.frame_current)

    def _write(self, context, session):
        action, result = session.write()
        flow = result.info["flow"]
        self.report({"INFO"}, f"Solved {len(result.shape_names)} shapes over {result.frames.size} frames of "
                              f"'{session.clip_name}' from {flow['components']} flow components "
                              f"({flow['explained_variance']:.1%} of the face's motion, {flow['example_frames']} "
                              f"posed frames, {result.strategy}, flow {flow['flow_frames_per_s']:.0f} frames/s); "
                              f"keyed '{action.name}'")


CLASSES = (FACECAP_OT_track_clip, FACECAP_OT_track_face_landmarks, FACECAP_OT_solve_clip_flow)
