"""The fusion benchmark's clips (facecap_addon/bench/fusion_bench.py): what the fusion map is fitted on."""

from pathlib import Path

import numpy as np
import pytest

from facecap.facecap_addon.bench import fusion_bench as fb
from facecap.facecap_addon.bench.landmark_bench import shared_folder


def test_random_activations_fire_every_shape_on_its_own():
    """The random-activation clips: a relaxed start (the take's neutral), then about five shapes at once, each
    fired independently of the others (their correlations average about 0), never two opposite
    directions at once; over the tuning clips every judged shape fires."""
    names = list(fb.face_arrays("ict-21", shared_folder() / "data")[2])
    clips = [c for c in fb.CLIPS if c.role == "tune-random"]
    assert len(clips) >= 8 and {c.face for c in clips} == {"ict-21", "ict-22"} and {c.azimuth for c in clips} == {0, 30}
    fired = set()
    for clip in clips:
        weights, head, gaze = fb.random_performance(names, clip.start, clip.frames)
        assert weights.shape == (fb.HOLD + clip.frames, len(names)) and head.shape == (len(weights), 6)
        assert not weights[: fb.HOLD].any() and 0.0 <= weights.min() and weights.max() <= 1.0
        active = (weights[fb.HOLD:] > 0.05).sum(axis=1)
        assert 3.0 <= active.mean() <= 8.0, active.mean()
        for a, b in fb.OPPOSITE.items():
            if a in names and b in names:
                assert not np.any((weights[:, names.index(a)] > 0) & (weights[:, names.index(b)] > 0)), (a, b)
        fired |= {n for k, n in enumerate(names) if weights[:, k].max() > 0.3}
        moving = weights[fb.HOLD:, weights[fb.HOLD:].std(axis=0) > 0]
        corr = np.corrcoef(moving.T)
        pairs = corr[~np.eye(len(corr), dtype=bool)]
        assert abs(pairs.mean()) < 0.05, pairs.mean()  # no shape drawn along with the others
    assert set(fb.judged_names()) <= fired, set(fb.judged_names()) - fired


def test_other_performers_are_judged_never_fitted_and_their_windows_fit_their_recordings():
    """The tuning clips perform two people (Alex and Jason Miller); the ``report-others`` clips, both reported faces
    and cameras, a third person's recording, never among the roles anything is fitted on. Another performer's clip
    is named by the performer, each window inside its recording (read by row at 30 frames/s from the recording's
    60)."""
    from facecap.facecap_addon.bench import fusion_clips as fc
    from facecap.solvers.io.weights import read_weights

    others = [c for c in fb.CLIPS if c.role == "report-others"]
    assert {c.face for c in others} == {"ict-mean", "facecap"} and {c.azimuth for c in others} == {0, 30}
    assert "report-others" not in fc.MAP_ROLES and len({c.name for c in fb.CLIPS}) == len(fb.CLIPS)
    tuned = {c.recording for c in fb.CLIPS if c.role in fc.MAP_ROLES}
    performer = lambda recording: Path(recording).stem.split("_")[1]  # noqa: E731
    tuning_people = {performer(r) for r in tuned if r.endswith(".csv")}
    assert tuning_people == {"alex", "jmtechart"}
    assert not {c.recording for c in fb.CLIPS if c.role == "report"} & tuned  # Alex's other recording
    for clip in [c for c in fb.CLIPS if c.recording.startswith("edge-cases/")]:
        assert clip.role in ("tune", "report-others", "tune-performers")
        assert clip.role != "report-others" or performer(clip.recording) not in tuning_people
        assert f"{clip.face}-{performer(clip.recording)}-" in clip.name  # named by the performer
        track = read_weights(shared_folder() / "data" / "realdata" / clip.recording)
        step = max(1, int(round(track.fps / clip.fps)))
        assert clip.start + step * clip.frames <= len(track.values), clip.name


def test_pinned_counts_the_weights_held_at_their_full_extent():
    """The bench's "at 1" figure: the share of judged samples at >= 0.999, NaN left out."""
    from facecap.facecap_addon.bench.fusion_clips import pinned

    w = np.array([[1.0, 0.5], [0.9995, np.nan], [0.2, 0.0], [0.998, 1.0]])
    assert pinned(w) == 100.0 * 3 / 7
    assert np.isnan(pinned(np.full((2, 2), np.nan)))


def test_the_shapes_carrying_the_error_add_up_to_the_visible_rmse(capsys):
    """Each judged shape's squared error (``region_rmse``'s "shapes") is what the visible RMSE averages, a shape the
    truth lacks left out; ``print_shapes`` names the largest first with its share."""
    from facecap.facecap_addon.bench.fusion_clips import judged_names, print_shapes, region_rmse

    names = judged_names()
    rng = np.random.default_rng(3)
    truth = rng.uniform(0, 1, (50, len(names)))
    truth[:, names.index("mouthRollLower")] = np.nan
    got = truth + rng.normal(0, 0.05, truth.shape)
    got[:, names.index("eyeWideLeft")] = truth[:, names.index("eyeWideLeft")] + 0.5  # the one shape far off
    r = region_rmse(got, truth, names)
    assert "mouthRollLower" not in r["shapes"] and len(r["shapes"]) == len(names) - 1
    assert np.sqrt(np.mean(list(r["shapes"].values()))) == pytest.approx(r["visible"], rel=1e-12)
    assert r["shapes"]["eyeWideLeft"] == pytest.approx(0.25, abs=0.02)
    print_shapes({"report-ict-mean-x": {"fused": r}})
    line = capsys.readouterr().out
    assert line.startswith("ict fused, the shapes carrying it: eyeWideLeft 0.50 (")


def test_the_performers_check_never_fits_on_a_performer_it_calls_unseen_nor_on_a_reported_window():
    """``--performers``: each fit reads the ROM sessions, the random activations and the windows of its performers
    only; a group judged by a fit without its performer holds none of the clips the fit read; Sentien's tuning
    windows keep 20 rows clear of the reported window on either side, and the shipped fit's roles never include
    them."""
    from facecap.facecap_addon.bench import fusion_clips as fc
    from facecap.facecap_addon.bench import fusion_fit as ff

    assert "tune-performers" not in fc.MAP_ROLES
    assert ff.PERFORMER_FITS[0] == ("alex", "jmtechart")  # the shipped fit's performers come first
    assert {fc.performer(c) for c in fb.CLIPS if c.role in fc.MAP_ROLES} - {None} == {"alex", "jmtechart"}
    groups = ff.performer_groups()
    assert all(groups.values()) and {who for who, _ in groups} == {"alex", "jmtechart", "sentien"}
    for people in ff.PERFORMER_FITS:
        read = ff.performer_fit_clips(people)
        assert {fc.performer(c) for c in read} - {None} == set(people)
        assert not [c for c in read if c.role.startswith("report")]
        for (who, _face), group in groups.items():
            assert all(fc.performer(c) == who for c in group)
            if who not in people:
                assert not {c.name for c in group} & {c.name for c in read}
    reported = [(c.start, c.start + 2 * c.frames) for c in fb.CLIPS if c.role == "report-others"]
    for clip in [c for c in fb.CLIPS if c.role == "tune-performers"]:
        rows = (clip.start, clip.start + 2 * clip.frames)  # 30 frames/s read from the recording's 60
        assert all(rows[1] + 20 <= a or b + 20 <= rows[0] for a, b in reported), clip.name


def test_the_maps_ridge_is_judged_on_a_face_and_a_performer_the_fold_never_read():
    """``fit_cross`` chooses the map's ridge on folds that leave a tuning identity and a tuning performer out
    together: no clip a fold judges shares its face, nor its performer, with a clip the fold fits on; ROM sessions
    and random activations (nobody's habits) are fitted on, never judged; every tuning performer on every tuning
    identity is judged once; a single performer gives no such fold."""
    from facecap.facecap_addon.bench import fusion_clips as fc
    from facecap.facecap_addon.bench import fusion_fit as ff

    clips = [c for c in fb.CLIPS if c.role in fc.MAP_ROLES]
    folds = ff.performer_folds(clips)
    faces = {c.face for c in clips}
    people = {fc.performer(c) for c in clips} - {None}
    assert len(folds) == len(faces) * len(people) == 4
    judged_pairs = set()
    for kept, judged in folds:
        assert judged and kept
        assert {c.face for c in judged}.isdisjoint({c.face for c in kept})
        assert {fc.performer(c) for c in judged}.isdisjoint({fc.performer(c) for c in kept})
        assert all(c.role in ff.PERFORMANCE_ROLES for c in judged)
        assert any(fc.performer(c) is None for c in kept)  # the habitless clips stay in
        judged_pairs |= {(c.face, fc.performer(c)) for c in judged}
    assert judged_pairs == {(f, p) for f in faces for p in people}
    alone = [c for c in clips if fc.performer(c) in (None, "alex")]
    assert ff.performer_folds(alone) == []


def test_a_guide_clip_cached_by_the_follower_who_copied_the_guides_eyes_is_rendered_again(tmp_path, monkeypatch):
    """A cache from before the follower kept their own eyes holds follow clips whose map learnt the guide's eyes:
    ``prepare`` renders such a clip again (its stale video removed first) and returns a clip of today's follower,
    or of another role, as cached."""
    class Rendering(Exception):
        pass

    def render(*_args, **_kwargs):
        raise Rendering

    monkeypatch.setattr(fb, "render_face_clip", render)
    follow = next(c for c in fb.CLIPS if c.role == "follow")
    report = next(c for c in fb.CLIPS if c.role == "report")
    np.savez(tmp_path / f"{report.name}.npz", truth=np.zeros(2))
    np.savez(tmp_path / f"{follow.name}.npz", truth=np.zeros(2), follower=np.array(fb.FOLLOWER))
    assert set(fb.prepare(report, tmp_path, None, log=print)) == {"truth"}
    assert "follower" in fb.prepare(follow, tmp_path, None, log=print)
    np.savez(tmp_path / f"{follow.name}.npz", truth=np.zeros(2))  # an older cache's
    (tmp_path / f"{follow.name}.mp4").write_bytes(b"stale")
    with pytest.raises(Rendering):
        fb.prepare(follow, tmp_path, None, log=print)
    assert not (tmp_path / f"{follow.name}.mp4").exists()
