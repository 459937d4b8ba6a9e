"""The structure cannot rot: the project's import graph, built with ``ast`` from every module-level and
function-level import, has no cycle and no upward import; function-level imports only defer a heavy
module (scipy, OpenCV, Blender), each with a reason; no private name crosses a module; files stay small."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
HEAVY = {"scipy", "cv2", "bpy", "bpy_extras", "mathutils", "bmesh", "dask", "distributed",  # dask: optional
         "ai_edge_litert", "mediapipe"}  # the landmark runtimes benchmark's references, when installed
MAX_LINES = 500
LONG_FILES = {"sample_blends/character_geometry.py"}  # the generated character's geometry tables

#: Layers, top first: a module may import only from a lower layer or from its own package.
LAYERS = (
    ("facecap", 100),
    ("facecap.operators", 90),
    ("facecap.facecap_addon", 80),
    ("facecap.solvers", 75),  # the package's public face
    ("facecap.solvers.tools", 70),
    ("facecap.solvers.config", 60),
    ("facecap.solvers.solve", 55),
    ("facecap.solvers.rig", 52),  # a rig as the target: above the pipeline it finishes, below the solve path
    ("facecap.solvers.tuning", 50),
    ("facecap.solvers.video", 50),
    ("facecap.solvers.pipeline", 40),
    ("facecap.solvers.strategies", 30),
    ("facecap.solvers.rom", 25),  # range-of-motion sessions: below the strategies that learn from them
    ("facecap.solvers.character", 22),
    ("facecap.solvers.capture", 21),
    ("facecap.solvers.engine", 10),
    ("facecap.solvers.io", 10),
    ("facecap.solvers.markers", 0),
    ("facecap.solvers.transforms", 0),
    ("facecap.solvers.errors", -1),
    ("facecap.solvers.options", -1),
    ("facecap.solvers.extension_builds", -2),
)


def _modules():
    paths = [ROOT / "__init__.py"]
    for folder in ("operators", "facecap_addon", "solvers"):
        paths += sorted((ROOT / folder).rglob("*.py"))
    out = {}
    for path in paths:
        parts = path.relative_to(ROOT).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(("facecap",) + parts)] = path
    return out


MODULES = _modules()


def _layer(module):
    """(rank, package) of the longest LAYERS prefix of ``module``."""
    best = max((p for p, _ in LAYERS if module == p or module.startswith(p + ".")), key=len)
    return dict(LAYERS)[best], best


class Import:
    def __init__(self, module, path, node, target, lazy):
        self.module, self.path, self.node, self.target, self.lazy = module, path, node, target, lazy

    def where(self):
        return f"{self.path.relative_to(ROOT)}:{self.node.lineno}"


def _imports():
    out = []
    for module, path in MODULES.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        lazy = {id(n) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
                for n in ast.walk(f) if isinstance(n, (ast.Import, ast.ImportFrom))}
        package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1])
                    base = base + ("." + node.module if node.module else "")
                else:
                    base = node.module
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
            else:
                continue
            out += [Import(module, path, node, t, id(node) in lazy) for t in dict.fromkeys(targets)]
    return out


IMPORTS = _imports()


def _project(target):
    """The project module ``target`` names (a module, or the package holding a name), or None."""
    while target and target not in MODULES:
        target = target.rpartition(".")[0]
    return target or None


def _heavy():
    """{module: heavy third-party modules it loads at import time, through module-level imports}."""
    edges = {m: set() for m in MODULES}
    direct = {m: set() for m in MODULES}
    for imp in IMPORTS:
        if imp.lazy:
            continue
        top = imp.target.split(".")[0]
        if top in HEAVY:
            direct[imp.module].add(top)
        elif _project(imp.target):
            edges[imp.module].add(_project(imp.target))
    heavy = {}

    def visit(m, seen):
        if m not in heavy:
            seen.add(m)
            heavy[m] = set(direct[m]).union(*(visit(t, seen) for t in edges[m] if t not in seen))
        return heavy[m]

    for m in MODULES:
        visit(m, set())
    return heavy


def test_no_import_cycles():
    graph = {m: set() for m in MODULES}
    for imp in IMPORTS:
        target = _project(imp.target)
        if target and target != imp.module:
            graph[imp.module].add(target)
    index, low, stack, on, cycles = {}, {}, [], set(), []

    def strongconnect(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                strongconnect(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in graph:
        if v not in index:
            strongconnect(v)
    assert not cycles, f"import cycles: {cycles}"


def test_imports_only_go_down():
    upward = []
    for imp in IMPORTS:
        target = _project(imp.target)
        if not target or target == imp.module:
            continue
        (rank, layer), (to_rank, to_layer) = _layer(imp.module), _layer(target)
        if to_layer != layer and to_rank >= rank:
            upward.append(f"{imp.where()} {imp.module} -> {target}")
    assert not upward, "imports must go down the layers (operators -> facecap_addon -> solvers; inside solvers " \
                       "tools > config > solve > tuning/video > pipeline > strategies > character > capture > " \
                       "engine/io > base):\n" + "\n".join(upward)


def test_function_level_imports_only_defer_heavy_modules_and_say_why():
    heavy = _heavy()
    lines = {p: p.read_text(encoding="utf-8").splitlines() for p in MODULES.values()}
    bad = []
    for imp in (i for i in IMPORTS if i.lazy):
        top = imp.target.split(".")[0]
        target = _project(imp.target)
        defers = top in HEAVY or (target is not None and heavy[target] - heavy[imp.module])
        text = lines[imp.path]
        said = any("#" in line for line in text[imp.node.lineno - 1: imp.node.end_lineno]) \
            or text[imp.node.lineno - 2].strip().startswith("#")
        if not defers:
            bad.append(f"{imp.where()} imports {imp.target} in a function; nothing heavy is deferred: import it at "
                       "the top")
        elif not said:
            bad.append(f"{imp.where()} defers {imp.target}: say why in a comment")
    assert not bad, "\n".join(bad)


def test_no_private_names_cross_modules():
    crossing = [f"{imp.where()} imports {a.name} from {imp.target}" for imp in IMPORTS
                if isinstance(imp.node, ast.ImportFrom) and _project(imp.target)
                for a in imp.node.names if a.name.startswith("_") and not a.name.startswith("__")]
    assert not crossing, "\n".join(crossing)


def test_solvers_never_import_blender():
    not_blender = {"scipy", "cv2", "ai_edge_litert", "mediapipe"}
    blender = [f"{i.where()} imports {i.target}" for i in IMPORTS
               if i.module.startswith("facecap.solvers") and i.target.split(".")[0] in HEAVY - not_blender]
    assert not blender, "\n".join(blender)


@pytest.mark.parametrize("folder", ["solvers", "facecap_addon", "operators", "tests", "sample_blends"])
def test_files_stay_small(folder):
    long = {str(p.relative_to(ROOT)): n for p in (ROOT / folder).rglob("*.py")
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES
            and str(p.relative_to(ROOT)) not in LONG_FILES}
    assert not long, f"files above {MAX_LINES} lines (split them along a seam): {long}"


def test_solvers_top_level_is_a_few_modules_and_packages():
    modules = sorted(p.name for p in (ROOT / "solvers").glob("*.py"))
    packages = sorted(p.name for p in (ROOT / "solvers").iterdir() if (p / "__init__.py").is_file())
    assert len(modules) <= 8, f"solvers/ should hold packages, not flat modules: {modules}"
    assert {"engine", "io", "capture", "character", "strategies", "pipeline", "tuning", "video", "config",
            "tools"} <= set(packages)
