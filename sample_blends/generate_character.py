"""Build and save the deterministic sample character ``sample_blends/character.blend``.

Run headless with the bpy wheel of the **oldest supported Blender** (4.2), so that the committed file
opens in every supported version (a file saved by 5.0 has a new header that 4.2 cannot read; newer
versions read older files)::

    python3.11 -m venv /tmp/bpy42 && /tmp/bpy42/bin/pip install bpy==4.2.23 numpy==1.24.3
    /tmp/bpy42/bin/python sample_blends/generate_character.py [--output PATH] [--layout PATH]

The geometry (mesh, 52 ARKit shape keys, marker patches) comes from the numpy-only
``character_geometry.build_character()``; this script only writes it into Blender
data with ``foreach_set`` and saves a compressed .blend plus ``marker_layout.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import bpy
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def _import_repo_as_facecap():
    """Make this checkout importable as ``facecap`` when it is not installed (e.g. in a bare bpy 4.2 venv)."""
    import importlib.util

    try:
        import facecap  # noqa: F401
        return
    except ImportError:
        pass
    spec = importlib.util.spec_from_file_location("facecap", HERE.parent / "__init__.py",
                                                  submodule_search_locations=[str(HERE.parent)])
    module = importlib.util.module_from_spec(spec)
    sys.modules["facecap"] = module
    spec.loader.exec_module(module)


_import_repo_as_facecap()

from character_geometry import MATERIALS, build_character  # noqa: E402

OBJECT_NAME = "Face"
MATERIAL_COLOURS = {
    "skin": (0.80, 0.60, 0.50, 1.0),
    "sclera": (0.95, 0.95, 0.93, 1.0),
    "iris": (0.12, 0.22, 0.35, 1.0),
    "tongue": (0.75, 0.30, 0.32, 1.0),
    "lips": (0.72, 0.38, 0.38, 1.0),
}


def _new_mesh_object(geo):
    mesh = bpy.data.meshes.new(OBJECT_NAME)
    mesh.from_pydata(geo.vertices.tolist(), [], [list(f) for f in geo.faces])
    mesh.validate(verbose=False)
    if len(mesh.vertices) != len(geo.vertices):
        raise RuntimeError("mesh validation changed the vertex count")
    mesh.vertices.foreach_set("co", geo.vertices.astype(np.float32).ravel())
    mesh.polygons.foreach_set("use_smooth", np.ones(len(mesh.polygons), dtype=bool))
    for name in MATERIALS:
        mat = bpy.data.materials.new(name)
        mat.diffuse_color = MATERIAL_COLOURS[name]
        mesh.materials.append(mat)
    mesh.polygons.foreach_set("material_index", geo.face_material.astype(np.int32))
    mesh.update()
    obj = bpy.data.objects.new(OBJECT_NAME, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _add_shape_keys(obj, geo):
    obj.shape_key_add(name="Basis", from_mix=False)
    for name, delta in geo.shape_keys.items():
        kb = obj.shape_key_add(name=name, from_mix=False)
        kb.slider_min, kb.slider_max, kb.value = 0.0, 1.0, 0.0
        kb.data.foreach_set("co", (geo.vertices + delta).astype(np.float32).ravel())
    obj.data.shape_keys.use_relative = True


def _add_vertex_groups(obj, geo):
    for marker in geo.markers:
        group = obj.vertex_groups.new(name=marker.name)
        for v, w in zip(marker.vertices, marker.weights):
            group.add([int(v)], float(w), "REPLACE")


def layout_dict(geo):
    return {
        "object": OBJECT_NAME,
        "markers": [
            {"name": m.name, "stable": m.stable, "region": m.region, "description": m.description}
            for m in geo.markers
        ],
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=HERE / "character.blend")
    parser.add_argument("--layout", type=Path, default=HERE / "marker_layout.json")
    args = parser.parse_args(argv)

    geo = build_character()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.context.preferences.filepaths.save_version = 0   # no character.blend1 backup
    obj = _new_mesh_object(geo)
    _add_shape_keys(obj, geo)
    _add_vertex_groups(obj, geo)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    bpy.ops.wm.save_as_mainfile(filepath=str(args.output.resolve()), compress=True)
    args.layout.write_text(json.dumps(layout_dict(geo), indent=2) + "\n")
    print(f"Saved {args.output} ({len(geo.vertices)} vertices, {len(geo.shape_keys)} shape keys, "
          f"{len(geo.markers)} markers)")


if __name__ == "__main__":
    main(sys.argv[1:] if "--" not in sys.argv else sys.argv[sys.argv.index("--") + 1:])
