"""Face landmarks without a face: where the models are looked for, the temporal filter, the metric take, and
how a landmark take is configured (the detector itself on rendered footage: tests/blender/test_face_landmarks.py)."""

import numpy as np
import pytest

from facecap.solvers.errors import ConfigError, FacecapError
from facecap.solvers.markers import MarkerSet
from facecap.solvers.video.face_models import MODEL_FILES, LandmarkModelsMissing, find_models
from facecap.solvers.video.landmark_filter import smooth_landmarks
from facecap.solvers.video.landmarks import NAMES, RIGID, metric_take


def test_missing_models_are_one_message_naming_what_to_install(tmp_path, monkeypatch):
    monkeypatch.setenv("FACECAP_LANDMARK_MODELS", str(tmp_path / "nowhere"))
    monkeypatch.setenv("FACECAP_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr("facecap.solvers.video.face_models.BUNDLED", tmp_path / "bundled")
    monkeypatch.setattr("facecap.solvers.video.face_models._mediapipe_dirs", lambda: [])
    with pytest.raises(LandmarkModelsMissing) as err:
        find_models()
    message = str(err.value)
    assert "python -m facecap landmark-models" in message and "extension zip" in message
    assert "face_landmark.tflite" in message and "\n" not in message


def test_a_models_folder_missing_a_file_names_the_file(tmp_path):
    (tmp_path / MODEL_FILES["detector"]).write_bytes(b"x")
    with pytest.raises(FacecapError, match="no face_landmark.tflite, iris_landmark.tflite in this folder"):
        find_models(tmp_path)


def test_models_found_in_an_explicit_folder(tmp_path):
    for name in MODEL_FILES.values():
        (tmp_path / name).write_bytes(b"x")
    assert find_models(tmp_path)["mesh"] == tmp_path / MODEL_FILES["mesh"]


def _jitter_and_lips(noise, seed=0, fps=30.0):
    """A still point and a lip closing at 3 Hz (10 px), both with detector noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(600) / fps
    truth = np.zeros((len(t), 2, 2))
    truth[:, 1, 1] = 10 * np.maximum(0, np.sin(2 * np.pi * 3 * t)) ** 2
    return truth, truth + rng.normal(0, noise, truth.shape)


@pytest.mark.parametrize("noise", [0.3, 0.8])
def test_the_filter_removes_jitter_without_flattening_fast_lips(noise):
    truth, noisy = _jitter_and_lips(noise)
    out = smooth_landmarks(noisy, 30.0)
    jitter = np.std(out[:, 0] - truth[:, 0])
    assert jitter <= 0.6 * noise  # measured 0.56 x the raw jitter at both noise levels
    lips = np.sqrt(np.mean((out[:, 1] - truth[:, 1]) ** 2))
    assert lips <= 0.85 * noise  # closer to the true motion than the raw detections (measured 0.81 / 0.78 x)
    peaks = np.flatnonzero(truth[:, 1, 1] > 0.99 * truth[:, 1, 1].max())
    print(f"noise {noise}: jitter {jitter / noise:.2f} x, lips {lips / noise:.2f} x, peaks "
          f"{np.mean(out[peaks, 1, 1]):.2f} of {np.mean(truth[peaks, 1, 1]):.2f} px")
    assert np.mean(out[peaks, 1, 1]) >= np.mean(truth[peaks, 1, 1]) - 0.5  # the peaks are kept


def test_frames_without_a_face_stay_gaps_and_split_the_filter():
    truth, noisy = _jitter_and_lips(0.3)
    noisy[100:110] = np.nan
    noisy[110:] += 50.0  # the face came back elsewhere
    out = smooth_landmarks(noisy, 30.0)
    assert np.isnan(out[100:110]).all() and np.isfinite(out[:100]).all() and np.isfinite(out[110:]).all()
    assert abs(out[99, 0, 0]) < 2.0 and abs(out[110, 0, 0] - 50.0) < 2.0  # nothing smoothed across the gap


def test_metric_take_is_in_the_characters_axes_and_an_adult_size():
    rng = np.random.default_rng(1)
    F = 20
    base = rng.normal(0, 40, size=(len(NAMES), 3)) + [320.0, 240.0, 0.0]
    base[33], base[263] = [280.0, 220.0, 0.0], [360.0, 220.0, 0.0]  # eye corners 80 px apart
    base[1] = [320.0, 270.0, -40.0]  # the nose tip, nearer the camera (z < 0)
    zoom = np.linspace(1.0, 1.3, F)  # the face comes closer
    centre = np.array([320.0, 240.0, 0.0])
    px = (base[None] - centre) * zoom[:, None, None] + centre
    m = metric_take(MarkerSet(NAMES, np.arange(1.0, F + 1), px, fps=30.0, units="px"))
    assert m.units == "m"
    eyes = np.linalg.norm(m.positions[:, 33] - m.positions[:, 263], axis=1)
    np.testing.assert_allclose(eyes, 0.09, rtol=1e-9)  # every frame: distance to the camera taken out
    assert (m.positions[:, 1, 1] < m.positions[:, 33, 1]).all()  # the nose is in front: the face looks down -Y
    assert (m.positions[:, 1, 2] < m.positions[:, 33, 2]).all()  # and below the eyes: Z up
    assert m.positions[0, 263, 0] > m.positions[0, 33, 0]  # image right is +X


def test_rigid_landmarks_are_named_landmarks():
    assert len(RIGID) >= 10 and set(RIGID) <= set(NAMES)


# -- configs ---------------------------------------------------------------------------------------------
FOUR = ('[target]\nblend = "c.blend"\nobject = "Face"\n[source]\nvideo = "clip.mp4"\n'
        '[tracking]\nmethod = "landmarks"\n[output]\nweights = "w.csv"\n')


def test_four_sections_make_a_semantic_take_with_landmark_defaults(tmp_path):
    from facecap.solvers.config import load_take_config
    from facecap.solvers.video.flow_config import LandmarkTake

    path = tmp_path / "take.toml"
    path.write_text(FOUR, encoding="utf-8")
    config = load_take_config(path)
    assert isinstance(config.video, LandmarkTake) and config.video.smoothing and config.video.iris
    assert config.video.path == str(tmp_path / "clip.mp4")
    s = config.settings
    assert s.strategy == "semantic" and s.stable_markers == RIGID and s.neutral_detect
    assert config.binding.mode == "nearest"
    assert s.actor.template == "none"  # the detector's points are not the template's skin (docs/video.md)


def test_a_landmark_take_keeps_what_the_config_says(tmp_path):
    from facecap.solvers.config import load_take_config

    path = tmp_path / "take.toml"
    path.write_text(FOUR + '[neutral]\nframes = [1, 15]\n[stabilise]\nmarkers = ["lm010", "lm168", "lm234"]\n'
                    '[actor]\ntemplate = "auto"\n', encoding="utf-8")
    s = load_take_config(path).settings
    assert s.neutral_frames == (1, 15) and not s.neutral_detect and s.stable_markers == ("lm010", "lm168", "lm234")
    assert s.actor.template == "auto"


def test_a_landmark_take_names_its_bundle_and_what_to_do_with_the_scores(tmp_path):
    """By default the installed Face Landmarker and its scores fused; a bundle path is relative to the config."""
    from facecap.solvers.config import load_take_config

    path = tmp_path / "take.toml"
    path.write_text(FOUR, encoding="utf-8")
    video = load_take_config(path).video
    assert (video.bundle, video.blendshapes) == ("auto", "fuse")
    path.write_text(FOUR.replace('method = "landmarks"', 'method = "landmarks"\nbundle = "m/fl.task"\n'
                                 'blendshapes = "ignore"'), encoding="utf-8")
    video = load_take_config(path).video
    assert (video.bundle, video.blendshapes) == (str(tmp_path / "m" / "fl.task"), "ignore")


@pytest.mark.parametrize("extra, key, match", [
    ('[flow]\ncomponents = 4\n', None, r"\[flow\] does not apply to a landmark take"),
    ('[solve]\nstrategy = "linear"\n', "solve.strategy", "a landmark take solves with geometric"),
])
def test_landmark_take_errors_name_the_key(tmp_path, extra, key, match):
    from facecap.solvers.config import load_take_config

    path = tmp_path / "take.toml"
    path.write_text(FOUR + extra, encoding="utf-8")
    with pytest.raises(ConfigError, match=match) as err:
        load_take_config(path)
    assert key is None or err.value.key == key


def test_track_config_for_landmarks_needs_no_seeds_and_refuses_them(tmp_path):
    from facecap.solvers.video.cli import load_track_config

    path = tmp_path / "track.toml"
    path.write_text('[source]\nvideo = "clip.mp4"\n[tracking]\nmethod = "landmarks"\nsmoothing = false\n'
                    '[output]\nmarkers = "lm.csv"\n', encoding="utf-8")
    settings = load_track_config(path)
    assert settings["method"] == "landmarks" and settings["options"] == {"smoothing": False}
    path.write_text('[source]\nvideo = "clip.mp4"\n[tracking]\nmethod = "landmarks"\nregion = [0, 0, 10, 10]\n'
                    '[output]\nmarkers = "lm.csv"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match="finds the face itself"):
        load_track_config(path)
    path.write_text('[source]\nvideo = "clip.mp4"\n[tracking]\nmethod = "landmarks"\nwin_size = 21\n'
                    '[output]\nmarkers = "lm.csv"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=r"\['win_size'\] do not apply"):
        load_track_config(path)


def test_gaze_weights_follow_the_irises_as_arkit_sets_them():
    from facecap.solvers.video.gaze import EYEBALL, gaze_weights

    F = 30
    p = np.zeros((F, len(NAMES), 3))
    p[:, 33, :2], p[:, 133, :2] = [100.0, 100.0], [130.0, 100.0]  # the subject's right eye (image left)
    p[:, 362, :2], p[:, 263, :2] = [170.0, 100.0], [200.0, 100.0]
    p[:, 468, :2], p[:, 473, :2] = [115.0, 100.0], [185.0, 100.0]
    p[:, 159, :2], p[:, 145, :2] = [115.0, 95.0], [115.0, 105.0]  # open lids
    p[:, 386, :2], p[:, 374, :2] = [185.0, 95.0], [185.0, 105.0]
    look = np.arange(F) >= 20  # the last 10 frames look 20 degrees to the subject's left (image right)
    shift = 30.0 * EYEBALL * np.sin(np.radians(20.0))
    p[look, 468, 0] += shift
    p[look, 473, 0] += shift
    w = gaze_weights(p)
    np.testing.assert_allclose(w["eyeLookOutLeft"][look], 20 / 35, atol=1e-9)  # the left eye looks out
    np.testing.assert_allclose(w["eyeLookInRight"][look], 20 / 35, atol=1e-9)  # the right eye looks in
    for name in ("eyeLookInLeft", "eyeLookOutRight", "eyeLookUpLeft", "eyeLookDownRight"):
        assert np.all(w[name] == 0), name
    assert np.all(w["eyeLookOutLeft"][~look] == 0)
    p[25, 386, 1] = p[25, 374, 1] = 100.0  # a blink: the iris model's guess behind the lid is not used
    p[25, 473, 0] -= 8.0
    assert gaze_weights(p)["eyeLookOutLeft"][25] == pytest.approx(20 / 35)


def _eyes(F):
    """Landmark pixels (F, 478, 3) of two open eyes 30 px wide, irises centred, lids 10 px apart."""
    p = np.zeros((F, len(NAMES), 3))
    p[:, 33, :2], p[:, 133, :2] = [100.0, 100.0], [130.0, 100.0]
    p[:, 362, :2], p[:, 263, :2] = [170.0, 100.0], [200.0, 100.0]
    p[:, 468, :2], p[:, 473, :2] = [115.0, 100.0], [185.0, 100.0]
    p[:, 159, :2], p[:, 145, :2] = [115.0, 95.0], [115.0, 105.0]
    p[:, 386, :2], p[:, 374, :2] = [185.0, 95.0], [185.0, 105.0]
    return p


def test_gaze_is_measured_from_the_neutral_frames_not_the_median_one():
    """A take that looks aside most of the time: the median frame looks aside, the neutral looks ahead."""
    from facecap.solvers.video.gaze import EYEBALL, gaze_weights

    F = 30
    p = _eyes(F)
    shift = 30.0 * EYEBALL * np.sin(np.radians(20.0))
    p[10:, 468, 0] += shift  # 20 of 30 frames look 20 degrees to the subject's left
    p[10:, 473, 0] += shift
    by_median = gaze_weights(p)
    assert np.all(by_median["eyeLookOutLeft"][10:] == 0)  # the look is taken for straight ahead
    w = gaze_weights(p, np.arange(0, 8))
    np.testing.assert_allclose(w["eyeLookOutLeft"][10:], 20 / 35, atol=1e-9)
    np.testing.assert_allclose(w["eyeLookInRight"][10:], 20 / 35, atol=1e-9)
    assert np.all(w["eyeLookOutLeft"][:10] == 0)


def test_lid_weights_are_the_lids_closure_from_the_neutral_gap():
    from facecap.solvers.video.gaze import WIDE, gaze_locks, lid_weights

    F = 12
    p = _eyes(F)
    p[5, 159, 1], p[5, 145, 1] = 97.0, 103.0  # the right eye closed by 0.4 of its gap: a look down, as it is
    p[6, 386, 1], p[6, 374, 1] = 98.0, 102.0  # the left to 0.4 of it: the detector's closed eye
    p[7, 386, 1], p[7, 374, 1] = 97.5, 102.5  # half way between
    p[8, 386, 1], p[8, 374, 1] = 95.0 - 5.0 * WIDE, 105.0 + 5.0 * WIDE  # the left wide open
    p[10] = np.nan  # no face: no blink
    w = lid_weights(p, np.arange(0, 4))
    assert w["eyeBlinkRight"][5] == pytest.approx(0.4) and w["eyeBlinkLeft"][6] == pytest.approx(1.0)
    assert w["eyeBlinkLeft"][7] == pytest.approx(0.7)
    assert w["eyeWideLeft"][8] == pytest.approx(1.0) and w["eyeBlinkLeft"][8] == 0
    assert w["eyeBlinkRight"][[0, 1, 2, 3, 4, 6, 7, 8, 9, 10]].max() == 0 and w["eyeWideRight"].max() == 0
    locks = dict(gaze_locks(["eye_blink_L", "eyeBlinkRight", "jawOpen", "eyeLookUpLeft"], p, np.arange(0, 4)))
    assert set(locks) == {"eye_blink_L", "eyeBlinkRight", "eyeLookUpLeft"}  # matched by name or alias
    np.testing.assert_allclose(locks["eye_blink_L"], w["eyeBlinkLeft"])
    np.testing.assert_allclose(locks["eyeBlinkRight"], w["eyeBlinkRight"])
