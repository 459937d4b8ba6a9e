"""Solve from Clip Flow: the character solved from a movie clip's dense flow and the frames an animator posed."""

from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from facecap.facecap_addon.scene import anim, layers
from facecap.solvers.video.synthetic import write_synthetic_clip

W, H, N, AMP = 240, 180, 90, 4.0
SHAPES = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "browDownLeft", "browDownRight", "cheekPuff")
POSED = np.linspace(0, N - 1, 15).round().astype(int)  # footage frames; the clip starts at scene frame 1
from scene_fixtures import modal_driver


@pytest.fixture(scope="module")
def footage(tmp_path_factory):
    return write_synthetic_clip(tmp_path_factory.mktemp("clipflow") / "face.avi", N, W, H, amplitude=AMP, noise=1.0,
                                seed=11, period=24.0)


@pytest.fixture
def scene(empty_scene, footage):
    """A character with the six shapes (and one nobody posed), the clip, and an Examples action of posed frames."""
    mesh = bpy.data.meshes.new("Face")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    obj = bpy.data.objects.new("Face", mesh)
    empty_scene.collection.objects.link(obj)
    obj.shape_key_add(name="Basis")
    for name in (*SHAPES, "tongueOut"):
        obj.shape_key_add(name=name, from_mix=False)
    key = mesh.shape_keys
    posed = anim.new_action_with_curves(key, name="posed", curves=[(f'key_blocks["{n}"].value', 0) for n in SHAPES],
                                        frames=POSED + 1.0, values=footage.motion.amplitudes[POSED] / AMP)
    clip = bpy.data.movieclips.load(footage.path)
    s = empty_scene.facecap
    s.target, s.examples_action, s.take_name = obj, posed, "face flow"
    v = s.video
    v.region, v.stable_region, v.flow_components = (24, 18, 192, 144), (48, 9, 144, 18), 10
    empty_scene.active_clip, empty_scene.frame_current = clip, 1  # the neutral reference
    return SimpleNamespace(scene=empty_scene, obj=obj, key=key, clip=clip, posed=posed,
                           truth=footage.motion.amplitudes / AMP)


def solved(scene):
    _, values = anim.read_curves(scene.key, [(f'key_blocks["{n}"].value', 0) for n in (*SHAPES, "tongueOut")],
                                 action=layers.solved_action(scene.key))
    return values


def unposed_rmse(values, truth):
    rest = np.setdiff1d(np.arange(N), POSED)
    return float(np.sqrt(np.mean((values[rest, :6] - truth[rest]) ** 2)))


def state(scene):
    key = scene.key
    return (set(bpy.data.actions.keys()), layers.solved_action(key), key.animation_data.action,
            len(key.animation_data.nla_tracks), scene.scene.facecap.last_action)


@pytest.mark.parametrize("strategy", ["linear", "rbf"])
def test_solve_from_clip_flow_keys_the_solve_layer(scene, strategy):
    scene.scene.facecap.video.flow_strategy = strategy
    assert bpy.ops.facecap.solve_clip_flow() == {"FINISHED"}
    action = layers.solved_action(scene.key)
    assert action is not None and action != scene.posed and scene.key.animation_data.action == scene.posed
    values = solved(scene)
    assert values.shape == (N, 7)
    rmse = unposed_rmse(values, scene.truth)
    print(f"Solve from Clip Flow ({strategy}): weights RMSE {rmse:.4f} on {N - POSED.size} unposed frames")
    assert rmse <= 0.06 and np.abs(values[:, 6]).max() <= 1e-6  # nobody posed tongueOut
    assert scene.scene.facecap.last_action == action.name


def test_missing_examples_or_character_is_one_readable_error(scene):
    scene.scene.facecap.examples_action = None
    with pytest.raises(RuntimeError, match="choose the Examples action in the Solve panel"):
        bpy.ops.facecap.solve_clip_flow()
    scene.scene.facecap.examples_action = scene.posed
    scene.scene.facecap.video.region = (200, 18, 100, 144)
    with pytest.raises(RuntimeError, match=r"`region` \[200, 18, 100, 144\] must be a non-empty box inside"):
        bpy.ops.facecap.solve_clip_flow()
    assert layers.solved_action(scene.key) is None


def _driver():
    from facecap.operators.video import FACECAP_OT_solve_clip_flow

    return modal_driver(FACECAP_OT_solve_clip_flow)


def test_esc_cancels_with_the_scene_untouched(scene, monkeypatch):
    from facecap.facecap_addon.scene.video_scene import ClipFlowSolving
    from facecap.operators import video as video_ops

    monkeypatch.setattr(video_ops, "STEP_SECONDS", 0.0)  # one frame per tick
    context = bpy.context
    before = state(scene)
    driver = _driver()(ClipFlowSolving(scene.scene, scene.clip, 1))
    tick, esc = SimpleNamespace(type="TIMER", value="NOTHING"), SimpleNamespace(type="ESC", value="PRESS")
    assert [driver.modal(context, tick) for _ in range(4)] == [{"RUNNING_MODAL"}] * 4
    assert driver.modal(context, SimpleNamespace(type="MOUSEMOVE", value="NOTHING")) == {"PASS_THROUGH"}
    assert driver._session.job.done == 4 and "frame 4 (4/90)" in driver._session.status()
    assert driver.modal(context, esc) == {"CANCELLED"}
    assert driver.reports == [("WARNING", "Solve from clip flow cancelled at frame 4; nothing was added to the scene")]
    assert state(scene) == before and layers.solved_action(scene.key) is None


def test_modal_ticks_to_the_end_and_keys_the_solve(scene, monkeypatch):
    from facecap.facecap_addon.scene.video_scene import ClipFlowSolving
    from facecap.operators import video as video_ops

    monkeypatch.setattr(video_ops, "STEP_SECONDS", 0.0)
    driver = _driver()(ClipFlowSolving(scene.scene, scene.clip, 1))
    tick = SimpleNamespace(type="TIMER", value="NOTHING")
    results = [driver.modal(bpy.context, tick) for _ in range(N + 1)]
    assert results[:N] == [{"RUNNING_MODAL"}] * N and results[N] == {"FINISHED"}
    kind, message = driver.reports[-1]
    assert kind == "INFO" and f"Solved 7 shapes over {N} frames of 'face.avi' from 10 flow components" in message
    assert unposed_rmse(solved(scene), scene.truth) <= 0.06
    # Background mode: INVOKE runs to completion too.
    assert bpy.ops.facecap.solve_clip_flow("INVOKE_DEFAULT") == {"FINISHED"}
