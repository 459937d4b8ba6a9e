"""Generate the sample take from the sample character (deterministic).

Run with the project environment (bpy wheel, ``pip install -e .``)::

    python sample_blends/generate_take.py

Writes, next to this file:
  character_basis.npz     the character's 52 shape keys sampled at its marker bindings (for Blender-free tests)
  sample_take.csv         markers (mm) with head motion, noise sigma 0.3 mm and ~5% gaps on non-stable markers
  sample_take_clean.csv   the same performance and head motion without noise or gaps
  sample_take_weights.csv ground-truth weights (frame,<shape>,...)
  sample_take_head.csv    ground-truth head rotation per frame (rotation vector in degrees, capture axes)
"""

import json
from pathlib import Path

import bpy
import numpy as np

from facecap.facecap_addon.scene.scene_data import basis_from_object
from facecap.solvers.io.csv import write_markers_csv, write_weights_csv
from facecap.solvers.tools.synthetic.synth import performance_weights, synthesize_take

HERE = Path(__file__).resolve().parent
N_FRAMES = 720  # 12 s at 60 fps
FPS = 60.0
REST = 60  # neutral T-pose hold at the start and at the end


def main():
    layout = json.loads((HERE / "marker_layout.json").read_text())
    names = [m["name"] for m in layout["markers"]]
    stable = [m["name"] for m in layout["markers"] if m["stable"]]
    bpy.ops.wm.open_mainfile(filepath=str(HERE / "character.blend"), load_ui=False)
    basis = basis_from_object(bpy.data.objects[layout["object"]], names)
    basis.save_npz(HERE / "character_basis.npz")

    weights = performance_weights(basis.shape_names, N_FRAMES, fps=FPS, rest=REST, seed=0)
    take = synthesize_take(basis, weights, fps=FPS, rest=REST, stable=stable, units="mm", seed=2)
    write_markers_csv(HERE / "sample_take.csv", take.markers)
    write_markers_csv(HERE / "sample_take_clean.csv", take.clean)
    write_weights_csv(HERE / "sample_take_weights.csv", take.markers.frames, basis.shape_names, weights)
    head = np.column_stack([take.markers.frames, take.head_rotvec_deg])
    np.savetxt(HERE / "sample_take_head.csv", head, delimiter=",", fmt=["%d", "%.9f", "%.9f", "%.9f"],
               header="frame,head_rx_deg,head_ry_deg,head_rz_deg", comments="")
    gaps = np.isnan(take.markers.positions[:, :, 0]).mean()
    print(f"wrote {N_FRAMES} frames, {len(names)} markers ({len(stable)} stable), {gaps:.1%} gaps")


if __name__ == "__main__":
    main()
