"""Fusion of the Face Landmarker's blendshape scores with the landmark solve (solvers/video/fusion.py)."""

import numpy as np
import pytest

from facecap.solvers.errors import FacecapError
from facecap.solvers.video.fusion import FaceScores, FusionTable, fit_table, fuse, neutral_corrected


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
