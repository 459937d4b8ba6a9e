"""Every operator through bpy.ops.facecap.*, as a user would run them, on a scene built here."""

import sys
from pathlib import Path

import bpy
import numpy as np
import pytest

from scene_fixtures import LayoutStub, build_character, draw_panel, modal_driver, sub_panels

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
from synthetic_face import make_basis  # noqa: E402

from facecap.facecap_addon.scene import anim, layers  # noqa: E402
from facecap.solvers.io.csv import write_markers_csv  # noqa: E402
from facecap.solvers.tools.synthetic.synth import synthesize_take  # noqa: E402

N_FRAMES = 240


@pytest.fixture
def take(empty_scene, tmp_path):
    basis, stable = make_basis()
    rng = np.random.default_rng(7)
    weights = np.clip(rng.uniform(-0.4, 1.0, size=(N_FRAMES, basis.n_shapes)), 0, 1)
    weights[:60] = 0.0
    synth = synthesize_take(basis, weights, stable=stable, noise_sigma=0.0, gap_fraction=0.03, seed=5)
    path = tmp_path / "take01.csv"
    write_markers_csv(path, synth.markers)
    obj = build_character(basis)
    return {"path": path, "obj": obj, "weights": weights, "basis": basis, "stable": stable, "synth": synth}


def _import(take):
    assert bpy.ops.facecap.import_markers(filepath=str(take["path"]), units="mm", fps=60.0) == {"FINISHED"}


def _solved_values(obj, names):
    key = obj.data.shape_keys
    _, values = anim.read_curves(key, [(f'key_blocks["{n}"].value', 0) for n in names], action=layers.solved_action(key))
    return values


def test_import_markers_creates_keyed_empties(take):
    _import(take)
    s = bpy.context.scene.facecap
    assert s.take_name == "take01"
    assert s.marker_collection is not None
    assert len(s.marker_collection.objects) == take["basis"].n_markers
    assert sorted(m.name for m in s.markers if m.stable) == sorted(take["stable"])
    frames, values = anim.read_curves(bpy.data.objects["m3"], [("location", i) for i in range(3)])
    raw = take["synth"].markers.positions[:, take["basis"].marker_names.index("m3")] * 1e-3
    keyed = np.isin(take["synth"].markers.frames, frames)
    np.testing.assert_array_equal(keyed, ~np.isnan(raw[:, 0]))  # gaps stay gaps (no key), not zeros
    np.testing.assert_allclose(values, raw[keyed], atol=1e-6)


def test_import_bad_csv_reports_file_and_line(empty_scene, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,a_x,a_y,a_z\n1,0,0,0\n2,0,oops,0\n")
    with pytest.raises(RuntimeError, match=r"bad\.csv, line 3, field 'a_y'"):
        bpy.ops.facecap.import_markers(filepath=str(bad))


def test_set_neutral_validates_range(take):
    _import(take)
    assert bpy.ops.facecap.set_neutral(first=1, last=50) == {"FINISHED"}
    s = bpy.context.scene.facecap
    assert (s.neutral_first, s.neutral_last) == (1, 50)
    with pytest.raises(RuntimeError, match="outside the take"):
        bpy.ops.facecap.set_neutral(first=5000, last=5010)
    assert (s.neutral_first, s.neutral_last) == (1, 50)


def test_stabilise_keys_head_motion(take):
    _import(take)
    bpy.ops.facecap.set_neutral(first=1, last=50)
    assert bpy.ops.facecap.stabilise() == {"FINISHED"}
    head = bpy.context.scene.facecap.head_object
    assert head is not None
    frames, rot = anim.read_curves(head, [("rotation_euler", i) for i in range(3)])
    assert frames.size == N_FRAMES
    assert np.abs(rot[:50]).max() < 1e-6  # still during the neutral hold
    assert np.abs(rot).max() > np.radians(5)  # the synthetic head does move
    assert np.abs(np.diff(rot, axis=0)).max() < np.radians(5)  # unwrapped: no flips


def test_stabilise_needs_three_stable_markers(take):
    _import(take)
    for m in bpy.context.scene.facecap.markers:
        m.stable = False
    assert not bpy.ops.facecap.stabilise.poll()


def test_solve_keys_a_new_solve_layer_and_keeps_the_previous(take):
    _import(take)
    s = bpy.context.scene.facecap
    s.target = take["obj"]
    bpy.ops.facecap.set_neutral(first=1, last=50)
    s.regularisation = s.sparsity = s.symmetry = s.head_smoothing = s.smoothing_second = 0.0  # exact data, no priors
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    key = take["obj"].data.shape_keys
    first = layers.solved_action(key)
    assert first.name == "take01"
    assert key.animation_data.action is None, "the animator's layer stays theirs (empty here)"
    names = take["basis"].shape_names
    solved = _solved_values(take["obj"], names)
    assert solved.shape == (N_FRAMES, len(names))
    np.testing.assert_allclose(solved, take["weights"], atol=1e-4)  # float32 mesh, noise-free take

    # every curve of the first take (keyed weights, sampled diagnostics), read at a few frames
    probe = [5.0, 11.0, 30.0]
    before = [[fc.evaluate(f) for f in probe] for fc in anim.action_fcurves(first, key)]
    s.regularisation = 0.05
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    second = layers.solved_action(key)
    assert second != first and second.name == "take01.001"
    assert first.use_fake_user and len(layers.solve_track(key).strips) == 1
    assert first.name in bpy.data.actions
    after = [[fc.evaluate(f) for f in probe] for fc in anim.action_fcurves(first, key)]
    np.testing.assert_array_equal(after, before, err_msg="the first take's curves must be untouched")
    assert s.last_action == "take01.001"


def test_solve_without_character_is_greyed_out(take):
    _import(take)
    assert not bpy.ops.facecap.solve.poll()


@pytest.mark.parametrize("panel", ["FACECAP_PT_take", "FACECAP_PT_stabilise", "FACECAP_PT_solve"])
def test_panels_draw(take, panel):
    _import(take)
    cls = getattr(bpy.types, panel)
    assert cls.bl_category == "FaceCap" and cls.bl_space_type == "VIEW_3D"
    layout = LayoutStub()
    stub = type("PanelStub", (), {"layout": layout})()
    cls.draw(stub, bpy.context)
    assert layout.calls


@pytest.mark.parametrize("setting, value, listed", [
    ("binding_mode", "nearest", "binding_landmarks"),
    ("strategy", "geometric", "regions"),
    ("strategy", "calibrated", "calib_poses"),
    ("strategy", "parallel", "mapping"),
])
def test_every_editable_list_is_drawn_with_its_buttons(take, setting, value, listed):
    _import(take)
    s = bpy.context.scene.facecap
    setattr(s, setting, value)
    layout = LayoutStub()
    for panel in ("FACECAP_PT_take", "FACECAP_PT_solve"):
        draw_panel(panel, layout)
    assert ("template_list", listed) in layout.calls
    i = layout.calls.index(("template_list", listed))
    assert [kind for kind, _ in layout.calls[i + 1 : i + 3]] == ["operator", "operator"]  # add, remove


def test_shape_locks_bounds_regions_from_the_panel(take):
    _import(take)
    s = bpy.context.scene.facecap
    s.target = take["obj"]
    bpy.ops.facecap.set_neutral(first=1, last=50)
    assert bpy.ops.facecap.refresh_shapes() == {"FINISHED"}
    assert [x.name for x in s.shapes] == list(take["basis"].shape_names)
    s.shapes["shape3"].lock = True
    s.shapes["shape3"].lock_value = 0.4
    s.shapes["shape5"].upper = 0.2
    bpy.ops.facecap.region_add()
    s.regions[0].markers = "m1*, m2*"
    s.shapes["shape7"].region = s.regions[0].name
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    names = take["basis"].shape_names
    solved = _solved_values(take["obj"], names)
    assert np.all(solved[:, 3] == pytest.approx(0.4))
    assert solved[:, 5].max() <= 0.2 + 1e-6
    # The options survive a refresh.
    bpy.ops.facecap.refresh_shapes()
    assert s.shapes["shape3"].lock and s.shapes["shape7"].region == s.regions[0].name
    bpy.ops.facecap.region_remove()
    assert s.shapes["shape7"].region == ""


def test_diagnostic_curves_are_keyed_with_the_weights(take):
    _import(take)
    s = bpy.context.scene.facecap
    s.target = take["obj"]
    bpy.ops.facecap.set_neutral(first=1, last=50)
    bpy.ops.facecap.solve()
    key = take["obj"].data.shape_keys
    frames, values = anim.read_curves(key, [('["facecap_residual_mm"]', 0), ('["facecap_at_bound"]', 0)],
                                      action=layers.solved_action(key))
    assert frames.size == N_FRAMES
    assert np.all(values[:, 0] >= 0) and values[:, 0].max() > 0  # residual in mm, priors leave some
    assert np.all(values[:, 1] == np.round(values[:, 1]))
    # Per-marker error curves, grouped; per frame their RMS over the seen markers is the residual curve.
    names = take["basis"].marker_names
    curves = [(f'["facecap_error_mm_{n}"]', 0) for n in names]
    _, per_marker = anim.read_curves(key, curves, action=layers.solved_action(key))
    assert per_marker.shape == (N_FRAMES, len(names))
    seen = np.isfinite(per_marker)
    rms = np.sqrt(np.nansum(per_marker**2, axis=1) / seen.sum(axis=1))
    np.testing.assert_allclose(rms, values[:, 0], rtol=1e-4, atol=1e-5)
    groups = {fc.group.name for fc in anim.action_fcurves(layers.solved_action(key), key) if fc.group}
    assert {"FaceCap Weights", "FaceCap Diagnostics", "FaceCap Marker Error"} <= groups
    # weights are keys (the animator edits them), diagnostics are samples (one per frame, 9x smaller)
    for fc in anim.action_fcurves(layers.solved_action(key), key):
        diagnostic = fc.group.name != "FaceCap Weights"
        assert (len(fc.sampled_points) > 0) == diagnostic and (len(fc.keyframe_points) > 0) != diagnostic


@pytest.mark.parametrize(
    "ui_list, collection", [("FACECAP_UL_markers", "markers"), ("FACECAP_UL_shapes", "shapes"), ("FACECAP_UL_regions", "regions")]
)
def test_lists_draw_their_items(take, ui_list, collection):
    _import(take)
    s = bpy.context.scene.facecap
    s.target = take["obj"]
    bpy.ops.facecap.refresh_shapes()
    bpy.ops.facecap.region_add()
    item = getattr(s, collection)[0]
    layout = LayoutStub()
    getattr(bpy.types, ui_list).draw_item(None, bpy.context, layout, s, item, 0, s, "", 0)
    assert ("label", item.name) in layout.calls or ("prop", "name") in layout.calls


def _solve_driver():
    from facecap.operators.solve import FACECAP_OT_solve

    return modal_driver(FACECAP_OT_solve)


def test_solve_and_key_runs_modal_then_keys_or_esc_leaves_the_scene_as_it_was(take, monkeypatch):
    """*Solve and Key* in the sidebar: the solve runs beside the interface (timer ticks and other events pass
    while it works, the status bar says what), Esc drops it with nothing keyed; left to finish, it keys the
    solve layer as bpy.ops does."""
    import threading
    from types import SimpleNamespace

    from facecap.facecap_addon.scene import scene_solve

    _import(take)
    context, scene = bpy.context, bpy.context.scene
    s = scene.facecap
    s.target = take["obj"]
    bpy.ops.facecap.set_neutral(first=1, last=50)
    go = threading.Event()
    real_solve = scene_solve.solve
    monkeypatch.setattr(scene_solve, "solve", lambda request: go.wait(60) and real_solve(request))
    actions = set(bpy.data.actions.keys())
    tick, esc = SimpleNamespace(type="TIMER", value="NOTHING"), SimpleNamespace(type="ESC", value="PRESS")
    driver = _solve_driver()(scene_solve.SolveInBackground(s, scene))
    assert driver.modal(context, SimpleNamespace(type="MOUSEMOVE", value="NOTHING")) == {"PASS_THROUGH"}
    assert driver.modal(context, tick) == {"RUNNING_MODAL"}
    assert driver._session.status().startswith("Solve and Key: solving 240 frames from 60 markers x ")
    assert driver.modal(context, esc) == {"CANCELLED"}
    go.set()
    driver._session.thread.join()
    assert driver._session.cancelled and driver._session.result is not None  # solved on its thread, dropped
    assert driver.reports == [("WARNING", driver.reports[0][1])] and "nothing was keyed" in driver.reports[0][1]
    assert set(bpy.data.actions.keys()) == actions and layers.solved_action(take["obj"].data.shape_keys) is None

    driver = _solve_driver()(scene_solve.SolveInBackground(s, scene))
    driver._session.thread.join()
    assert driver.modal(context, tick) == {"FINISHED"}
    assert driver.reports[-1][0] == "INFO" and f"over {N_FRAMES} frames" in driver.reports[-1][1]
    assert layers.solved_action(take["obj"].data.shape_keys).name == "take01"


def test_stabilise_and_solve_show_their_options_in_sub_panels_that_apply(take):
    _import(take)
    s = bpy.context.scene.facecap
    assert [c.bl_label for c in sub_panels("FACECAP_PT_stabilise")] == ["Neutral", "Master T-Pose",
                                                                        "Head Fit and Alignment"]
    shown = {}
    for strategy in ("geometric", "parallel", "linear"):
        s.strategy = strategy
        shown[strategy] = [c.bl_label for c in sub_panels("FACECAP_PT_solve") if not hasattr(c, "poll")
                           or c.poll(bpy.context)]
    assert shown == {"geometric": ["Priors and Smoothing", "Shapes"],
                     "parallel": ["Strategy Inputs", "Shapes"], "linear": ["Strategy Inputs", "Shapes"]}
    for name in ("FACECAP_PT_stabilise", "FACECAP_PT_solve"):  # every branch of every sub-panel draws
        assert draw_panel(name).calls
