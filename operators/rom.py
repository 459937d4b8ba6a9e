"""The range-of-motion session of the Solve panel: *Find Poses* marks the ROM take's holds on the timeline, *Save
Performer Profile* writes the actor's shapes measured from them for every later take of that performer. A ROM take
tracked from video (*Track Face Landmarks*, keeping the blendshape scores) is the performer's ROM on camera: its
poses are found in the scores and the profile holds their response on that camera."""

import os
from types import SimpleNamespace

import bpy
import numpy as np
from bpy.props import BoolProperty, StringProperty

from ..facecap_addon.scene import rom_markers, rom_scene
from ..solvers.errors import FacecapError
from ..solvers.video.follow import FollowFit
from ..solvers.video.response import ResponseFit
from .solve import SolveJobOperator


def why_not(context):
    """Why the ROM buttons cannot run now (their poll message), or None."""
    s = context.scene.facecap
    if s.strategy != "semantic":
        return "A ROM session calibrates the semantic strategy: choose Strategy > Semantic"
    if s.calib_sheet == "NONE" and not s.calib_guide.strip():
        return "Choose a ROM sheet first (Actor calibration > ROM Sheet), or the Guide a landmark take followed"
    if not rom_markers.has_rom_take(s):
        return rom_scene.NO_ROM_TAKE[0].upper() + rom_scene.NO_ROM_TAKE[1:]
    return None


def camera_poses(fit, frames):
    """The poses a ROM on camera found (a ResponseFit), as ``rom_markers.place_markers`` takes them: each pose with
    the middle frame of its hold on the timeline (NaN: not found); ``frames``: the ROM take's frame numbers (the
    fit's holds are indices into them)."""
    index = np.arange(len(frames), dtype=np.float64)
    middles = [float("nan") if f is None else float(np.interp(0.5 * (f[0] + f[1]), index, frames))
               for f in fit.frames]
    return SimpleNamespace(poses=fit.poses, middles=middles)


class RomJobOperator(SolveJobOperator):
    """The ROM operators beside the interface (``SolveJobOperator``: the status bar says what is measured and for
    how long, Esc cancels; from scripts and in background mode they run at once)."""

    untouched = "nothing was changed"

    @classmethod
    def poll(cls, context):
        why = why_not(context)
        if why is not None:
            cls.poll_message_set(why)
        return why is None

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            session = self._session
            self._stop(context)
            self.report({"WARNING"}, f"{session.what} cancelled after {session.seconds():.1f} s; {self.untouched}")
            return {"CANCELLED"}
        return SolveJobOperator.modal(self, context, event)


class FACECAP_OT_rom_find_poses(RomJobOperator, bpy.types.Operator):
    """Find the ROM sheet's poses in the ROM take (its holds, named against the human template when installed, else the character's shapes) and mark each at its middle frame with a timeline marker 'ROM: <pose>' (earlier ROM markers are replaced, your other markers kept). Drag a marker to move its hold, delete it to leave the pose out: the solve and Save Performer Profile use the markers. The status bar shows progress; Esc cancels"""

    bl_idname = "facecap.rom_find_poses"
    bl_label = "Find Poses"
    bl_options = {"REGISTER", "UNDO"}

    untouched = "the timeline markers are as they were"

    def _start(self, context):
        return rom_scene.RomInBackground(context.scene.facecap, what="Find Poses", use_markers=False)

    def _write(self, context, session):
        result = session.wait()
        if isinstance(result, ResponseFit):  # a ROM on camera: the poses found in its blendshape scores
            made = rom_markers.place_markers(context.scene, camera_poses(result, session.frames))
            for note in result.notes:
                self.report({"WARNING"}, note)
            self.report({"INFO"}, f"Find Poses (ROM on camera): {result.summary}; marked "
                                  f"'{rom_markers.PREFIX}<pose>' on the timeline: "
                                  f"{', '.join(m.name[len(rom_markers.PREFIX):] for m in made)}")
            return {"FINISHED"}
        found = result.found
        made = rom_markers.place_markers(context.scene, found)
        for note in found.notes:  # poses not found, expressions the sheet does not ask, by name
            self.report({"WARNING"}, note)
        labels = [m.name[len(rom_markers.PREFIX):] for m in made]
        sheet = context.scene.facecap.calib_sheet
        self.report({"INFO"}, f"Find Poses: {len(made)} of {len(found.poses)} poses of {sheet} "
                              f"found ({len(found.holds)} holds in the ROM take, named against {result.prior}) and "
                              f"marked '{rom_markers.PREFIX}<pose>' on the timeline: {', '.join(labels)}")
        return {"FINISHED"}


class FACECAP_OT_rom_save_profile(RomJobOperator, bpy.types.Operator):
    """Measure the actor's shapes from the ROM take (at the 'ROM: ' timeline markers when there are any, else at the holds found; a landmark take with a Guide: the take solved and added to the fusion map) and save them as a performer profile (.npz); Performer Profile then points to it, so every later solve of this performer uses it. An existing file is replaced only when facecap wrote it, or with Overwrite. The status bar shows progress; Esc cancels"""

    bl_idname = "facecap.rom_save_profile"
    bl_label = "Save Performer Profile"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="File", subtype="FILE_PATH", description="The performer profile (.npz) to write")
    filter_glob: StringProperty(default="*.npz", options={"HIDDEN"})
    check_existing: BoolProperty(default=True, options={"HIDDEN"})
    overwrite: BoolProperty(name="Overwrite", default=False,
                            description="Replace an existing file facecap did not write (a profile or library "
                            "facecap wrote is replaced without this)")
    browsed: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"})  # chosen in the file browser: modal

    untouched = "no file was written"

    def check(self, _context):
        """Keep the file name's suffix .npz (the file browser calls this on every change)."""
        if self.filepath and os.path.splitext(self.filepath)[1].lower() != ".npz":
            self.filepath += ".npz"
            return True
        return False

    def invoke(self, context, _event):
        if not self.filepath:
            s = context.scene.facecap
            base = bpy.path.abspath("//") if bpy.data.filepath else os.path.expanduser("~")
            self.filepath = os.path.join(base, f"{s.take_name or 'performer'}_profile.npz")
        self.browsed = True
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        """Check where the profile goes, then measure (beside the interface after the file browser, else at once)."""
        if not self.filepath:
            self.report({"ERROR"}, "choose the performer profile's file (.npz)")
            return {"CANCELLED"}
        try:
            rom_scene.check_profile_output(context.scene.facecap, rom_scene.profile_path(self.filepath),
                                           overwrite=self.overwrite)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if self.browsed and not bpy.app.background and context.window is not None:
            return SolveJobOperator.invoke(self, context, None)  # after the file browser: beside the interface
        return super().execute(context)

    def _start(self, context):
        return rom_scene.RomInBackground(context.scene.facecap, what="Save Performer Profile", use_markers=True)

    def _write(self, context, session):
        settings = context.scene.facecap
        result = session.wait()
        path = rom_scene.profile_path(self.filepath)
        rom_scene.check_profile_output(settings, path, overwrite=self.overwrite)  # again: a while has passed
        rom_scene.save_profile(settings, result, path)
        if isinstance(result, ResponseFit):
            for note in result.notes:
                self.report({"WARNING"}, note)
            self.report({"INFO"}, f"Saved the performer profile {path}: the blendshape scores' response on this "
                                  f"camera ({result.summary}); every later landmark take of this performer uses it "
                                  "(Performer Profile)")
            return {"FINISHED"}
        if isinstance(result, FollowFit):
            self.report({"INFO"}, f"Saved the performer profile {path}: {result.summary}; every later landmark take "
                                  "of this performer and camera fuses through it (Performer Profile)")
            return {"FINISHED"}
        found = result.found
        for note in result.notes:
            self.report({"WARNING"} if note in found.notes else {"INFO"}, note)
        where = f"at the {int(found.found.sum())} '{rom_markers.PREFIX}' markers" if found.given else \
            f"at the holds of {int(found.found.sum())} of {len(found.poses)} poses found (Find Poses marks them)"
        self.report({"INFO"}, f"Saved the performer profile {path}: {len(result.measured.shape_names)} shapes "
                              f"measured {where}; every later solve uses it (Performer Profile)")
        return {"FINISHED"}


CLASSES = (FACECAP_OT_rom_find_poses, FACECAP_OT_rom_save_profile)
