"""The artist's workflow, run by a bpy-wheel Python of one supported Blender (not by pytest).

    python matrix_workflow.py INPUTS.json RESULT.json

The extension zip is installed and enabled with Blender's own installer into the user folders the
environment points at (``BLENDER_USER_*``, set by the caller before Blender starts); then every step
runs through ``bpy.ops`` as the sidebar would. Each step's outcome (``"ok"`` or the error) and what it
produced is written to RESULT.json for the test to judge against ground truth; a step that fails does
not stop the steps that do not depend on it. No project code is imported from the repository: the
add-on's helpers come from the installed extension (``bl_ext.user_default.facecap``).
"""

import base64
import importlib
import importlib.util
import json
import os
import re
import sys
import tempfile
import time
import traceback

import bpy
import numpy as np

ADDON = "bl_ext.user_default.facecap"
WEAK, WEAK_SCALE = ("jawOpen", "mouthSmileLeft", "browInnerUp", "eyeBlinkLeft"), 0.5
FLOW_SHAPES = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "browDownLeft", "browDownRight", "cheekPuff")


class Workflow:
    def __init__(self, inputs):
        self.inp = inputs
        self.out = {"steps": {}}

    def step(self, name, fn):
        start = time.perf_counter()
        try:
            value = fn()
            self.out["steps"][name] = "ok"
            if value is not None:
                self.out[name] = value
        except Exception as exc:  # recorded for the test to show; later independent steps still run
            self.out["steps"][name] = f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=4)}"
        self.out.setdefault("seconds", {})[name] = round(time.perf_counter() - start, 3)

    # -- helpers from the installed add-on
    def addon(self, module):
        return importlib.import_module(f"{ADDON}.{module}")

    def solved(self, names):
        anim, layers = self.addon("facecap_addon.scene.anim"), self.addon("facecap_addon.scene.layers")
        key = bpy.data.objects["Face"].data.shape_keys
        frames, values = anim.read_curves(key, [(layers.shape_path(n), 0) for n in names],
                                          action=layers.solved_action(key))
        return frames, values

    def shape_names(self):
        key = bpy.data.objects["Face"].data.shape_keys
        return [b.name for b in key.key_blocks if b != key.reference_key]

    # -- steps
    def environment(self):
        return {
            "blender": list(bpy.app.version),
            "numpy": np.__version__,
            "python": list(sys.version_info[:3]),
            "importable_before_install": {m: importlib.util.find_spec(m) is not None for m in ("scipy", "cv2")},
        }

    def other_build_refused(self):
        """The zip of the other Python generation: Blender's installer refuses it, saying why."""
        out = self.inp["other_zip"]
        with tempfile.TemporaryFile(mode="w+") as log:
            sys.stdout.flush()
            saved = os.dup(1)
            os.dup2(log.fileno(), 1)  # the installer's messages, printed by Blender and by Python
            try:
                result = bpy.ops.extensions.package_install_files(filepath=out, repo="user_default",
                                                                  enable_on_install=True)
            finally:
                sys.stdout.flush()
                os.dup2(saved, 1)
                os.close(saved)
            log.seek(0)
            text = log.read()
        folder = os.path.join(bpy.utils.user_resource("EXTENSIONS"), "user_default", "facecap")
        return {"result": sorted(result), "output": text, "installed": os.path.isdir(folder),
                "enabled": ADDON in bpy.context.preferences.addons}

    def install(self):
        start = time.perf_counter()
        result = bpy.ops.extensions.package_install_files(filepath=self.inp["zip"], repo="user_default",
                                                          enable_on_install=True)
        seconds = time.perf_counter() - start
        module = sys.modules.get(ADDON)
        return {"result": sorted(result), "seconds": seconds, "enabled": ADDON in bpy.context.preferences.addons,
                "module_file": getattr(module, "__file__", None),
                "extensions_dir": bpy.utils.user_resource("EXTENSIONS"),
                "heavy_after_enable": [m for m in ("scipy", "cv2") if m in sys.modules]}

    def open_sample(self):
        bpy.ops.wm.open_mainfile(filepath=self.inp["blend"])
        bpy.ops.wm.save_as_mainfile(filepath=self.inp["work_blend"])  # never write next to the sample
        return {"objects": sorted(bpy.data.objects.keys()), "file_version": list(bpy.data.version)}

    def import_markers(self):
        r = bpy.ops.facecap.import_markers(filepath=self.inp["take"], units="mm", fps=60.0)
        s = bpy.context.scene.facecap
        return {"result": sorted(r), "markers": len(s.markers), "take": s.take_name,
                "frames": [bpy.context.scene.frame_start, bpy.context.scene.frame_end]}

    def suggest_stable(self):
        r = bpy.ops.facecap.suggest_stable()
        return {"result": sorted(r), "stable": sorted(m.name for m in bpy.context.scene.facecap.markers if m.stable)}

    def detect_neutral(self):
        r = bpy.ops.facecap.detect_neutral()
        return {"result": sorted(r), "mode": bpy.context.scene.facecap.neutral_mode}

    def set_neutral(self):
        s = bpy.context.scene.facecap
        s.neutral_mode = "RANGE"  # the artist switches back to the T-pose hold at the start
        r = bpy.ops.facecap.set_neutral(first=1, last=50)
        return {"result": sorted(r), "range": [s.neutral_first, s.neutral_last]}

    def stabilise(self):
        r = bpy.ops.facecap.stabilise()
        s = bpy.context.scene.facecap
        return {"result": sorted(r), "head": s.head_object.name if s.head_object else None,
                "flagged": s.flagged_frames}

    def clean_markers(self):
        r = bpy.ops.facecap.clean_markers()  # defaults: spline fill of gaps up to 8 frames
        return {"result": sorted(r), "take": bpy.context.scene.facecap.take_name}

    def solve(self):
        s = bpy.context.scene.facecap
        s.target = bpy.data.objects["Face"]
        assert bpy.ops.facecap.refresh_shapes() == {"FINISHED"}
        r = bpy.ops.facecap.solve()  # default settings
        names = self.shape_names()
        frames, values = self.solved(names)
        return {"result": sorted(r), "names": names, "frames": frames.tolist(), "weights": values.tolist(),
                "action": s.last_action, "strategy": s.strategy}

    def retune(self):
        """The case the tuning loop is for: the character's sculpted shapes are weaker than the actor's
        expressions (WEAK at 50%), so the solve over-drives them; the animator keys the true pose on the
        worst frames on the layer above the solve, adds the edited frames and retunes."""
        s, scene = bpy.context.scene.facecap, bpy.context.scene
        key = bpy.data.objects["Face"].data.shape_keys
        basis = np.empty(len(key.reference_key.data) * 3, np.float32)
        key.reference_key.data.foreach_get("co", basis)
        for name in WEAK:
            co = np.empty_like(basis)
            key.key_blocks[name].data.foreach_get("co", co)
            key.key_blocks[name].data.foreach_set("co", basis + WEAK_SCALE * (co - basis))
        assert bpy.ops.facecap.solve() == {"FINISHED"}
        names = self.shape_names()
        truth_names, truth = self.inp["truth_names"], np.asarray(self.inp["truth"])
        order = [truth_names.index(n) for n in names]
        frames, before = self.solved(names)
        err = np.abs(before - truth[:, order]).max(axis=1)
        rows = []
        for t in np.argsort(-err, kind="stable"):  # the worst frames, at least 30 apart
            if all(abs(int(t) - r) >= 30 for r in rows):
                rows.append(int(t))
            if len(rows) == 8:
                break
        for t in sorted(rows):  # the whole true pose, keyed on the layer above the solve
            scene.frame_set(int(frames[t]))
            for k, n in enumerate(names):
                key.key_blocks[n].value = float(truth[t, order[k]])
                key.key_blocks[n].keyframe_insert("value", frame=int(frames[t]))
        added = bpy.ops.facecap.tuning_add_edited()
        r = bpy.ops.facecap.retune()
        _, after = self.solved(names)
        version = s.library_versions[0] if len(s.library_versions) else None
        return {"add_edited": sorted(added), "result": sorted(r), "rows": sorted(rows), "report": s.last_report,
                "tuning_frames": [t.frame for t in s.tuning_frames], "before": before.tolist(),
                "weights": after.tolist(), "library_active": s.library_active,
                "corrected": [version.corrected_before, version.corrected_after] if version else None}

    def track_clip(self):
        scene = bpy.context.scene
        clip = bpy.data.movieclips.load(self.inp["track_clip"])
        scene.active_clip, scene.frame_current = clip, 1
        width, height = clip.size
        for i, (x, y) in enumerate(self.inp["track_seeds"]):
            track = clip.tracking.tracks.new(name=f"p{i}", frame=1)
            track.markers.insert_frame(1, co=(x / width, 1.0 - y / height))
        r = bpy.ops.facecap.track_clip()
        markers = self.addon("facecap_addon.scene.take").markers_from_collection(scene.facecap)
        order = [markers.names.index(f"p{i}") for i in range(len(self.inp["track_seeds"]))]
        return {"result": sorted(r), "size": [width, height], "dim": markers.dim, "units": markers.units,
                "positions": np.nan_to_num(markers.positions[:, order], nan=1e9).tolist()}

    def solve_clip_flow(self):
        scene, s = bpy.context.scene, bpy.context.scene.facecap
        anim, flow = self.addon("facecap_addon.scene.anim"), self.inp["flow"]
        key = bpy.data.objects["Face"].data.shape_keys
        posed = np.asarray(flow["posed"])
        posed_action = anim.new_action_with_curves(
            key, name="posed", curves=[(f'key_blocks["{n}"].value', 0) for n in FLOW_SHAPES],
            frames=posed + 1.0, values=np.asarray(flow["posed_weights"]))
        clip = bpy.data.movieclips.load(flow["clip"])
        s.target, s.examples_action = bpy.data.objects["Face"], posed_action
        v = s.video
        v.region, v.stable_region, v.flow_components = (24, 18, 192, 144), (48, 9, 144, 18), 10
        scene.active_clip, scene.frame_current = clip, 1
        r = bpy.ops.facecap.solve_clip_flow()
        names = self.shape_names()
        _, values = self.solved(names)
        return {"result": sorted(r), "names": names, "weights": values.tolist(), "action": s.last_action}

    def save_and_reopen(self):
        s = bpy.context.scene.facecap
        names = self.shape_names()
        _, before = self.solved(names)
        state = (s.take_name, s.last_action, s.library_active, len(s.markers))
        path = self.inp["saved_blend"]
        assert bpy.ops.wm.save_as_mainfile(filepath=path) == {"FINISHED"}
        assert bpy.ops.wm.open_mainfile(filepath=path) == {"FINISHED"}
        s = bpy.context.scene.facecap
        _, after = self.solved(names)
        return {"state_before": list(state), "state_after": [s.take_name, s.last_action, s.library_active,
                                                             len(s.markers)],
                "solve_layer_max_change": float(np.nanmax(np.abs(after - before))),
                "actions": sorted(bpy.data.actions.keys())}

    def export_review(self):
        """Export Review Report with the extension's own plotly.js (no plotly package in this Blender) and
        its contact sheet rendered with this Blender's Workbench."""
        path = self.inp["review_html"]
        r = bpy.ops.facecap.export_review(filepath=path, render=True)
        text = open(path, encoding="utf-8").read() if os.path.isfile(path) else ""
        tiles = re.findall(r'<img id="tile-(\d+)" src="data:image/png;base64,([^"]+)"', text)
        return {"result": sorted(r), "bytes": len(text), "has_plotly_js": "plotly.js v" in text,
                "plotly_package": importlib.util.find_spec("plotly") is not None, "tiles": len(tiles),
                "binding_tile": 'id="tile-binding"' in text,
                "face_fraction": [self.face_fraction(base64.b64decode(png)) for _, png in tiles]}

    @staticmethod
    def face_fraction(png):
        """The share of a rendered tile that is not the white background (Blender decodes the PNG)."""
        with tempfile.NamedTemporaryFile(suffix=".png", delete=False) as fh:
            fh.write(png)
        try:
            img = bpy.data.images.load(fh.name)
            w, h = img.size
            px = np.empty(w * h * 4, dtype=np.float32)
            img.pixels.foreach_get(px)
            bpy.data.images.remove(img)
        finally:
            os.remove(fh.name)
        rgb = np.round(px.reshape(h, w, 4)[:, :, :3] * 255.0)
        return float((rgb.min(axis=2) < 250).mean())

    def bind_by_position(self):
        """The sample take with its markers renamed (no vertex group matches): bound by position to the
        sample character (nearest surface point after an automatic alignment), then solved."""
        scene_data = self.addon("facecap_addon.scene.scene_data")
        scene_binding = self.addon("facecap_addon.scene.scene_binding")
        bpy.ops.wm.open_mainfile(filepath=self.inp["blend"])
        obj = bpy.data.objects["Face"]
        rename = self.inp["rename"]
        mesh = scene_data.mesh_from_object(obj)
        truth_points = {rename[n]: w @ mesh.vertices[i] for n, (i, w) in mesh.vertex_groups.items() if n in rename}
        obj.vertex_groups.clear()  # nothing to bind by name
        assert bpy.ops.facecap.import_markers(filepath=self.inp["renamed_take"], units="mm", fps=60.0) == {"FINISHED"}
        s = bpy.context.scene.facecap
        stable = set(self.inp["renamed_stable"])
        for item in s.markers:
            item.stable = item.name in stable
        s.neutral_first, s.neutral_last = 1, 50
        s.target, s.binding_mode = obj, "nearest"
        r = bpy.ops.facecap.bind_markers()
        empties = [o for o in bpy.data.collections[scene_binding.COLLECTION].objects if o.parent == obj]
        err_mm = [float(np.linalg.norm(np.array(e.location) - truth_points[e[scene_binding.TAG]]) * 1000)
                  for e in empties]
        assert bpy.ops.facecap.refresh_shapes() == {"FINISHED"}
        solved = bpy.ops.facecap.solve()
        names = self.shape_names()
        _, values = self.solved(names)
        return {"result": sorted(r), "summary": s.binding_summary, "points": len(empties), "error_mm": err_mm,
                "solve": sorted(solved), "names": names, "weights": values.tolist()}

    def bundled_modules(self):
        import cv2
        import scipy

        return {"scipy": [scipy.__version__, scipy.__file__], "cv2": [cv2.__version__, cv2.__file__]}

    def run(self):
        self.step("environment", self.environment)
        self.step("other_build_refused", self.other_build_refused)
        self.step("install", self.install)
        for name in ("open_sample", "import_markers", "suggest_stable", "detect_neutral", "set_neutral", "stabilise",
                     "clean_markers", "solve", "export_review", "retune", "track_clip", "solve_clip_flow",
                     "save_and_reopen", "bind_by_position", "bundled_modules"):
            self.step(name, getattr(self, name))
        return self.out


def main():
    inputs_path, result_path = sys.argv[-2:]
    with open(inputs_path, encoding="utf-8") as fh:
        inputs = json.load(fh)
    out = Workflow(inputs).run()
    with open(result_path, "w", encoding="utf-8") as fh:
        json.dump(out, fh)


if __name__ == "__main__":
    main()
