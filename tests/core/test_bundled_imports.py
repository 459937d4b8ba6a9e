"""Every import the add-on can reach at run time is available in a real Blender with the extension zip.

A real Blender has its own Python with the standard library, Blender's modules and a few third-party
packages (numpy, requests, zstandard and their dependencies), and nothing else: scipy and OpenCV come
only from the wheels bundled in the extension zip (``wheels.lock.toml``). This walks the source that
ships (``__init__.py``, ``__main__.py``, ``facecap_addon/``, ``operators/``, ``solvers/``) with ``ast``,
collecting module-level and function-level imports plus the modules named to ``importlib.import_module``
and ``__import__``, and fails on any that is neither.
"""

import ast
import sys
from pathlib import Path

from facecap.solvers.tools.build_extension import read_lock

REPO = Path(__file__).resolve().parents[2]
SHIPPED = ["__init__.py", "__main__.py", "facecap_addon", "operators", "solvers"]

#: Modules compiled into Blender or shipped in its scripts folders (4.2-5.0).
BLENDER_MODULES = {"bpy", "bpy_extras", "bpy_types", "mathutils", "bmesh", "gpu", "gpu_extras", "blf", "bl_math",
                   "bl_ui", "bl_operators", "addon_utils", "aud", "idprop", "imbuf", "freestyle", "rna_prop_ui"}
#: Third-party packages in Blender's own site-packages (4.2-5.0); numpy is the one the add-on may use.
BLENDER_SITE_PACKAGES = {"numpy", "requests", "zstandard", "certifi", "idna", "urllib3", "charset_normalizer"}
#: Optional packages of headless features, never reached from the sidebar, each absent-safe: the reason.
OPTIONAL = {
    "tqdm": "batch's progress bar; without it (as in Blender's Python) batch prints plain lines",
    "dask": "batch --scheduler only (the 'farm' extra); without it that option is one line naming the extra",
    "distributed": "as dask",
    "ai_edge_litert": "landmarker_runtimes (a developer's benchmark) only: the reference runtime, used when installed",
    "mediapipe": "landmarker_runtimes only, as ai_edge_litert: the reference pipeline, used when installed",
}
#: Calls whose first argument names a module that is imported at run time.
IMPORT_CALLS = {"import_module", "__import__"}


def shipped_files():
    for entry in SHIPPED:
        path = REPO / entry
        yield from (sorted(path.rglob("*.py")) if path.is_dir() else [path])


def runtime_imports(path):
    """(top-level module, line) for every absolute import and literal dynamic import in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from ((alias.name.split(".")[0], node.lineno) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            yield node.module.split(".")[0], node.lineno
        elif isinstance(node, ast.Call) and node.args:
            name = getattr(node.func, "id", None) or getattr(node.func, "attr", None)
            arg = node.args[0]
            if name in IMPORT_CALLS and isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                yield arg.value.split(".")[0], node.lineno


def test_every_runtime_import_is_blenders_or_bundled():
    _, wheel_imports = read_lock()
    allowed = set(sys.stdlib_module_names) | BLENDER_MODULES | BLENDER_SITE_PACKAGES | set(wheel_imports) | set(OPTIONAL)
    seen, unknown = set(), []
    for path in shipped_files():
        for module, line in runtime_imports(path):
            seen.add(module)
            if module not in allowed:
                unknown.append(f"{path.relative_to(REPO)}:{line}: {module}")
    assert unknown == [], "imports that a real Blender with the extension zip cannot satisfy:\n" + "\n".join(unknown)
    # The walk does see what it is meant to police (it would pass vacuously otherwise).
    assert {"bpy", "numpy", "scipy", "cv2"} <= seen, sorted(seen)


def test_optional_packages_are_absent_safe(monkeypatch):
    """Without tqdm batch still shows progress (plain lines); without Dask --scheduler is one line."""
    import builtins

    import pytest

    real = builtins.__import__

    def no_optional(name, *args, **kwargs):
        if name.split(".")[0] in OPTIONAL:
            raise ImportError(f"No module named '{name}'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_optional)
    import importlib

    import facecap.facecap_addon.batch.batch_progress as progress

    progress = importlib.reload(progress)
    assert progress.tqdm is None
    from facecap.facecap_addon.batch.batch_farm import FarmPool
    from facecap.solvers.errors import FacecapError

    with pytest.raises(FacecapError, match=r'Dask distributed, which is not installed: pip install "facecap\[farm\]"'):
        FarmPool("tcp://127.0.0.1:1").run([], None)
    monkeypatch.setattr(builtins, "__import__", real)
    importlib.reload(progress)


def test_the_addon_never_imports_itself_by_its_development_name():
    """Inside Blender the package is ``bl_ext.<repo>.facecap``: an absolute ``facecap`` import breaks there."""
    found = [f"{p.relative_to(REPO)}:{line}" for p in shipped_files()
             for m, line in runtime_imports(p) if m == "facecap"]
    assert found == []


def test_numpy_is_never_bundled():
    wheels, imports = read_lock()
    assert "numpy" not in imports and not any(w.name == "numpy" for w in wheels)
