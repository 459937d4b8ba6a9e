"""The performer's ROM on camera (solvers/video/response.py): the blendshape scores' response per shape, fitted
from a ROM clip's scores, stored in the performer profile and applied to later landmark takes."""

from types import SimpleNamespace

import numpy as np
import pytest

from facecap.solvers.errors import ConfigError, FacecapError, InputFileError
from facecap.solvers.rom import ARKIT_51, sequence_poses
from facecap.solvers.tools.synthetic.realism.rom import rom_weights
from facecap.solvers.video.fusion import FaceScores, FusionTable, fuse, neutral_corrected
from facecap.solvers.video.response import (
    GAIN_RANGE,
    ScoreResponse,
    fit_response,
    fit_weights_response,
    profile_contents,
    relative,
    save_profile,
)

FPS = 30.0
POSES = sequence_poses("facecap-24")


def camera(seed):
    """A performer and camera whose blendshape head reads ``r * w + rest`` (+ noise) for each shape's weight w:
    responses 0.4-0.9 (no score saturates), resting levels 0-0.15."""
    rng = np.random.default_rng(seed)
    return rng.uniform(0.4, 0.9, len(ARKIT_51)), rng.uniform(0.0, 0.15, len(ARKIT_51))


def scores_of(weights, response, rest, rng):
    return np.clip(response * weights + rest + rng.normal(0.0, 0.01, weights.shape), 0.0, 1.0)


def rom_clip(seed, *, skip=(), extra=0):
    """(scores, neutral frame indices, weights, poses performed) of an imperfect ROM session (``realism.rom``:
    80-100 % of each asked shape, neighbours leaking in, wobbling holds) seen through ``camera(seed)``."""
    rng = np.random.default_rng(seed + 1000)
    weights, performed, _, _ = rom_weights(ARKIT_51, POSES, rng, fps=FPS, skip=skip, extra=extra)
    r, rest = camera(seed)
    return scores_of(weights, r, rest, rng), np.flatnonzero(~weights.any(axis=1)), weights, performed


def test_the_response_recovers_each_shapes_gain_from_an_imperfect_rom():
    """Every shape a found pose asks at full gets the gain that undoes the camera's (1 - rest) / r, within what the
    performer's 80-100 % allows (a pose held at 0.9 of the asked 1 reads 1/0.9 too high), and a separate clip
    of the same performer and camera (another session) comes out closer to its weights."""
    scores, neutral, _, _ = rom_clip(3)
    fit = fit_response(scores, ARKIT_51, neutral, POSES, fps=FPS)
    assert fit.summary.startswith("24 of 24 poses found")
    r, rest = camera(3)
    expect = (1.0 - rest) / r
    full = [k for k, n in enumerate(ARKIT_51) if any(p.weight_of(n) == 1.0 for p in POSES)]
    ratio = fit.response.gain[full] / expect[full]
    assert np.all((ratio > 0.85) & (ratio < 1.3)), dict(zip(np.array(ARKIT_51)[full], ratio.round(2)))
    assert 1.0 < np.median(ratio) < 1.15
    np.testing.assert_allclose(fit.response.offset, 0.0, atol=0.05)
    # a separate clip: another session seen through the same camera
    rng = np.random.default_rng(77)
    weights, *_ = rom_weights(ARKIT_51, POSES, rng, fps=FPS)
    other = neutral_corrected(scores_of(weights, r, rest, rng), np.flatnonzero(~weights.any(axis=1)))
    before = np.sqrt(np.mean((other - weights) ** 2))
    after = np.sqrt(np.mean((fit.response(other, ARKIT_51) - weights) ** 2))
    assert after < 0.6 * before, (before, after)


def test_another_reading_of_the_rom_is_calibrated_at_the_poses_its_scores_found():
    """``fit_weights_response``: another reading of the same ROM clip (a solve that reads every shape at 0.5 of its
    weight) measured at the frames the scores' fit found each pose: gains near 2 for the shapes the sheet asks at
    full, the identity for names kept (the lids' locks) and for shapes no pose asks; no pose found is refused."""
    scores, neutral, weights, _ = rom_clip(3)
    fit = fit_response(scores, ARKIT_51, neutral, POSES, fps=FPS)
    rng = np.random.default_rng(5)
    reading = 0.5 * weights + rng.normal(0.0, 0.01, weights.shape)
    keep = ("eyeBlinkLeft", "eyeBlinkRight")
    got = fit_weights_response(reading, ARKIT_51, neutral, fit.frames, POSES, sheet="facecap-24", keep=keep)
    full = [k for k, n in enumerate(ARKIT_51) if any(p.weight_of(n) == 1.0 for p in POSES) and n not in keep]
    assert np.all((got.gain[full] > 1.6) & (got.gain[full] < 2.4)), dict(zip(np.array(ARKIT_51)[full],
                                                                              got.gain[full].round(2)))
    assert 1.8 < np.median(got.gain[full]) < 2.3
    for name in keep + tuple(n for n in ARKIT_51 if not any(p.weight_of(n) > 0 for p in POSES)):
        assert name not in got.changed()
    assert got.sheet == "facecap-24"
    with pytest.raises(FacecapError, match="no pose of the ROM clip was found"):
        fit_weights_response(reading, ARKIT_51, neutral, [None] * len(POSES), POSES)


def test_a_skipped_pose_is_named_and_the_others_keep_their_holds():
    """The performer skips "eyes shut": the alignment names it instead of shifting the next poses onto the wrong
    holds; its shapes (asked by no other pose) keep their scores."""
    scores, neutral, weights, performed = rom_clip(5, skip=(5,))
    fit = fit_response(scores, ARKIT_51, neutral, POSES, fps=FPS)
    assert fit.frames[5] is None
    assert any("not found" in n and "'eyes shut'" in n for n in fit.notes)
    for j, span in enumerate(fit.frames):  # each pose found is measured where its asked shapes are held
        if span is None:
            continue
        asked = [ARKIT_51.index(s) for s, _ in POSES[j].weights]
        held = weights[span[0]:span[1] + 1][:, asked]
        assert np.all(held > 0.5 * np.array([w for _, w in POSES[j].weights])), POSES[j].label
    blink = ARKIT_51.index("eyeBlinkLeft")
    assert (fit.response.gain[blink], fit.response.offset[blink]) == (1.0, 0.0)


def test_poses_placed_by_the_user_are_measured_there_and_nowhere_else():
    """Holds given ({label: frame index}, what [calibration] holds and the dragged ``ROM: `` markers give): only
    those poses are measured, around the hold found at each middle; a marker dragged onto another pose's hold
    measures that hold (the user is followed, not second-guessed)."""
    scores, neutral, _, _ = rom_clip(3)
    found = fit_response(scores, ARKIT_51, neutral, POSES, fps=FPS)
    middle = {p.label: 0.5 * (f[0] + f[1]) for p, f in zip(POSES, found.frames)}
    given = {label: middle[label] for label in ("jaw open", "smile", "eyes shut")}
    placed = fit_response(scores, ARKIT_51, neutral, POSES, fps=FPS, given=given)
    assert placed.summary.startswith("3 of 24 poses where they were placed")
    assert [p.label for p, f in zip(POSES, placed.frames) if f is not None] == ["jaw open", "smile", "eyes shut"]
    for label in given:
        j = [p.label for p in POSES].index(label)
        assert abs(0.5 * sum(placed.frames[j]) - middle[label]) <= 1.0
    jaw = ARKIT_51.index("jawOpen")
    assert placed.response.gain[jaw] == pytest.approx(found.response.gain[jaw], rel=0.1)
    assert "browInnerUp" not in placed.response.changed()  # no placed pose asks it
    # "smile" dragged onto the jaw's hold: what is measured there is the jaw's, so the smile's score reads nothing
    wrong = fit_response(scores, ARKIT_51, neutral, POSES, fps=FPS, given={"smile": middle["jaw open"]})
    assert "mouthSmileLeft" not in wrong.response.changed() and any("kept as scored" in n for n in wrong.notes)


def test_an_extra_expression_is_named_and_left_out():
    scores, neutral, _, performed = rom_clip(8, extra=1)
    assert -1 in performed
    fit = fit_response(scores, ARKIT_51, neutral, POSES, fps=FPS)
    assert any("match no pose of the sheet" in n for n in fit.notes)
    assert fit.summary.startswith("24 of 24 poses found (25 holds")


def test_holds_that_could_be_read_two_ways_are_left_out_and_named():
    """The camera does not see a puff or the jaw's sideways and forward motion, and reads a sideways jaw as the
    mouth pulled left (as the 30 degree renders do): two like holds for four poses the scores cannot tell apart.
    They are left out of the fit and named, never guessed; the other poses are found; a clip that is mostly such
    stretches is refused."""
    r, rest = camera(0)
    for name in ("cheekPuff", "jawLeft", "jawRight", "jawForward"):
        r[ARKIT_51.index(name)] = 0.0

    def session(poses, seed):
        rng = np.random.default_rng(seed)
        weights, _, _, _ = rom_weights(ARKIT_51, poses, rng, fps=FPS)
        seen = weights.copy()
        seen[:, ARKIT_51.index("mouthLeft")] += 0.9 * (weights[:, ARKIT_51.index("jawLeft")]
                                                       + weights[:, ARKIT_51.index("jawRight")])
        return scores_of(seen, r, rest, rng), np.flatnonzero(~weights.any(axis=1))

    scores, neutral = session(POSES, 1000)
    fit = fit_response(scores, ARKIT_51, neutral, POSES, fps=FPS)
    assert any("could be read more than one way" in n and "'jaw left', 'jaw right'" in n for n in fit.notes)
    labels = [p.label for p in POSES]
    assert all(fit.frames[labels.index(p)] is None for p in ("puff", "jaw left", "jaw right", "jaw forward"))
    assert fit.frames[labels.index("mouth left")] is not None
    assert fit.summary.startswith("20 of 24 poses found")
    with pytest.raises(FacecapError, match="do not follow the sheet clearly around pose"):
        fit_response(*session(POSES[13:18], 1001)[:1], ARKIT_51, session(POSES[13:18], 1001)[1], POSES[13:18],
                     fps=FPS)


def test_a_score_that_never_responds_and_a_score_never_asked_stay_as_scored():
    """A score dead on this camera (0 whatever the face does) is not amplified into noise; a score the sheet never
    asks (tongueOut) has nothing to be calibrated by; gains stay within GAIN_RANGE."""
    scores, neutral, _, _ = rom_clip(3)
    names = ARKIT_51 + ("tongueOut",)
    dead = ARKIT_51.index("eyeWideLeft")  # "surprise" still shows in the brows
    scores[:, dead] = 0.02 + np.random.default_rng(1).normal(0, 0.005, len(scores))
    scores = np.concatenate([scores, np.full((len(scores), 1), 0.1)], axis=1)
    fit = fit_response(scores, names, neutral, POSES, fps=FPS)
    r = fit.response
    assert (r.gain[dead], r.offset[dead]) == (1.0, 0.0) and "eyeWideLeft" not in r.changed()
    assert any("kept as scored" in n and "eyeWideLeft" in n for n in fit.notes)
    assert "eyeWideRight" in r.changed()
    assert "tongueOut" not in r.changed()
    assert np.all((r.gain >= GAIN_RANGE[0]) & (r.gain <= GAIN_RANGE[1]))


def test_a_rom_clip_without_poses_or_neutral_is_refused():
    scores, neutral, _, _ = rom_clip(3)
    with pytest.raises(FacecapError, match="neutral frames"):
        fit_response(scores, ARKIT_51, [], POSES, fps=FPS)
    with pytest.raises(FacecapError, match="no pose of the sheet was found"):
        fit_response(np.full_like(scores, 0.1), ARKIT_51, neutral, POSES, fps=FPS)
    with pytest.raises(FacecapError, match=r"`scores` must have shape"):
        fit_response(scores[:, :5], ARKIT_51, neutral, POSES, fps=FPS)


def test_the_relative_response_reads_a_performer_as_the_reference_faces():
    """reference^-1 o own: a performer whose scores read half of the reference faces' gets gain 2 against them;
    the identity where either left a score as scored."""
    names = ("jawOpen", "mouthSmileLeft", "browInnerUp")
    ref = ScoreResponse(names, [1.5, 1.0, 1.2], [0.0, 0.0, 0.01])
    own = ScoreResponse(names, [3.0, 1.4, 1.0], [0.02, 0.0, 0.0])
    rel = relative(own, ref)
    np.testing.assert_allclose(rel.gain, [2.0, 1.0, 1.0])  # smile: the reference's identity; brows: own's
    np.testing.assert_allclose(rel.offset, [0.02 / 1.5, 0.0, 0.0])
    c = np.array([[0.1, 0.5, 0.3], [0.4, 0.2, np.nan]])
    np.testing.assert_allclose(ref(rel(c, names), names)[:, 0], own(c, names)[:, 0])
    assert np.isnan(rel(c, names)[1, 2])  # no face stays no face


def test_the_response_is_what_fuse_applies_and_the_table_keeps_its_reference(tmp_path):
    names = ("jawOpen", "browInnerUp")
    response = ScoreResponse(names, [2.0, 1.0], [0.0, 0.0], "facecap-24")
    table = FusionTable({"jawOpen": 1.0, "browInnerUp": 1.0}, {"jawOpen": 0.0, "browInnerUp": 0.0},
                        reference=response)
    table.save(tmp_path / "t.json")
    back = FusionTable.load(tmp_path / "t.json")
    assert back.reference.names == names and back.reference.sheet == "facecap-24"
    np.testing.assert_allclose(back.reference.gain, [2.0, 1.0])
    s = np.array([[0.0, 0.0], [0.2, 0.3], [0.3, 0.3]])
    w, _ = fuse(np.zeros((3, 2)), names, FaceScores(s, names, [0], response=response), table=table)
    np.testing.assert_allclose(w, [[0.0, 0.0], [0.4, 0.3], [0.6, 0.3]])
    with pytest.raises(FacecapError, match="positive"):
        ScoreResponse(names, [0.0, 1.0], [0.0, 0.0])


# -- config, profile, later takes ---------------------------------------------------------------------------------
TAKE = ('[target]\nobject = "Face"\n[source]\nvideo = "clip.mp4"\n[tracking]\nmethod = "landmarks"\n'
        '[output]\nweights = "w.csv"\n')


def config(tmp_path, extra, name="take.toml", profile=None):
    from facecap.solvers.config import load_take_config

    path = tmp_path / name
    take = TAKE if profile is None else TAKE.replace('weights = "w.csv"\n', f'weights = "w.csv"\nprofile = "{profile}"\n')
    path.write_text(take + extra, encoding="utf-8")
    return load_take_config(path)


def landmarks_of(scores):
    """What score_response reads of a LandmarkResult: its scores, their names, its frames and rate."""
    frames = np.arange(1, len(scores) + 1, dtype=np.float64)
    return SimpleNamespace(blendshapes=scores, blendshape_names=ARKIT_51,
                           markers=SimpleNamespace(frames=frames, fps=FPS))


def test_a_rom_take_writes_its_response_into_the_profile_and_a_later_take_applies_it(tmp_path):
    """The take itself is the ROM ([calibration] sequence on a landmark take, its neutral given): its response goes
    into [output] profile; a later take with [actor] profile reads the same response back and fuses through it."""
    from facecap.facecap_addon.headless.actor_outputs import write_profile
    from facecap.facecap_addon.headless.landmark_take import score_response

    scores, neutral, _, _ = rom_clip(3)
    assert np.all(neutral[:30] == np.arange(30))  # the session's lead-in rests: frames 1-30
    rom = config(tmp_path, '[calibration]\nsequence = "facecap-24"\nneutral = [1, 30]\n', profile="performer.npz")
    assert rom.video_rom.path is None and rom.video_rom.sheet == "facecap-24" and rom.video_rom.neutral == (1, 30)
    assert rom.settings.calibration.sequence == ()  # the scores' ROM, not a marker ROM of the semantic solve
    said = []
    response, report, notes = score_response(rom, landmarks_of(scores), said.append)
    assert report["from"] == "the take" and said[0].startswith("ROM on camera: 24 of 24 poses found")
    assert len(response.changed()) > 30
    outputs = {}
    write_profile(rom, SimpleNamespace(fitted=None), outputs, response=response)
    profile = tmp_path / "performer.npz"
    assert outputs["profile"] == str(profile) and profile_contents(profile)[0] is False
    later = config(tmp_path, '[actor]\nprofile = "performer.npz"\n', name="later.toml")
    back, report, notes = score_response(later, landmarks_of(scores[:50]), said.append)
    assert notes == () and report["sheet"] == "facecap-24"
    np.testing.assert_allclose(back.gain, response.gain)
    np.testing.assert_allclose(back.offset, response.offset)
    s = np.concatenate([np.zeros((1, len(ARKIT_51))), np.random.default_rng(0).uniform(0, 0.5, (4, len(ARKIT_51)))])
    table = FusionTable({n: 1.0 for n in ARKIT_51}, {n: 0.0 for n in ARKIT_51})
    w, _ = fuse(np.zeros_like(s), ARKIT_51, FaceScores(s, ARKIT_51, [0], response=back), table=table)
    np.testing.assert_allclose(w, np.clip(response(s, ARKIT_51), 0, 1))
    assert not np.allclose(w, s)
    with pytest.raises(ConfigError, match="performer profile") as err:  # a profile needs something to hold
        write_profile(rom, SimpleNamespace(fitted=None), {}, response=None)
    assert err.value.key == "output.profile"


def test_a_marker_profile_on_a_video_take_says_what_it_lacks(tmp_path):
    from facecap.facecap_addon.headless.landmark_take import score_response
    from facecap.solvers.character.basis import Basis

    profile = tmp_path / "markers.npz"
    Basis(("jawOpen",), ("m1", "m2"), np.zeros((2, 3)), np.ones((1, 2, 3))).save_npz(profile)
    assert profile_contents(profile) == (True, None)
    later = config(tmp_path, f'[actor]\nprofile = "{profile.name}"\n')
    response, report, notes = score_response(later, landmarks_of(np.zeros((5, len(ARKIT_51)))), print)
    assert response is None and report is None
    assert "holds no blendshape response" in notes[0] and "[calibration] video" in notes[0]
    # both in one profile: the measured shapes still load as a Basis
    both = tmp_path / "both.npz"
    save_profile(both, basis=Basis.load_npz(profile), response=ScoreResponse(("jawOpen",), [1.5], [0.0]))
    assert Basis.load_npz(both).shape_names == ("jawOpen",)
    assert profile_contents(both)[1].gain[0] == 1.5
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(InputFileError, match="junk.npz"):
        profile_contents(tmp_path / "junk.npz")


def test_holds_in_the_config_place_the_poses_of_a_rom_on_camera(tmp_path):
    """[calibration] holds on a landmark take's ROM: frame numbers of the clip (frame 1 first), only those poses
    measured; a frame outside the clip is refused naming the key and the pose."""
    from facecap.facecap_addon.headless.landmark_take import score_response

    scores, neutral, _, _ = rom_clip(3)
    found = fit_response(scores, ARKIT_51, neutral, POSES, fps=FPS)
    jaw = 1 + 0.5 * sum(found.frames[0])  # "jaw open", as a frame number
    take = config(tmp_path, '[calibration]\nsequence = "facecap-24"\nneutral = [1, 30]\n'
                  f'holds = {{"jaw open" = {jaw}}}\n')
    assert take.video_rom.holds == (("jaw open", jaw),)
    response, report, _ = score_response(take, landmarks_of(scores), lambda _m: None)
    assert report["summary"].startswith("1 of 24 poses where they were placed")
    assert "jawOpen" in response.changed() and "mouthSmileLeft" not in response.changed()
    late = config(tmp_path, '[calibration]\nsequence = "facecap-24"\nneutral = [1, 30]\nholds = {smile = 99999}\n')
    with pytest.raises(ConfigError, match=r"\[calibration.holds\] 'smile' is placed at frame 99999, outside the ROM"):
        score_response(late, landmarks_of(scores), lambda _m: None)


@pytest.mark.parametrize("take, extra, key, match", [
    (TAKE.replace('method = "landmarks"', 'method = "dis"'), '[calibration]\nvideo = "rom.mp4"\nsequence = '
     '"facecap-24"\n', "calibration.video", "calibrates a landmark take's blendshape scores"),
    (TAKE, '[calibration]\nvideo = "rom.mp4"\n', "calibration.sequence", "the sheet the ROM on camera performs"),
    (TAKE, '[calibration]\nvideo = "rom.mp4"\nsequence = "facecap-24"\nmarkers = "rom.c3d"\n', "calibration.markers",
     "not both"),
    (TAKE, '[calibration]\nvideo = "rom.mp4"\nsequence = "facecap-99"\n', "calibration.sequence", "unknown sheet"),
    (TAKE, '[calibration]\nvideo = ""\nsequence = "facecap-24"\n', "calibration.video", "expected a file name"),
    (TAKE.replace('method = "landmarks"', 'method = "landmarks"\nblendshapes = "ignore"'),
     '[calibration]\nvideo = "rom.mp4"\nsequence = "facecap-24"\n', "calibration.video", "leaves them out"),
    (TAKE, '[calibration]\nsequence = "facecap-24"\nholds = {grin = 40}\n', "calibration.holds",
     "'grin' is not a pose of the sequence"),
    (TAKE, '[calibration]\nvideo = "rom.mp4"\nsequence = "facecap-24"\nholds = {smile = "x"}\n', "calibration.holds",
     "must be a number"),
])
def test_rom_on_camera_config_errors_name_the_key(tmp_path, take, extra, key, match):
    from facecap.solvers.config import load_take_config

    path = tmp_path / "take.toml"
    path.write_text(take + extra, encoding="utf-8")
    with pytest.raises(ConfigError, match=match) as err:
        load_take_config(path)
    assert key in [getattr(e, "key", None) for e in getattr(err.value, "problems", [err.value])] or \
        f"[{key}]" in str(err.value)


def test_a_filmed_rom_config_writes_a_profile_of_its_response(tmp_path):
    """[calibration] video is relative to the config; with it, [output] profile needs no semantic calibration."""
    c = config(tmp_path, '[calibration]\nvideo = "rom.mp4"\nsequence = "facecap-24"\n', profile="perf.npz")
    assert c.video_rom.path == str(tmp_path / "rom.mp4") and len(c.video_rom.poses) == 24
    assert c.output_profile == tmp_path / "perf.npz"
    with pytest.raises(ConfigError, match="a performer profile holds"):
        config(tmp_path, "", profile="perf.npz")
    from facecap.solvers.config.paths import take_inputs

    assert take_inputs(c)["[calibration.video]"] == tmp_path / "rom.mp4"  # no output may overwrite it
