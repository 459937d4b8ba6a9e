"""Solve the take onto the character and key the weights as a new solve layer."""

import bpy
import numpy as np

from ..facecap_addon.scene import scene_solve, tuning_scene
from ..facecap_addon.ui.greyed import needs, unless
from ..solvers.errors import FacecapError
from .video import ClipJobOperator  # its cancel and _stop: Blender ending the operator, the timer and status bar


TICK_SECONDS = 0.1  # how often the sidebar looks at a running solve
STEP_SECONDS = 0.1  # a rig solve's work per tick (on the main thread): the interface stays live between


class SolveJobOperator(ClipJobOperator):
    """The sidebar's solves beside the interface: ``_start(context)`` gives the session
    (``scene_solve.start_session``), ``_write(context, session)`` keys its finished result. Invoked from the
    sidebar the solve runs while the status bar says what and for how long, Esc cancels with nothing written;
    from scripts and in background mode it runs at once."""

    def execute(self, context):
        """Solve and write at once (bpy.ops from scripts and background mode)."""
        try:
            session = self._start(context)
            session.wait()
            return self._write(context, session)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}

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
        session = self._session
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            self._stop(context)
            self.report({"WARNING"}, f"{session.what} cancelled after {session.seconds():.1f} s; nothing was keyed")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if hasattr(session, "step"):  # a rig: its steps run here, on the main thread (Blender evaluates it)
            try:
                session.step(STEP_SECONDS)
            except FacecapError as exc:
                self._stop(context)
                self.report({"ERROR"}, str(exc))
                return {"CANCELLED"}
            context.window_manager.progress_update(int(100 * session.fraction))
        if not session.finished:  # the status bar says what is solving and for how long
            context.workspace.status_text_set(session.status())
            return {"RUNNING_MODAL"}
        self._stop(context)
        try:
            return self._write(context, session)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}


class FACECAP_OT_solve(SolveJobOperator, bpy.types.Operator):
    """Solve shape-key weights (or a rig's controls) for every frame and key them as the solve layer (a new action named after the take; your own keys on the layer above are kept). The status bar shows what is solving, how far and for how long; Esc cancels with the scene untouched"""

    bl_idname = "facecap.solve"
    bl_label = "Solve and Key"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "character", "take or weights")

    def _start(self, context):
        return scene_solve.start_session(context.scene.facecap, context.scene)

    def _write(self, context, session):
        """Key the finished solve and report it (a FacecapError of the solve is raised here)."""
        settings = context.scene.facecap
        result = session.wait()
        action = scene_solve.key_solve(settings, result)
        ok = np.isfinite(result.residual_rms)
        source = f"{len(result.marker_names)} markers" if result.stabilise is not None else f"{len(result.source_names)} channels"
        residual = f", RMS residual {float(np.mean(result.residual_rms[ok]) * 1e3):.2f} mm" if ok.any() else ""
        library = f", library '{settings.library_active}'" if settings.library_active else ""
        summary = (
            f"Solved {len(result.shape_names)} shapes over {result.frames.size} frames from "
            f"{source} ({settings.strategy}{library}){residual} in {session.seconds():.1f} s, action '{action.name}'"
        )
        settings.last_report = summary
        for note in result.warnings:
            self.report({"WARNING"}, note)
        self.report({"INFO"}, summary)
        return {"FINISHED"}


class FACECAP_OT_refresh_shapes(bpy.types.Operator):
    """Fill the shape list from the character's shape keys, or the rig's controls with a rig as the target (keeps the options of shapes already listed)"""

    bl_idname = "facecap.refresh_shapes"
    bl_label = "Refresh Shapes"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "character")

    def execute(self, context):
        settings = context.scene.facecap
        key = settings.target.data.shape_keys
        try:
            controls = tuning_scene.rig_channels(settings)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if key is None and controls is None:
            self.report({"ERROR"}, f"'{settings.target.name}' has no shape keys")
            return {"CANCELLED"}
        rows = [(c.name, c.lower, c.upper) for c in controls] if controls is not None else \
            [(b.name, b.slider_min, b.slider_max) for b in key.key_blocks if b != key.reference_key]
        old = {s.name: (s.lock, s.lock_value, s.lower, s.upper, s.region) for s in settings.shapes}
        settings.shapes.clear()
        for name, lower, upper in rows:
            item = settings.shapes.add()
            item.name = name
            item.lower, item.upper = lower, upper
            if name in old:
                item.lock, item.lock_value, item.lower, item.upper, item.region = old[name]
        self.report({"INFO"}, f"{len(settings.shapes)} shapes listed")
        return {"FINISHED"}


class FACECAP_OT_region_add(bpy.types.Operator):
    """Add a face region (its shapes are solved from its own markers only)"""

    bl_idname = "facecap.region_add"
    bl_label = "Add Region"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        settings = context.scene.facecap
        region = settings.regions.add()
        region.name = f"region{len(settings.regions)}"
        settings.active_region = len(settings.regions) - 1
        return {"FINISHED"}


class FACECAP_OT_region_remove(bpy.types.Operator):
    """Remove the active region (its shapes go back to the whole face)"""

    bl_idname = "facecap.region_remove"
    bl_label = "Remove Region"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return unless(cls, len(context.scene.facecap.regions) > 0, "No regions: nothing to remove")

    def execute(self, context):
        settings = context.scene.facecap
        name = settings.regions[settings.active_region].name
        for shape in settings.shapes:
            if shape.region == name:
                shape.region = ""
        settings.regions.remove(settings.active_region)
        settings.active_region = max(0, settings.active_region - 1)
        return {"FINISHED"}


CLASSES = (FACECAP_OT_solve, FACECAP_OT_refresh_shapes, FACECAP_OT_region_add, FACECAP_OT_region_remove)
