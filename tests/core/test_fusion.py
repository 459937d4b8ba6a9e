"""Fusion of the Face Landmarker's blendshape scores with the landmark solve (solvers/video/fusion.py)."""

import numpy as np
import pytest

from facecap.solvers.errors import FacecapError
from facecap.solvers.video.fusion import (
    MAP_FILE_NAME,
    SMOOTHING_S,
    FaceScores,
    FusionTable,
    fit_lid_gaze,
    fit_map,
    fit_table,
    fuse,
    lids_against_gaze,
    neutral_corrected,
    smooth_runs,
)
from facecap.solvers.video.gaze import gap_from_lids, lids_from_gap


def test_scores_are_corrected_by_their_level_on_the_neutral_frames():
    """A shape that rests at 0.3 reads 0 on the neutral and 1 at full; NaN (no face) stays NaN."""
    s = np.array([[0.3, 0.0], [0.3, 0.1], [0.65, 0.5], [1.0, 1.0], [np.nan, np.nan]])
    c = neutral_corrected(s, [0, 1])
    np.testing.assert_allclose(c[:4, 0], [0.0, 0.0, 0.5, 1.0])
    np.testing.assert_allclose(c[:4, 1], [0.0, 0.05 / 0.95, 0.45 / 0.95, 1.0])
    assert np.isnan(c[4]).all()
    with pytest.raises(FacecapError, match="neutral frames"):
        neutral_corrected(s, [])


def test_fuse_combines_per_shape_by_the_table_and_keeps_the_rest():
    """Per shape a * corrected + b * solve, clipped to the bounds; the character's names match the scores'
    through the alias tables; shapes without a score, and frames without a face, keep the solve; the response
    hook sees the corrected scores before they are combined."""
    F = 6
    scores = np.zeros((F, 3))
    scores[:, 0] = [0.2, 0.2, 0.6, 1.0, 0.2, np.nan]  # browInnerUp, resting at 0.2
    scores[:, 1] = [0.0, 0.0, 0.5, 0.9, 0.0, np.nan]  # jawOpen
    scores[:, 2] = 0.4  # a score no shape of the character has
    names = ("browInnerUp", "jawOpen", "cheekPuff")
    solve = np.tile([[0.1, 0.3, 0.7]], (F, 1))
    table = FusionTable({"browInnerUp": 1.0, "jawOpen": 0.5, "cheekPuff": 1.0},
                        {"browInnerUp": 0.0, "jawOpen": 0.5, "cheekPuff": 0.0})
    seen = []

    def response(c, n):
        seen.append((c.copy(), n))
        return c

    w, fused = fuse(solve, ("BrowInnerUp", "jaw_open", "mySmirk"), FaceScores(scores, names, np.array([0, 1])),
                    table=table, response=response)
    assert fused == ["BrowInnerUp", "jaw_open"]
    np.testing.assert_allclose(w[:5, 0], [0.0, 0.0, 0.5, 1.0, 0.0])
    np.testing.assert_allclose(w[:5, 1], 0.5 * np.array([0.0, 0.0, 0.5, 0.9, 0.0]) + 0.5 * 0.3)
    np.testing.assert_allclose(w[:, 2], 0.7)  # no score for mySmirk
    np.testing.assert_allclose(w[5], solve[5])  # no face: the solve
    assert seen and seen[0][1] == names and np.isclose(seen[0][0][3, 0], 1.0)
    w2, _ = fuse(solve, ("browInnerUp", "jawOpen", "x"),  # a performer's response riding with the scores
                 FaceScores(scores, names, np.array([0, 1]), response=lambda c, n: 2.0 * c), table=table,
                 upper=np.array([0.8, 1.0, 1.0]))
    assert w2[:5, 0].max() == pytest.approx(0.8)  # the character's bound
    with pytest.raises(FacecapError, match="5 frames; the solve has 6"):
        fuse(solve, names, FaceScores(scores[:5], names, np.array([0])), table=table)


def _jitter(x):
    return float(np.mean(np.abs(np.diff(x, 2, axis=0))))


def test_fused_weights_are_smoothed_over_time_but_blinks_gaps_and_holds_are_kept():
    """With the take's frame rate the fused weights lose the per-frame scores' jitter (a Gaussian of SMOOTHING_S),
    a held pose keeps its level, no frame is smoothed across a gap (a frame without a face), blinks stay sharp
    (a 3-frame blink keeps its peak), and ``smoothing=False`` or an unknown rate leaves the weights as fused."""
    rng = np.random.default_rng(3)
    F = 240
    t = np.arange(F) / 30.0
    level = 0.3 + 0.25 * np.sin(2 * np.pi * 0.4 * t)  # a smile that comes and goes
    level[:20] = 0.0  # after a rest
    level[20:35] = np.linspace(0.0, level[35], 15)
    level[150:190] = level[150]  # and holds
    blink = np.zeros(F)
    blink[100:103] = [0.5, 1.0, 0.5]
    names = ("mouthSmileLeft", "eyeBlinkLeft")
    scores = np.stack([level, blink], axis=1) + rng.normal(0.0, 0.03, (F, 2)) * np.array([1.0, 0.0])
    scores[60:63] = np.nan  # three frames without a face
    scores[:, 0] = np.clip(scores[:, 0], 0.0, 1.0)
    table = FusionTable({"mouthSmileLeft": 1.0, "eyeBlinkLeft": 1.0}, {"mouthSmileLeft": 0.0, "eyeBlinkLeft": 0.0})
    solve = np.full((F, 2), 0.25)
    rest = np.arange(20)
    raw, _ = fuse(solve, names, FaceScores(scores, names, rest, fps=30.0, smoothing=False), table=table)
    smooth, fused = fuse(solve, names, FaceScores(scores, names, rest, fps=30.0), table=table)
    unknown, _ = fuse(solve, names, FaceScores(scores, names, rest), table=table)
    assert fused == list(names)
    np.testing.assert_array_equal(unknown, raw)  # no frame rate: nothing to smooth by
    seen = np.isfinite(scores[:, 0])
    assert _jitter(smooth[seen, 0]) < 0.45 * _jitter(raw[seen, 0])  # the scores' chatter: less than half left
    err = lambda w: np.sqrt(np.mean((w[seen, 0] - level[seen]) ** 2))  # noqa: E731
    assert err(smooth) < 0.8 * err(raw)  # nearer the performance, not only smoother
    assert abs(np.mean(smooth[158:182, 0]) - level[150]) < 0.01  # the hold keeps its level
    np.testing.assert_array_equal(smooth[:, 1], raw[:, 1])  # the blink as fused
    assert smooth[101, 1] == pytest.approx(1.0)
    np.testing.assert_allclose(smooth[60:63], solve[60:63])  # the gap keeps the solve
    # either side of the gap is smoothed on its own: a jump across it is not blurred into the other side
    values = np.r_[np.zeros(20), np.ones(20)]
    split = np.r_[np.ones(20, bool), np.zeros(5, bool), np.ones(20, bool)]
    np.testing.assert_allclose(smooth_runs(values, split, SMOOTHING_S * 30.0), values, atol=1e-12)
    joined = smooth_runs(values, np.ones(40, bool), SMOOTHING_S * 30.0)
    assert 0.0 < joined[19] < 0.5 < joined[20] < 1.0
    both = smooth_runs(np.stack([values, values[::-1]], axis=1), split, 1.0)  # columns at once, as one by one
    np.testing.assert_allclose(both[:, 1], smooth_runs(values[::-1], split, 1.0), atol=1e-12)


def test_fit_table_recovers_known_gains_and_round_trips(tmp_path):
    """On data made from known non-negative gains (and noise) the fit finds them; a shape that never moves in the
    tuning data keeps the solve; the saved table reads back."""
    rng = np.random.default_rng(0)
    n = 2000
    truth = np.clip(rng.random((n, 3)) ** 2, 0, 1)
    truth[:, 2] = 0.0
    corrected = truth / 0.8 + rng.normal(0, 0.02, (n, 3))
    solved = 0.5 * truth + rng.normal(0, 0.2, (n, 3))
    solved[:, 1] = truth[:, 1] + rng.normal(0, 0.01, n)  # a shape the solve gets right
    corrected[:, 1] = rng.random(n)  # and the scores do not
    t = fit_table(truth, solved, corrected, ["a", "b", "c"], measured_on={"clips": ["x"]})
    assert t.score["a"] == pytest.approx(0.8, abs=0.03) and t.solve["a"] < 0.05
    assert t.score["b"] < 0.02 and t.solve["b"] == pytest.approx(1.0, abs=0.02)
    assert (t.score["c"], t.solve["c"]) == (0.0, 1.0)
    t.save(tmp_path / "t.json")
    back = FusionTable.load(tmp_path / "t.json")
    assert back.measured_on == {"clips": ["x"]} and back.score["a"] == pytest.approx(t.score["a"], abs=1e-4)
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(FacecapError, match="bad.json: not a fusion table"):
        FusionTable.load(tmp_path / "bad.json")


def test_the_shipped_table_names_every_judged_shape():
    """The measured table (fusion_table.json) has gains for the ARKit shapes the blendshape head scores."""
    from facecap.solvers.video.face_landmarker import BLENDSHAPE_NAMES

    t = FusionTable.load()
    assert set(BLENDSHAPE_NAMES[1:]) - {"cheekPuff"} <= set(t.score)
    assert all(v >= 0 for v in t.score.values()) and all(v >= 0 for v in t.solve.values())
    assert len(t.measured_on["clips"]) >= 4 and all(c.startswith("tune-") for c in t.measured_on["clips"])


def _cross_talk_take(rng, n):
    """Truth of three shapes; the head's lower-lip score also rises with the jaw (cross-talk within the lower face),
    the brow's with the jaw too (across the halves); the solve sees them all, noisily."""
    truth = rng.random((n, 3)) ** 2
    corrected = np.stack([truth[:, 0] + 0.6 * truth[:, 1], truth[:, 1], truth[:, 2] + 0.3 * truth[:, 1]], axis=1)
    corrected += rng.normal(0, 0.02, (n, 3))
    solved = truth + rng.normal(0, 0.15, (n, 3))
    return truth, solved, corrected


def test_the_map_undoes_cross_talk_the_per_shape_table_cannot(tmp_path):
    """A score that reads another shape of its half of the face too: the per-shape table can only scale it; the map,
    fitted on tuning takes, subtracts the other shape's share on a take it never saw. Across the halves it reads
    nothing (a brow from the jaw is a performer's habit, not what the head misreads). Saved and loaded beside its
    table, fuse uses it."""
    rng = np.random.default_rng(3)
    names = ["mouthLowerDownLeft", "jawOpen", "browInnerUp"]
    tuning = [_cross_talk_take(rng, 400) for _ in range(3)]
    truth, solved, corrected = (np.concatenate(p) for p in zip(*tuning))
    table = fit_table(truth, solved, corrected, names)
    cross = fit_map(tuning, names, 1e-4)
    W = cross.weights(table, np.ones(3, bool), np.ones(3, bool))
    assert W[1, 0] < -0.3  # the lower lip less the jaw's share of its score
    assert W[[1, 4], 2].tolist() == [0.0, 0.0] and W[[2, 5], 0].tolist() == [0.0, 0.0]  # nothing across the halves
    table.save(tmp_path / "fusion_table.json")
    cross.save(tmp_path / MAP_FILE_NAME)
    loaded = FusionTable.load(tmp_path / "fusion_table.json")
    assert loaded.map is not None and loaded.map.names == tuple(names)
    t, s, c = _cross_talk_take(rng, 500)
    raw = np.r_[np.zeros((5, 3)), c]  # five neutral frames first, so the correction leaves the scores as they are
    solve = np.r_[np.zeros((5, 3)), s]
    take = FaceScores(raw, tuple(names), np.arange(5))
    rmse = lambda w: float(np.sqrt(np.mean((w[5:, 0] - t[:, 0]) ** 2)))  # noqa: E731
    character = ("mouthLowerDown_L", "jaw_open", "BrowInnerUp")
    per_shape = rmse(fuse(solve, character, take, table=loaded, cross=False)[0])
    mapped, fused = fuse(solve, character, take, table=loaded)
    assert fused == list(character)
    assert rmse(mapped) <= 0.5 * per_shape, (rmse(mapped), per_shape)  # measured 0.021 against 0.105
    assert rmse(mapped) < 0.03
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "fusion_table.json").write_text((tmp_path / "fusion_table.json").read_text())
    (tmp_path / "bad" / MAP_FILE_NAME).write_bytes(b"not an npz")
    with pytest.raises(FacecapError, match=f"{MAP_FILE_NAME}: not a fusion map"):
        FusionTable.load(tmp_path / "bad" / "fusion_table.json")


def test_the_map_is_solved_for_the_inputs_a_take_has():
    """A character without one of the map's shapes: the map is the ridge solution on the inputs left (the same
    normal equations without that shape's solve), not the full map with a zero put in."""
    rng = np.random.default_rng(5)
    names = ["a", "b", "c"]
    clips = [(rng.random((300, 3)), rng.random((300, 3)), rng.random((300, 3))) for _ in range(2)]
    lam = 0.01
    cross = fit_map(clips, names, lam)
    table = FusionTable({"a": 0.5, "b": 0.4, "c": 0.3}, {"a": 0.2, "b": 0.1, "c": 0.6})
    have_solve = np.array([True, False, True])
    W = cross.weights(table, np.ones(3, bool), have_solve)
    keep = [0, 1, 2, 3, 5]  # the scores, then the solve of a and c
    X = [np.concatenate([c, s], axis=1)[:, keep] for t, s, c in clips]
    prior = np.zeros((6, 3))
    prior[[0, 1, 2], [0, 1, 2]] = [0.5, 0.4, 0.3]
    prior[[3, 4, 5], [0, 1, 2]] = [0.2, 0.1, 0.6]
    G = sum(x.T @ x / len(x) for x in X) + lam * len(clips) * np.eye(5)
    M = sum(x.T @ t / len(x) for x, (t, s, c) in zip(X, clips)) + lam * len(clips) * prior[keep]
    np.testing.assert_allclose(W, np.linalg.solve(G, M), rtol=1e-10, atol=1e-12)


LIDS = ("eyeBlinkLeft", "eyeWideLeft", "eyeLookDownLeft", "eyeSquintLeft", "jawOpen")


def _looking_down_take(rng, n, per_look_down):
    """A take whose truth blinks now and then and looks down in between; the landmark solve reads the lid gap, which
    the look down lowers by ``per_look_down`` of the neutral gap at eyeLookDown 1 (a half blink to the gap alone)."""
    truth = np.zeros((n, len(LIDS)))
    truth[:, 2] = np.clip(np.sin(np.arange(n) / 15.0), 0, 1) * 0.8  # looks down
    truth[rng.random(n) < 0.05, 0] = 1.0  # blinks
    gap = 1.0 - truth[:, 0] * 0.6 + per_look_down * truth[:, 2] + rng.normal(0, 0.01, n)
    solved = truth.copy()
    solved[:, 0], solved[:, 1] = lids_from_gap(gap)
    return truth, solved


def test_the_lids_are_read_against_the_gaze_so_a_look_down_is_not_a_blink():
    """``lids_against_gaze`` takes back what a look down closes of the lid gap: the solve's half blink while the
    eye looks down goes, a real blink stays shut; the slope is fitted from tuning frames without a blink;
    0 (or an eye without its look-down shape) leaves the lids as solved; ``fuse`` reads them so with the table's
    ``lid_gaze``."""
    rng = np.random.default_rng(3)
    truth, solved = _looking_down_take(rng, 600, -0.5)
    np.testing.assert_allclose(gap_from_lids(*lids_from_gap(np.linspace(0.45, 1.45, 50))), np.linspace(0.45, 1.45, 50))
    slope = fit_lid_gaze(truth, solved, LIDS)
    assert slope == pytest.approx(-0.5, abs=0.02)
    looking, blinking = (truth[:, 2] > 0.5) & (truth[:, 0] == 0), truth[:, 0] == 1
    assert solved[looking, 0].mean() > 0.3  # the lid gap alone: a half blink
    read = lids_against_gaze(solved, LIDS, slope)
    assert np.abs(read[looking, 0]).max() < 0.06 and read[blinking & (truth[:, 2] == 0), 0].min() > 0.9
    np.testing.assert_array_equal(read[:, 2:], solved[:, 2:])
    np.testing.assert_array_equal(lids_against_gaze(solved, LIDS, 0.0), solved)
    np.testing.assert_array_equal(lids_against_gaze(solved, ("eyeBlinkLeft", "eyeWideLeft", "x", "y", "z"), slope),
                                  solved)
    # fuse: the table's lid_gaze, the blink read from the solve alone (score gain 0)
    table = FusionTable({"eyeBlinkLeft": 0.0}, {"eyeBlinkLeft": 1.0}, lid_gaze=slope)
    scores = FaceScores(np.zeros((len(solved), 1)), ("eyeBlinkLeft",), np.array([0]))
    fused, _ = fuse(solved, LIDS, scores, table=table)
    np.testing.assert_allclose(fused[:, 0], read[:, 0])
    assert fit_lid_gaze(truth, np.where(np.arange(len(LIDS)) == 2, 0.0, solved), LIDS) == 0.0  # never looks down


def test_the_shipped_table_reads_the_lids_against_the_gaze(tmp_path):
    """fusion_table.json carries the slope fitted on its tuning clips (a look down lowers the lid: negative), and a
    table's slope round-trips; one outside [-1, 0] is refused."""
    t = FusionTable.load()
    assert -1.0 <= t.lid_gaze < -0.1
    t.save(tmp_path / "t.json")
    assert FusionTable.load(tmp_path / "t.json").lid_gaze == pytest.approx(t.lid_gaze, abs=1e-4)
    text = (tmp_path / "t.json").read_text().replace(f'"lid_gaze": {round(t.lid_gaze, 4)}', '"lid_gaze": 0.5')
    (tmp_path / "bad.json").write_text(text)
    with pytest.raises(FacecapError, match="lid_gaze must be from -1 to 0"):
        FusionTable.load(tmp_path / "bad.json")


def test_the_shipped_map_covers_the_table_and_was_fitted_on_tuning_clips_only():
    """fusion_map.npz: every shape of the table, fitted on tuning faces' performances and ROM sessions (never a
    reported clip), its ridge chosen among several by leaving a tuning identity out."""
    t = FusionTable.load()
    assert t.map is not None and set(t.map.names) == set(t.score)
    clips = t.measured_on["map_clips"]
    assert all(c.startswith("tune-") for c in clips) and any(c.startswith("tune-rom-") for c in clips)
    assert len(t.measured_on["map_ridge_cv"]) >= 3 and t.map.ridge == pytest.approx(
        t.measured_on["map_ridge"] * len(clips))


def test_a_landmark_take_fuses_at_its_frame_rate_and_smooths_as_its_tracking_says():
    """The headless landmark take hands the fusion the take's frame rate and ``[tracking] smoothing``: on (the
    default) the fused weights are smoothed, ``smoothing = false`` leaves them as unfiltered as the landmarks."""
    from types import SimpleNamespace

    from facecap.facecap_addon.headless.landmark_take import with_scores
    from facecap.solvers.markers import MarkerSet
    from facecap.solvers.pipeline.settings import RetargetSettings
    from facecap.solvers.solve import SolveRequest

    F = 30
    markers = MarkerSet(("a",), np.arange(1, F + 1, dtype=np.float64), np.zeros((F, 1, 3)), fps=24.0, units="m")
    settings = RetargetSettings(stable_markers=(), neutral_frames=(1, 5))
    request = SolveRequest(character=("browInnerUp",), settings=settings, markers=markers)
    found = SimpleNamespace(blendshapes=np.zeros((F, 1)), blendshape_names=("browInnerUp",))
    for smoothing in (True, False):
        scores = with_scores(request, found, SimpleNamespace(smoothing=smoothing, blendshapes="fuse")).scores
        assert scores.fps == 24.0 and scores.smoothing is smoothing
        np.testing.assert_array_equal(scores.neutral, np.arange(5))  # [neutral] frames 1-5
    assert with_scores(request, found, SimpleNamespace(smoothing=True, blendshapes="ignore")).scores is None
