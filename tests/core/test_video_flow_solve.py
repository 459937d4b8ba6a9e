"""Retargeting footage without markers (retarget_flow) and the take config of a video take."""

import numpy as np
import pytest

pytest.importorskip("cv2")

from facecap.solvers import FacecapError  # noqa: E402
from facecap.solvers.config import load_take_config  # noqa: E402
from facecap.solvers.errors import ConfigError  # noqa: E402
from facecap.solvers.pipeline import RetargetResult, RetargetSettings  # noqa: E402
from facecap.solvers.strategies.options import ExamplePairs  # noqa: E402
from facecap.solvers.video import Cancelled  # noqa: E402
from facecap.solvers.video.flow_solve import FlowSolveSettings, retarget_flow, retarget_flow_job  # noqa: E402
from facecap.solvers.video.synthetic import write_synthetic_clip  # noqa: E402

W, H, N, AMP = 240, 180, 100, 4.0
SHAPES = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "browDownLeft", "browDownRight", "cheekPuff")
REGION = (24, 18, 192, 144)
STABLE = ((48, 9, 144, 18),)  # a forehead band, far from every bump: moves with the head only
POSED = np.linspace(0, N - 1, 16).round().astype(int)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A synthetic face (six bumps = six shapes, weight = amplitude / AMP) with head motion, as an mp4 file."""
    return write_synthetic_clip(tmp_path_factory.mktemp("flowsolve") / "face.mp4", N, W, H, amplitude=AMP,
                                noise=1.0, seed=11, period=24.0)


def posed(clip, frames=POSED):
    return ExamplePairs(frames + 1.0, clip.motion.amplitudes[frames] / AMP, SHAPES)  # frame 1 = motion time 0


def unposed_rmse(result, clip, shapes=SHAPES):
    truth = clip.motion.amplitudes / AMP
    rest = np.setdiff1d(np.arange(N), POSED)
    cols = [result.shape_names.index(s) for s in shapes]
    return float(np.sqrt(np.mean((result.weights[rest][:, cols] - truth[rest]) ** 2)))


@pytest.mark.parametrize("strategy", ["linear", "rbf", "pca"])
def test_flow_features_retarget_the_footage(clip, strategy):
    flow = FlowSolveSettings(region=REGION, stable_region=STABLE, n_components=10)
    r = retarget_flow(clip.path, SHAPES, posed(clip), settings=RetargetSettings((), (1, 1), strategy=strategy),
                      flow=flow)
    assert isinstance(r, RetargetResult) and r.strategy == strategy and r.weights.shape == (N, 6)
    assert np.isnan(r.residual_rms).all() and r.residual_space is None  # no markers are fitted
    figures = r.info["flow"]
    assert figures["components"] == 10 and figures["frames"] == N and figures["example_frames"] == 16
    assert figures["stabilised"] and figures["stable_samples"] > 50 and 0.95 < figures["explained_variance"] <= 1
    assert r.source_weights.shape == (N, 10) and r.source_names[0] == "flow_pc1"
    rmse = unposed_rmse(r, clip)
    print(f"retarget_flow {strategy}: weights RMSE {rmse:.4f} on {N - POSED.size} unposed frames, "
          f"flow {figures['flow_frames_per_s']:.0f} frames/s at {W}x{H}")
    assert rmse <= 0.06


def test_bounds_locks_and_unposed_shapes(clip):
    character = (*SHAPES, "tongueOut")
    settings = RetargetSettings((), (1, 1), strategy="linear", bounds=(("jawOpen", 0.0, 0.5),),
                                locks=(("browDown*", 0.25),))
    r = retarget_flow(clip.path, character, posed(clip), settings=settings,
                      flow=FlowSolveSettings(region=REGION, stable_region=STABLE, variance=0.99))
    assert r.weights[:, 0].max() <= 0.5 + 1e-12
    np.testing.assert_allclose(r.weights[:, 3:5], 0.25)
    np.testing.assert_allclose(r.weights[:, 6], 0.0, atol=1e-12)
    assert any("tongueOut" in w for w in r.warnings)
    assert r.info["flow"]["components"] < 10  # the fewest components explaining 99 %


def test_examples_frames_choose_the_posed_frames_used(clip):
    from facecap.solvers.strategies.options import ExampleSettings

    flow = FlowSolveSettings(region=REGION, stable_region=STABLE, n_components=6, grid_step=8)
    some = RetargetSettings((), (1, 1), strategy="linear", examples=ExampleSettings(frames=(1.0, 21.0, 41.0, 60.0,
                                                                                             80.0, 100.0, 14.0, 34.0)))
    r = retarget_flow(clip.path, SHAPES, posed(clip), settings=some, flow=flow)
    assert r.info["flow"]["example_frames"] == 8
    with pytest.raises(FacecapError, match=r"frame\(s\) \[5.0\] have no posed weights"):
        retarget_flow_job(clip.path, SHAPES, posed(clip), flow=flow, settings=RetargetSettings(
            (), (1, 1), strategy="rbf", examples=ExampleSettings(frames=(5.0,))))


def test_cancelling_between_frames_produces_nothing(clip):
    job = retarget_flow_job(clip.path, SHAPES, posed(clip), flow=FlowSolveSettings(region=REGION, grid_step=8))
    assert job.step(5) is False and job.done == 5 and job.result is None
    job.cancel()
    with pytest.raises(Cancelled, match="cancelled at frame 5"):
        job.step()
    with pytest.raises(Cancelled, match=r"cancelled at frame 7 \(7 of 100 frames done\)"):
        retarget_flow(clip.path, SHAPES, posed(clip), flow=FlowSolveSettings(region=REGION, grid_step=8),
                      progress=lambda done, total: done < 7)


@pytest.mark.parametrize("flow,examples,message", [
    (dict(region=(200, 10, 100, 50)), None,
     r"`region` \[200, 10, 100, 50\] must be a non-empty box inside the 240x180"),
    (dict(stable_region=((-5, 0, 10, 10),)), None, "`stable_region`"),
    (dict(reference=500), None, "`reference` frame 500 is not in the footage"),
    ({}, ExamplePairs(np.array([3.0, 900.0]), np.zeros((2, 6)), SHAPES),
     r"posed frame\(s\) \[900.0\] are not in the footage \(1-100\)"),
    ({}, ExamplePairs(np.array([3.0, 9.0]), np.zeros((2, 6)), ("nope",) + SHAPES[1:]),
     r"name shape\(s\) the character does not have: \['nope'\]"),
])
def test_bad_input_fails_before_the_first_frame(clip, flow, examples, message):
    ex = posed(clip) if examples is None else examples
    with pytest.raises(FacecapError, match=message):
        retarget_flow_job(clip.path, SHAPES, ex, flow=FlowSolveSettings(**flow))
    with pytest.raises(FacecapError, match="flow features drive linear, rbf, pca; got strategy 'semantic'"):
        retarget_flow_job(clip.path, SHAPES, posed(clip), settings=RetargetSettings((), (1, 1)))


# -- the take config -------------------------------------------------------------------------------
def take(tmp_path, body):
    path = tmp_path / "take.toml"
    path.write_text('[target]\nobject = "Face"\n' + body)
    return path


VIDEO = '[source]\nvideo = "face.mp4"\n'
EXAMPLES = '[examples]\nweights = "posed.csv"\n'


def test_a_video_take_config(tmp_path):
    cfg = load_take_config(take(tmp_path, VIDEO + 'first = 2\nfps = 25\n[tracking]\nregion = [10, 20, 100, 80]\n'
                                'stable_region = [[0, 0, 20, 20], [100, 0, 20, 20]]\nreference = 4\n'
                                '[flow]\nvariance = 0.98\n' + EXAMPLES))
    v = cfg.video
    assert v.path == str(tmp_path / "face.mp4") and v.footage == {"first": 2, "fps": 25.0}
    assert v.flow.method == "dis" and v.flow.region == (10, 20, 100, 80) and v.flow.reference == 4
    assert v.flow.stable_region == ((0, 0, 20, 20), (100, 0, 20, 20)) and v.flow.variance == 0.98
    assert cfg.settings.strategy == "linear"  # the default for video takes
    assert cfg.markers_path is None and cfg.action_name == "face"
    assert cfg.examples_weights_path == tmp_path / "posed.csv"
    one = load_take_config(take(tmp_path, VIDEO + '[tracking]\nstable_region = [0, 0, 20, 20]\n[flow]\n'
                                'components = 5\n[solve]\nstrategy = "rbf"\n' + EXAMPLES))
    assert one.video.flow.stable_region == ((0, 0, 20, 20),) and one.video.flow.n_components == 5
    assert load_take_config(take(tmp_path, '[source]\nmarkers = "take.csv"\n[stabilise]\nmarkers = ["a", "b", "c"]\n'
                                 '[neutral]\nframes = [1, 2]\n')).video is None


@pytest.mark.parametrize("body,key,message", [
    (VIDEO + '[solve]\nstrategy = "rbf"\n', "examples.weights", "strategy 'rbf' needs \\[examples\\] weights"),
    (VIDEO + '[tracking]\nregion = [10, 20, 0, 80]\n' + EXAMPLES, "tracking.region", "expected \\[x, y, w, h\\]"),
    (VIDEO + '[tracking]\nmethod = "lk"\n' + EXAMPLES, "tracking.method", "dense flow"),
    (VIDEO + '[tracking]\nstable_region = [1, 2]\n' + EXAMPLES, "tracking.stable_region", "expected"),
    (VIDEO + '[tracking]\nwin_size = 21\n' + EXAMPLES, "tracking.win_size", "unknown key"),
    (VIDEO + '[flow]\ncomponents = 0\n' + EXAMPLES, "flow.components", ">= 1"),
    (VIDEO + '[flow]\ncomponents = 4\nvariance = 0.9\n' + EXAMPLES, "flow.variance", "not both"),
    (VIDEO + '[solve]\nstrategy = "geometric"\n' + EXAMPLES, "solve.strategy", "linear, rbf, pca"),
    (VIDEO + 'markers = "take.csv"\n' + EXAMPLES, "source.markers", "not both"),
    ('[source]\nmarkers = "take.csv"\n[tracking]\nregion = [1, 2, 3, 4]\n', "source.video", "missing"),
    (VIDEO + 'scale = 2\n' + EXAMPLES, "source.scale", "> 0 and <= 1; got 2"),
    (VIDEO + EXAMPLES + 'markers = "other.csv"\n', "examples.markers", "frames of the footage"),
])
def test_video_config_errors_name_the_key(tmp_path, body, key, message):
    with pytest.raises(ConfigError, match=message) as err:
        load_take_config(take(tmp_path, body))
    assert err.value.key == key and "\n" not in str(err.value)


def test_marker_sections_do_not_apply_to_video(tmp_path):
    with pytest.raises(ConfigError, match=r"\[stabilise\] does not apply to a \[source\] video take"):
        load_take_config(take(tmp_path, VIDEO + EXAMPLES + '[stabilise]\nmarkers = ["a", "b", "c"]\n'))
