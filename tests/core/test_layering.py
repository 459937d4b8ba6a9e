"""The core never imports Blender modules."""

import subprocess
import sys


def test_import_solvers_does_not_import_bpy():
    code = ("import sys, facecap.solvers, facecap.solvers.tools.synthetic.synth; "
            "print(sorted(m for m in ('bpy', 'mathutils', 'bmesh') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_import_facecap_package_does_not_import_bpy():
    code = "import sys, facecap; print('bpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
