"""Export the take for a game engine or another DCC: the character, its shape keys and the baked take."""

import os

import bpy

from ..facecap_addon.scene.export import FORMATS, export_take
from ..facecap_addon.ui.greyed import needs
from ..solvers.errors import FacecapError

SUFFIX = {"GLTF": ".glb", "FBX": ".fbx"}


class FACECAP_OT_export_take(bpy.types.Operator):
    """Write the character with its shape keys and the take (the solve with your corrections baked in, and the head motion when it is keyed) as binary glTF or FBX. The scene is not changed"""

    bl_idname = "facecap.export_take"
    bl_label = "Export Take"
    bl_options = {"REGISTER"}

    filepath: bpy.props.StringProperty(name="File", description="The .glb or .fbx file to write", subtype="FILE_PATH")
    format: bpy.props.EnumProperty(
        name="Format",
        items=(("GLTF", "glTF Binary (.glb)", "One self-contained file: Unity, Unreal, Godot, three.js, USD tools"),
               ("FBX", "FBX (.fbx)", "Maya, MotionBuilder, Unreal and Unity's FBX importers")),
        default="GLTF",
    )
    filter_glob: bpy.props.StringProperty(default="*.glb;*.fbx", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "character", "shape keys")

    def check(self, _context):
        """Keep the file name's suffix the format's (the file browser calls this on every change)."""
        root, ext = os.path.splitext(self.filepath)
        wanted = SUFFIX[self.format]
        if self.filepath and ext.lower() != wanted:
            self.filepath = (root if ext.lower() in FORMATS else self.filepath) + wanted
            return True
        return False

    def invoke(self, context, _event):
        if not self.filepath:
            s = context.scene.facecap
            base = bpy.path.abspath("//") or os.path.expanduser("~")
            self.filepath = os.path.join(base, (s.take_name or s.target.name) + SUFFIX[self.format])
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        s = context.scene.facecap
        path = bpy.path.abspath(self.filepath)
        if os.path.splitext(path)[1].lower() in FORMATS:
            self.format = FORMATS[os.path.splitext(path)[1].lower()]
        else:
            path += SUFFIX[self.format]
        head = ""
        if s.head_target is not None:
            head = s.head_target.name + (f":{s.head_bone}" if s.head_target.type == "ARMATURE" and s.head_bone else "")
        try:
            info = export_take(s.target, path, head_target=head, take_name=s.take_name or None)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        head_note = f" and the head motion of '{info['head']}'" if info["head"] else ""
        self.report({"INFO"}, f"Exported {info['shapes']} shapes over frames {info['frames'][0]}-{info['frames'][1]}"
                              f"{head_note} to {info['path']}")
        return {"FINISHED"}


CLASSES = (FACECAP_OT_export_take,)
