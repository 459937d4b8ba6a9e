"""The animator feedback loop in the sidebar (issue 7), through bpy.ops as an animator would use it.

Ground truth: the sample character performs a take; the character in the scene has 4 shapes
sculpted at 40% of the amplitude the markers show, so the geometric solve over-drives them. The
animator keys the true weights on 8 frames on the layer above the solve, adds the edited frames and
retunes.
"""

from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from scene_fixtures import LayoutStub, build_character

from facecap.facecap_addon.scene import anim, layers, tuning_scene
from facecap.solvers.character.basis import Basis
from facecap.solvers.tools.compare import SAMPLE_BASIS, STABLE
from facecap.solvers.io.csv import write_markers_csv
from facecap.solvers.tools.synthetic.synth import performance_weights, synthesize_take

WEAK = ("jawOpen", "mouthSmileLeft", "browInnerUp", "eyeBlinkLeft")
N_FRAMES = 480


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    out = tmp_path_factory.mktemp("tune")
    truth_basis = Basis.load_npz(SAMPLE_BASIS)
    deltas = truth_basis.deltas.copy()
    for name in WEAK:
        deltas[truth_basis.shape_names.index(name)] *= 0.4
    weak = Basis(truth_basis.shape_names, truth_basis.marker_names, truth_basis.neutral, deltas,
                 truth_basis.lower, truth_basis.upper)
    W = performance_weights(truth_basis.shape_names, N_FRAMES, seed=4)
    for name in WEAK:  # the weak shapes stay inside what the over-driven solve can still express
        W[:, truth_basis.shape_names.index(name)] *= 0.35
    synth = synthesize_take(truth_basis, W, stable=STABLE, units="mm", noise_sigma=0.0001, gap_fraction=0.0, seed=3)
    write_markers_csv(out / "take01.csv", synth.markers)
    return SimpleNamespace(dir=out, weak=weak, truth=W, frames=synth.markers.frames)


@pytest.fixture
def solved(empty_scene, data):
    obj = build_character(data.weak)
    assert bpy.ops.facecap.import_markers(filepath=str(data.dir / "take01.csv"), units="mm", fps=60.0) == {"FINISHED"}
    s = empty_scene.facecap
    s.target = obj
    s.strategy = "geometric"  # the character's own shapes are what the retune corrects (character_basis)
    s.neutral_first, s.neutral_last = int(data.frames[0]), int(data.frames[0]) + 50
    assert bpy.ops.facecap.refresh_shapes() == {"FINISHED"}
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    return SimpleNamespace(scene=empty_scene, s=s, obj=obj, key=obj.data.shape_keys, names=data.weak.shape_names)


def _solve_values(ctx):
    curves = [(layers.shape_path(n), 0) for n in ctx.names]
    return anim.read_curves(ctx.key, curves, action=layers.solved_action(ctx.key))[1]


def _correct(ctx, data, rows):
    """Key the whole true pose at ``rows`` on the layer above the solve, as the UI does (a key on one
    frame also shifts its neighbours, so an animator fixing a pose keys every shape of it)."""
    for t in rows:
        frame = int(data.frames[t])
        ctx.scene.frame_set(frame)
        for k, n in enumerate(ctx.names):
            block = ctx.key.key_blocks[n]
            block.value = float(data.truth[t, k])
            assert block.keyframe_insert("value", frame=frame)


def _worst_rows(data, solve, n=8, sep=20):
    err = np.abs(solve - data.truth).max(axis=1)
    rows = []
    for t in np.argsort(-err, kind="stable"):
        if all(abs(int(t) - r) >= sep for r in rows):
            rows.append(int(t))
        if len(rows) == n:
            return sorted(rows)


def _rmse(a):
    return float(np.sqrt(np.mean(np.asarray(a) ** 2)))


def test_retune_from_the_edited_frames(solved, data):
    ctx = solved
    before = _solve_values(ctx)
    rows = _worst_rows(data, before)
    _correct(ctx, data, rows)
    edits = ctx.key.animation_data.action
    edit_keys = [tuple(k.co) for fc in anim.action_fcurves(edits, ctx.key) for k in fc.keyframe_points]
    assert bpy.ops.facecap.tuning_add_edited() == {"FINISHED"}
    assert [t.frame for t in ctx.s.tuning_frames] == [int(data.frames[t]) for t in rows]
    assert all(t.change > 0.02 for t in ctx.s.tuning_frames)
    assert sorted(m.frame for m in ctx.scene.timeline_markers if m.name == "tune") == [int(data.frames[t]) for t in rows]

    assert bpy.ops.facecap.retune() == {"FINISHED"}
    s = ctx.s
    assert len(s.library_versions) == 1 and s.library_active == s.library_versions[0].name
    row = s.library_versions[0]
    assert row.kind == "character_basis" and row.corrected_after < row.corrected_before
    after = _solve_values(ctx)
    held = np.setdiff1d(np.arange(N_FRAMES), rows)
    corrected_before, corrected_after = _rmse(before[rows] - data.truth[rows]), _rmse(after[rows] - data.truth[rows])
    held_before, held_after = _rmse(before[held] - data.truth[held]), _rmse(after[held] - data.truth[held])
    print(f"\nretune in Blender: corrected {corrected_before:.4f} -> {corrected_after:.4f}, "
          f"held-out {held_before:.4f} -> {held_after:.4f}")
    assert corrected_after <= 0.05
    assert held_after <= 0.85 * held_before
    assert all(0 <= t.error <= 0.05 for t in s.tuning_frames)
    # The animator's action is untouched; the layer continues as a copy without the taken-in keys.
    assert [tuple(k.co) for fc in anim.action_fcurves(edits, ctx.key) for k in fc.keyframe_points] == edit_keys
    assert ctx.key.animation_data.action != edits and edits.use_fake_user
    assert layers.edit_key_frames(ctx.key, ctx.names).size == 0
    # The version round-trips from the .blend bit for bit.
    version = tuning_scene.load_version(ctx.scene, s.library_active)
    assert version.kind == "character_basis" and version.payload.deltas.shape == data.weak.deltas.shape


def test_undo_restores_the_state_before_the_retune(solved, data):
    ctx = solved
    rows = _worst_rows(data, _solve_values(ctx))
    _correct(ctx, data, rows)
    assert bpy.ops.facecap.tuning_add_edited() == {"FINISHED"}
    solve_name, edits_name = layers.solved_action(ctx.key).name, ctx.key.animation_data.action.name
    bpy.ops.ed.undo_push(message="before retune")
    assert bpy.ops.facecap.retune() == {"FINISHED"}
    bpy.ops.ed.undo_push(message="Retune")  # what the UI does after an UNDO operator (not in background calls)
    assert ctx.scene.facecap.library_active
    bpy.ops.ed.undo()
    s = bpy.context.scene.facecap
    key = s.target.data.shape_keys
    assert s.library_active == "" and len(s.library_versions) == 0
    assert layers.solved_action(key).name == solve_name and key.animation_data.action.name == edits_name
    assert len(s.tuning_frames) == len(rows)


def test_going_back_is_one_click(solved, data):
    ctx = solved
    original = _solve_values(ctx)
    _correct(ctx, data, _worst_rows(data, original))
    assert bpy.ops.facecap.tuning_add_edited() == {"FINISHED"}
    assert bpy.ops.facecap.retune() == {"FINISHED"}
    tuned = ctx.s.library_active
    assert bpy.ops.facecap.library_revert() == {"FINISHED"}
    assert ctx.s.library_active == ""
    np.testing.assert_allclose(_solve_values(ctx), original, atol=1e-6)
    assert bpy.ops.facecap.library_use(name=tuned) == {"FINISHED"}
    assert ctx.s.library_active == tuned and len(ctx.s.library_versions) == 1


def test_fit_gain_and_offset_from_the_corrections(solved, data):
    ctx = solved
    rows = _worst_rows(data, _solve_values(ctx))
    _correct(ctx, data, rows)
    assert bpy.ops.facecap.tuning_add_edited() == {"FINISHED"}
    before = _solve_values(ctx)
    assert bpy.ops.facecap.fit_gain_offset() == {"FINISHED"}
    shapes = {s.name: s for s in ctx.s.shapes}
    assert any(abs(shapes[n].gain - 1.0) > 0.1 for n in WEAK)
    after = _solve_values(ctx)
    assert _rmse(after[rows] - data.truth[rows]) < _rmse(before[rows] - data.truth[rows])


def test_controls_are_applied_and_saved_as_presets(solved, data, tmp_path):
    ctx = solved
    raw = _solve_values(ctx)
    k = ctx.names.index("jawOpen")
    shape = next(s for s in ctx.s.shapes if s.name == "jawOpen")
    shape.gain, shape.use_clamp, shape.clamp_max = 0.5, True, 0.3
    mute = next(s for s in ctx.s.shapes if s.name == "mouthSmileLeft")
    mute.mute = True
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    keyed = _solve_values(ctx)
    np.testing.assert_allclose(keyed[:, k], np.clip(0.5 * raw[:, k], 0.0, 0.3), atol=1e-6)
    assert np.all(keyed[:, ctx.names.index("mouthSmileLeft")] == 0)
    preset = tmp_path / "controls.json"
    assert bpy.ops.facecap.controls_save(filepath=str(preset)) == {"FINISHED"}
    shape.gain, shape.use_clamp, mute.mute = 1.0, False, False
    assert bpy.ops.facecap.controls_load(filepath=str(preset)) == {"FINISHED"}
    assert (shape.gain, shape.use_clamp, shape.clamp_max, mute.mute) == (0.5, True, pytest.approx(0.3), True)


def test_jump_to_the_next_worst_frame(solved):
    ctx = solved
    frames, residual = tuning_scene.residual_curve(ctx.key)
    ctx.scene.frame_set(int(frames[0]))
    assert bpy.ops.facecap.jump_worst() == {"FINISHED"}
    first = ctx.scene.frame_current
    assert first == int(frames[np.argmax(residual)])
    assert bpy.ops.facecap.jump_worst() == {"FINISHED"}
    second = ctx.scene.frame_current
    assert abs(second - first) > ctx.s.worst_spread
    r = dict(zip(frames.astype(int), residual))
    assert r[second] <= r[first]
    assert r[second] == max(v for f, v in r.items() if abs(f - first) > ctx.s.worst_spread)


def test_next_worst_frame_walks_the_peaks():
    frames = np.arange(1, 21, dtype=float)
    residual = np.zeros(20)
    residual[[4, 5, 12, 17]] = [5.0, 4.0, 3.0, 1.0]
    order = [tuning_scene.next_worst_frame(frames, residual, None, spread=2)]
    for _ in range(3):
        order.append(tuning_scene.next_worst_frame(frames, residual, order[-1], spread=2))
    assert order[:3] == [5.0, 13.0, 18.0]
    assert tuning_scene.next_worst_frame(frames, residual, 6.0, spread=2) == 5.0  # not a peak: the worst


def test_tune_panel_draws(solved):
    ctx = solved
    ctx.s.active_shape = 0
    layout = LayoutStub()
    bpy.types.FACECAP_PT_tune.draw(type("PanelStub", (), {"layout": layout})(), bpy.context)
    assert layout.calls



def test_the_cli_gives_the_same_retune_as_the_operator(solved, data, tmp_path):
    """``python -m facecap tune`` on the same take, character and corrections (written as the
    corrections CSV from the sidebar's tuning frames) stores the same library and the same weights."""
    import subprocess
    import sys

    from facecap.solvers.io.csv import read_weights_csv, write_weights_csv
    from facecap.solvers.tuning.store import load_version

    ctx = solved
    rows = _worst_rows(data, _solve_values(ctx))
    _correct(ctx, data, rows)
    assert bpy.ops.facecap.tuning_add_edited() == {"FINISHED"}
    corrections = tuning_scene.corrections(ctx.s)
    frames = sorted(corrections)
    write_weights_csv(tmp_path / "corrections.csv", frames, ctx.names,
                      np.array([[corrections[f][n] for n in ctx.names] for f in frames]))
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "character.blend"), copy=True)
    first, last = ctx.s.neutral_first, ctx.s.neutral_last
    (tmp_path / "take.toml").write_text(f"""
[target]
blend = "character.blend"
object = "Face"
[source]
markers = "{(data.dir / 'take01.csv').as_posix()}"
units = "mm"
fps = 60
[binding]
vertex_groups = true
[stabilise]
markers = {list(STABLE)!r}
[neutral]
frames = [{first}, {last}]
[solve]
strategy = "geometric"
[tuning]
corrections = "corrections.csv"
out = "library"
[output]
weights = "out/weights.csv"
""".replace("'", '"'))
    assert bpy.ops.facecap.retune() == {"FINISHED"}
    proc = subprocess.run([sys.executable, "-m", "facecap", "tune", "--config", str(tmp_path / "take.toml")],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    op_version = tuning_scene.load_version(ctx.scene, ctx.s.library_active)
    cli_version = load_version(tmp_path / "library" / f"{op_version.name}.npz") \
        if (tmp_path / "library" / f"{op_version.name}.npz").exists() else \
        next(load_version(p) for p in (tmp_path / "library").glob("*.npz") if "+tune" in p.name)
    assert cli_version.parent == op_version.parent
    np.testing.assert_allclose(cli_version.payload.deltas, op_version.payload.deltas, atol=1e-6)
    _, names, cli_weights = read_weights_csv(tmp_path / "out" / "weights.csv")
    assert tuple(names) == tuple(ctx.names)
    np.testing.assert_allclose(cli_weights, _solve_values(ctx), atol=1e-3)
    print(f"\noperator vs CLI: library max |diff| {np.abs(cli_version.payload.deltas - op_version.payload.deltas).max():.2e} m, "
          f"weights max |diff| {np.abs(cli_weights - _solve_values(ctx)).max():.2e}")


@pytest.mark.parametrize("operator", ["retune", "fit_gain_offset"])
def test_retune_and_fit_gain_run_beside_the_interface_and_esc_changes_nothing(solved, data, operator, monkeypatch):
    """From the sidebar both solve on a worker thread (the status bar says which and for how long); Esc leaves
    the library, the shape list, the solve layer and the animator's layer as they were; left to finish, the
    result is what bpy.ops gives."""
    import threading

    from scene_fixtures import modal_driver

    from facecap.facecap_addon.scene import scene_solve
    from facecap.operators import tuning

    ctx = solved
    _correct(ctx, data, _worst_rows(data, _solve_values(ctx)))
    assert bpy.ops.facecap.tuning_add_edited() == {"FINISHED"}
    cls = {"retune": tuning.FACECAP_OT_retune, "fit_gain_offset": tuning.FACECAP_OT_fit_gain_offset}[operator]
    Driver = modal_driver(cls)
    Driver.consume = True  # the operator property's default
    state = lambda: (len(ctx.s.library_versions), ctx.s.library_active, [(s.gain, s.offset) for s in ctx.s.shapes],  # noqa: E731
                     layers.solved_action(ctx.key).name, ctx.key.animation_data.action.name, _solve_values(ctx).tobytes())
    before = state()
    go = threading.Event()
    real_solve = scene_solve.solve
    tick, esc = SimpleNamespace(type="TIMER", value="NOTHING"), SimpleNamespace(type="ESC", value="PRESS")
    monkeypatch.setattr(scene_solve, "solve", lambda request: go.wait(60) and real_solve(request))
    driver = Driver(cls._start(Driver, bpy.context))  # _start reads only the context
    assert driver.modal(bpy.context, tick) == {"RUNNING_MODAL"}
    label = {"retune": "Retune", "fit_gain_offset": "Fit Gain and Offset"}[operator]
    assert driver._session.status().startswith(f"{label}: solving {N_FRAMES} frames")
    assert driver.modal(bpy.context, esc) == {"CANCELLED"}
    go.set()
    driver._session.thread.join()
    monkeypatch.setattr(scene_solve, "solve", real_solve)
    assert driver.reports[-1][0] == "WARNING" and f"{label} cancelled" in driver.reports[-1][1]
    assert state() == before
    driver = Driver(cls._start(Driver, bpy.context))
    driver._session.thread.join()
    assert driver.modal(bpy.context, tick) == {"FINISHED"}
    after = state()
    assert after[3] != before[3] and after[5] != before[5]  # a new solve layer with other values
    assert (after[0] == before[0] + 1) if operator == "retune" else (after[2] != before[2])
