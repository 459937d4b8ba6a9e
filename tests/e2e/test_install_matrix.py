# SPDX-License-Identifier: GPL-3.0-or-later
"""The install matrix: the built linux-x64 zips in Blender 4.2 LTS, 4.5 LTS, 5.0, 5.2 LTS and 5.3, as an
artist uses them.

For each release a cached venv holds only that ``bpy`` wheel and the numpy the release bundles, on the
Python it runs (scipy and OpenCV are not importable: they must come from the zip). Blender's extension
installer first refuses the zip of the other Python generation, then installs and enables the release's
own into a temporary user folder; ``matrix_workflow.py`` runs the artist's workflow through ``bpy.ops`` on
the sample character and take; this file judges what it produced against the sample's ground truth and
against Blender 5.0's run. Enabling is timed in fresh processes (``matrix_enable.py``).
"""

import json
import os
import statistics
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from matrix_env import MATRIX, REFERENCE, PrerequisiteError, blender_env, blender_venv, missing_prerequisite

from facecap.solvers.extension_builds import BUILDS, build_for_python
from facecap.solvers.io import import_markers
from facecap.solvers.io.csv import read_weights_csv, write_markers_csv
from facecap.solvers.tools.build_extension import read_lock
from facecap.solvers.video.synthetic import write_synthetic_clip

pytestmark = pytest.mark.slow

HERE = Path(__file__).resolve().parent
SAMPLE = HERE.parents[1] / "sample_blends"
TIMEOUT = 1200
ENABLE_RUNS = 5
JOBS = min(2, os.cpu_count() or 1)  # releases run at once (CI has 2 cores)
RMSE_LIMIT = 0.03       # default-settings solve vs the sample's ground truth (the demo gives 0.018)
RMSE_SPREAD = 0.001     # every release's default solve within this of Blender 5.0's
TRACK_SEEDS = [[120.0, 100.0], [200.0, 110.0], [160.0, 170.0]]
FLOW_FRAMES, FLOW_AMP = 90, 4.0
FLOW_POSED = np.linspace(0, FLOW_FRAMES - 1, 15).round().astype(int)
FLOW_SHAPES = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "browDownLeft", "browDownRight", "cheekPuff")


@pytest.fixture(scope="session")
def footage(tmp_path_factory):
    """The two synthetic clips (written here, where OpenCV is installed) and their ground truth."""
    out = tmp_path_factory.mktemp("footage")
    track = write_synthetic_clip(out / "track.avi", 24, 320, 240, seed=3)
    flow = write_synthetic_clip(out / "flow.avi", FLOW_FRAMES, 240, 180, amplitude=FLOW_AMP, noise=1.0, seed=11,
                                period=24.0)
    seeds = np.array(TRACK_SEEDS)
    return {
        "track_clip": track.path,
        "track_truth": np.stack([track.motion.forward(t, seeds) for t in range(24)]),
        "flow_clip": flow.path,
        "flow_truth": flow.motion.amplitudes / FLOW_AMP,
    }


@pytest.fixture(scope="session")
def truth():
    _, names, weights = read_weights_csv(SAMPLE / "sample_take_weights.csv")
    return list(names), np.asarray(weights)


@pytest.fixture(scope="session")
def renamed_take(tmp_path_factory):
    """The sample take with every marker renamed mk00..mk67 (so no vertex group matches): its CSV, the
    renaming and the renamed stable markers (as tests/blender/test_binding_ui.py)."""
    take = import_markers(SAMPLE / "sample_take.csv", units="mm", fps=60).markers
    rename = {n: f"mk{i:02d}" for i, n in enumerate(np.random.default_rng(5).permutation(take.names))}
    path = tmp_path_factory.mktemp("binding") / "renamed.csv"
    write_markers_csv(path, take.with_positions(take.positions, names=tuple(rename[n] for n in take.names)))
    layout = json.loads((SAMPLE / "marker_layout.json").read_text(encoding="utf-8"))["markers"]
    return {"renamed_take": str(path), "rename": rename,
            "renamed_stable": sorted(rename[m["name"]] for m in layout if m["stable"])}


def _zip_for(extension_zips, python, other=False):
    """The linux-x64 zip of the build for ``python`` (or, with ``other``, of another build)."""
    mine = build_for_python(python)
    build = next(b for b in BUILDS if b != mine) if other else mine
    return str(extension_zips["zips"][(build.name, "linux-x64")])


@pytest.fixture(scope="session")
def workflows(request, cache_dir, extension_zips, footage, truth, renamed_take, tmp_path_factory):
    """``run(bpy_version)``: the whole workflow of one release and its enable timings. The releases the
    selected tests need (and Blender 5.0, which the others are compared with) all start at the first
    request, ``JOBS`` at a time: each is a Blender process of its own, mostly on one core."""
    wanted = {item.callspec.params["workflow"] for item in request.session.items
              if hasattr(item, "callspec") and "workflow" in item.callspec.params}
    wanted.add(REFERENCE)
    pool = ThreadPoolExecutor(max_workers=JOBS)
    jobs = {}

    def run(bpy_version):
        if not jobs:
            order = [v for v, _ in MATRIX]
            # Blender 5.0 first: every release's comparison waits for it
            for version in sorted(wanted, key=lambda v: (v != REFERENCE, order.index(v))):
                work = tmp_path_factory.mktemp(f"blender-{version}")  # here: mktemp is not for threads
                jobs[version] = pool.submit(_run_workflow, version, work, cache_dir, extension_zips, footage,
                                            truth, renamed_take)
        return jobs[bpy_version].result()  # a skip or a failure is raised again for every test that asks

    yield run
    pool.shutdown(cancel_futures=True)


def _run_workflow(bpy_version, work, cache_dir, extension_zips, footage, truth, renamed_take):
    # the Python the release runs: that of the build whose range has it (test_blender_coverage.py checks
    # the builds against the Python tags of the bpy wheels)
    numpy_version = dict(MATRIX)[bpy_version]
    python_version = next(b.python for b in BUILDS if b.covers(bpy_version))
    try:
        python = blender_venv(cache_dir, bpy_version, numpy_version, python_version)
    except PrerequisiteError as exc:
        missing_prerequisite(str(exc))
    user = work / "user"
    user.mkdir()
    names, weights = truth
    flow_truth = footage["flow_truth"]
    inputs = {
        "zip": _zip_for(extension_zips, python_version),
        "other_zip": _zip_for(extension_zips, python_version, other=True),
        "blend": str(SAMPLE / "character.blend"),
        "work_blend": str(work / "character.blend"),
        "saved_blend": str(work / "saved.blend"),
        "review_html": str(work / "review.html"),
        "take": str(SAMPLE / "sample_take.csv"),
        "truth_names": names,
        "truth": weights.tolist(),
        "track_clip": footage["track_clip"],
        "track_seeds": TRACK_SEEDS,
        "flow": {"clip": footage["flow_clip"], "posed": FLOW_POSED.tolist(),
                 "posed_weights": flow_truth[FLOW_POSED].tolist()},
        **renamed_take,
    }
    (work / "inputs.json").write_text(json.dumps(inputs), encoding="utf-8")
    proc = subprocess.run([str(python), str(HERE / "matrix_workflow.py"), str(work / "inputs.json"),
                           str(work / "result.json")], capture_output=True, text=True, timeout=TIMEOUT,
                          env=blender_env(user), cwd=work)
    assert proc.returncode == 0, \
        f"Blender {bpy_version} workflow crashed:\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}"
    result = json.loads((work / "result.json").read_text(encoding="utf-8"))
    seconds = result.get("seconds", {})
    steps = ", ".join(f"{k} {v:.1f}" for k, v in seconds.items())
    return {"result": result, "user": user, "log": proc.stdout + proc.stderr, "bpy": bpy_version,
            "numpy": numpy_version, "python": python, "python_version": python_version, "inputs": inputs,
            "enable": _time_enable(python, user), "summary": f"Blender {bpy_version} workflow: "
            f"{sum(seconds.values()):.0f} s ({steps})"}


def _time_enable(python, user):
    """Enable the installed extension in fresh processes (as at start-up), ``ENABLE_RUNS`` times."""
    runs = []
    for i in range(ENABLE_RUNS):
        out = user.parent / f"enable-{i}.json"
        proc = subprocess.run([str(python), str(HERE / "matrix_enable.py"), str(out)],
                              capture_output=True, text=True, timeout=TIMEOUT, env=blender_env(user))
        runs.append(json.loads(out.read_text(encoding="utf-8")) if proc.returncode == 0
                    else {"error": proc.stderr[-3000:]})
    return runs


@pytest.fixture(scope="session", params=[v for v, _ in MATRIX], ids=[f"blender-{v}" for v, _ in MATRIX])
def workflow(request, workflows):
    """The workflow's result in one release; the tests below judge it."""
    done = workflows(request.param)
    print(f"\n{done['summary']}")
    return done


def _ok(workflow, *steps):
    for step in steps:
        status = workflow["result"]["steps"].get(step, "did not run")
        assert status == "ok", f"Blender {workflow['bpy']}, step '{step}': {status}\n--- log tail ---\n" \
                               f"{workflow['log'][-3000:]}"


def _rmse(a):
    return float(np.sqrt(np.mean(np.square(a))))


def _weights_vs_truth(step, truth):
    names, weights = truth
    order = [names.index(n) for n in step["names"]]
    return np.asarray(step["weights"]) - weights[:, order]


def test_release_environment_has_no_scipy_or_opencv_of_its_own(workflow):
    _ok(workflow, "environment")
    env = workflow["result"]["environment"]
    assert ".".join(map(str, env["blender"])) == workflow["bpy"]
    assert env["numpy"] == workflow["numpy"]
    assert ".".join(map(str, env["python"][:2])) == workflow["python_version"]
    assert env["importable_before_install"] == {"scipy": False, "cv2": False}


def test_the_other_generations_zip_is_refused_with_the_reason(workflow):
    """A 4.2-5.0 zip in Blender 5.3 (or a 5.1+ zip in 4.2): nothing installed, and the installer says why."""
    _ok(workflow, "other_build_refused")
    refused = workflow["result"]["other_build_refused"]
    assert not refused["installed"] and not refused["enabled"]
    other = next(b for b in BUILDS if b != build_for_python(workflow["python_version"]))
    if other.blender_max is not None and not other.covers(workflow["bpy"]):  # a newer Blender than it is for
        why = f"This Blender version ({workflow['bpy']}) must be less than the maximum version ({other.blender_max})"
    else:
        why = (f"This Blender version ({workflow['bpy']}) doesn't meet the minimum supported version "
               f"({other.blender_min})")
    assert why in refused["output"], refused["output"][-2000:]


def test_zip_installs_and_enables_into_the_temporary_user_folder(workflow):
    _ok(workflow, "install", "bundled_modules")
    install, user = workflow["result"]["install"], workflow["user"].resolve()
    assert install["result"] == ["FINISHED"] and install["enabled"]
    assert Path(install["extensions_dir"]).resolve().is_relative_to(user)
    assert Path(install["module_file"]).resolve().is_relative_to(user)
    assert install["heavy_after_enable"] == []  # scipy and OpenCV load when a feature needs them
    print(f"\nBlender {workflow['bpy']}: installing the zip took {install['seconds']:.1f} s")
    bundled = workflow["result"]["bundled_modules"]
    wheels, _ = read_lock()
    locked = {w.name: w.version for w in wheels if w.python == workflow["python_version"]}
    assert bundled["scipy"][0] == locked["scipy"]
    assert locked["opencv-contrib-python-headless"].startswith(bundled["cv2"][0] + ".")  # 4.14.0 of 4.14.0.94
    for _, path in bundled.values():  # from the zip's wheels, installed by Blender into the user folder
        assert Path(path).resolve().is_relative_to(user), path


def test_sample_opens_and_markers_prepare(workflow):
    _ok(workflow, "open_sample", "import_markers", "suggest_stable", "detect_neutral", "set_neutral", "stabilise",
        "clean_markers")
    r = workflow["result"]
    assert "Face" in r["open_sample"]["objects"]
    assert r["import_markers"]["markers"] == 68 and r["import_markers"]["frames"] == [1, 720]
    layout = json.loads((SAMPLE / "marker_layout.json").read_text(encoding="utf-8"))["markers"]
    assert r["suggest_stable"]["stable"] == sorted(m["name"] for m in layout if m["stable"])  # the 8 head markers
    assert r["detect_neutral"]["mode"] == "DETECT"
    assert r["set_neutral"]["range"] == [1, 50]
    assert r["stabilise"]["head"] and r["stabilise"]["flagged"] == 0
    assert r["clean_markers"]["take"] == "sample_take clean"


def test_default_solve_matches_the_ground_truth(workflow, truth):
    _ok(workflow, "solve")
    solve = workflow["result"]["solve"]
    assert solve["result"] == ["FINISHED"] and solve["strategy"] == "geometric"
    err = _weights_vs_truth(solve, truth)
    assert err.shape == (720, 52)
    print(f"\nBlender {workflow['bpy']}: default solve RMSE {_rmse(err):.4f}, max {np.abs(err).max():.3f}")
    assert _rmse(err) <= RMSE_LIMIT


def test_default_solve_is_blender_5_0s_within_0_001(workflow, workflows, truth):
    """The same take, settings and add-on give the same accuracy in every release (its own NumPy, SciPy
    and OpenCV): RMSE against the ground truth within 0.001 of Blender 5.0's."""
    _ok(workflow, "solve")
    reference = workflows(REFERENCE)
    _ok(reference, "solve")
    rmse = _rmse(_weights_vs_truth(workflow["result"]["solve"], truth))
    ref = _rmse(_weights_vs_truth(reference["result"]["solve"], truth))
    print(f"\nBlender {workflow['bpy']}: default solve RMSE {rmse:.5f}, Blender {REFERENCE} {ref:.5f} "
          f"(difference {rmse - ref:+.5f})")
    assert abs(rmse - ref) <= RMSE_SPREAD


def test_corrected_frames_retune(workflow, truth):
    """Weakened shapes (see matrix_workflow.Workflow.retune) over-drive the solve; eight corrected frames
    retune the library: the corrected frames fit and the frames nobody touched improve (as
    tests/blender/test_tuning_ui.py)."""
    _ok(workflow, "retune")
    retune = workflow["result"]["retune"]
    assert retune["add_edited"] == ["FINISHED"] and retune["result"] == ["FINISHED"], retune["report"]
    rows = retune["rows"]
    assert retune["tuning_frames"] == [f + 1 for f in rows]  # the sample take starts at frame 1
    assert retune["library_active"], retune["report"]
    names = workflow["result"]["solve"]["names"]
    before = _weights_vs_truth({"names": names, "weights": retune["before"]}, truth)
    after = _weights_vs_truth({"names": names, "weights": retune["weights"]}, truth)
    held = np.setdiff1d(np.arange(before.shape[0]), rows)
    corrected = (_rmse(before[rows]), _rmse(after[rows]))
    others = (_rmse(before[held]), _rmse(after[held]))
    print(f"\nBlender {workflow['bpy']}: retune corrected frames {corrected[0]:.4f} -> {corrected[1]:.4f}, "
          f"other frames {others[0]:.4f} -> {others[1]:.4f}")
    assert corrected[1] <= 0.05 and corrected[1] < corrected[0]
    assert others[1] <= 0.85 * others[0]


def test_clip_tracks_follow_the_footage(workflow, footage):
    _ok(workflow, "track_clip")
    track = workflow["result"]["track_clip"]
    assert track["result"] == ["FINISHED"] and track["size"] == [320, 240]
    assert track["dim"] == 2 and track["units"] == "px"
    err = np.linalg.norm(np.asarray(track["positions"]) - footage["track_truth"], axis=2)
    print(f"\nBlender {workflow['bpy']}: clip tracks median error {np.median(err):.3f} px")
    assert np.median(err) <= 0.5  # as tests/blender/test_track_clip.py


def test_solve_from_clip_flow(workflow, footage):
    _ok(workflow, "solve_clip_flow")
    flow = workflow["result"]["solve_clip_flow"]
    assert flow["result"] == ["FINISHED"]
    values = np.asarray(flow["weights"])
    cols = [flow["names"].index(n) for n in FLOW_SHAPES]
    unposed = np.setdiff1d(np.arange(FLOW_FRAMES), FLOW_POSED)
    rmse = _rmse(values[unposed][:, cols] - footage["flow_truth"][unposed])
    print(f"\nBlender {workflow['bpy']}: solve from clip flow RMSE {rmse:.4f} on {unposed.size} unposed frames")
    assert values.shape[0] == FLOW_FRAMES and rmse <= 0.06  # as tests/blender/test_solve_clip_flow.py
    others = np.delete(values, cols, axis=1)
    assert np.abs(others).max() <= 1e-6  # shapes nobody posed stay at rest


def test_save_and_reopen_keeps_the_work(workflow):
    _ok(workflow, "save_and_reopen")
    saved = workflow["result"]["save_and_reopen"]
    assert saved["state_after"] == saved["state_before"]
    assert saved["solve_layer_max_change"] <= 1e-6
    r = workflow["result"]
    assert {r["solve"]["action"], r["solve_clip_flow"]["action"], "posed"} <= set(saved["actions"])


def test_export_review_report_works_with_the_bundled_plotly_and_renders(workflow):
    _ok(workflow, "export_review")
    review = workflow["result"]["export_review"]
    assert review["result"] == ["FINISHED"] and not review["plotly_package"]
    assert review["has_plotly_js"] and review["bytes"] > 3_000_000  # plotly.js embedded from the add-on
    # the contact sheet, rendered by this Blender's Workbench: the face fills each tile, with room around it
    assert review["tiles"] >= 6 and review["binding_tile"], review
    assert all(0.2 < f < 0.8 for f in review["face_fraction"]), review["face_fraction"]


def test_markers_bind_by_position_and_solve(workflow, renamed_take, truth):
    """Markers named nothing like the character's vertex groups, bound to the nearest surface point after
    the automatic alignment (as tests/blender/test_binding_ui.py), then solved."""
    _ok(workflow, "bind_by_position")
    bound = workflow["result"]["bind_by_position"]
    assert bound["result"] == ["FINISHED"] and bound["solve"] == ["FINISHED"]
    assert bound["summary"].startswith("binding nearest (automatic): 68 of 68 markers bound"), bound["summary"]
    err = np.asarray(bound["error_mm"])
    assert err.size == 68 and np.median(err) < 0.5 and err.max() < 1.5, (np.median(err), err.max())
    rmse = _rmse(_weights_vs_truth(bound, truth))
    print(f"\nBlender {workflow['bpy']}: bound by position, points {np.median(err):.3f} mm median from the "
          f"vertex groups; solve RMSE {rmse:.4f}")
    assert rmse < 0.04


def test_enabling_is_instant_and_lazy(workflow):
    """The installed extension enabled in fresh processes (as at start-up); median of several runs."""
    runs = workflow["enable"]
    assert all("error" not in r for r in runs), [r["error"] for r in runs if "error" in r]
    assert all(r["result"] == ["FINISHED"] and r["enabled"] for r in runs)
    assert all(r["heavy_after_enable"] == [] for r in runs)
    enable, eager, cpu, eager_cpu = (statistics.median(r[key] for r in runs) for key in (
        "enable_seconds", "eager_import_seconds", "enable_cpu_seconds", "eager_import_cpu_seconds"))
    print(f"\nBlender {workflow['bpy']}: enable {enable:.3f} s ({cpu:.3f} s CPU) median of {ENABLE_RUNS}; importing "
          f"scipy and OpenCV up front would add {eager:.3f} s ({eager_cpu:.3f} s CPU, {eager_cpu / cpu:.1f}x)")
    sys.stdout.flush()
