"""Following a guide (solvers/video/follow.py): the guide placed in the clip where the performer performed it,
the clip's frames with the guide's weights as their truth added to the fusion map, stored in the performer profile
and read back by later takes."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from facecap.solvers.errors import ConfigError, FacecapError, InputFileError
from facecap.solvers.video.follow import (FOLLOW_SHARE, PerformerMap, find_offset, fit_follow, follow_timing,
                                          resample)
from facecap.solvers.video.fusion import FaceScores, FusionTable, fuse
from facecap.solvers.video.response import profile_contents, profile_performer, save_profile

FPS = 30.0
TABLE = FusionTable.load()
NAMES = TABLE.map.names  # the ARKit shapes the fusion map reads
HOLD = 30  # frames of a relaxed face before a clip's performance


def performance(seed, frames):
    """(frames, S) smooth, sparse weights on NAMES: each shape rises to 0.3-1 a few times, several at once."""
    rng = np.random.default_rng(seed)
    w = np.zeros((frames, len(NAMES)))
    t = np.arange(frames)
    for k in range(len(NAMES)):
        for _ in range(rng.integers(1, 4)):
            centre, width = rng.uniform(0, frames), rng.uniform(4, 15)
            w[:, k] += rng.uniform(0.3, 1.0) * np.exp(-0.5 * ((t - centre) / width) ** 2)
    return np.clip(w, 0.0, 1.0)


def performer(seed):
    """How one performer and camera read: each score ``r * w`` (r 0.3-0.8: this head under-reads them) and each
    solved weight ``q * w`` plus a share of its neighbour's weight (cross-talk)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(0.3, 0.8, len(NAMES)), rng.uniform(0.4, 0.9, len(NAMES)), rng.uniform(0.0, 0.3, len(NAMES))


def filmed(weights, reads, seed):
    """(scores (F, S), solved (F, S)) of ``weights`` performed after HOLD relaxed frames, read as ``reads`` says."""
    r, q, x = reads
    rng = np.random.default_rng(seed)
    w = np.r_[np.zeros((HOLD, len(NAMES))), weights]
    scores = np.clip(r * w + rng.normal(0, 0.01, w.shape), 0, 1)
    solved = np.clip(q * w + x * np.roll(w, 1, axis=1) + rng.normal(0, 0.01, w.shape), 0, 1)
    return scores, solved


def scores_of(values):
    return FaceScores(values, NAMES, np.arange(HOLD), fps=FPS)


def rmse(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2)))


def test_the_guide_is_placed_where_the_performer_performed_it():
    """Late, at another amplitude per shape, noisy, with gaps: the offset is found to a frame, whether the guide
    starts inside the clip or before it (the clip starts late) or runs past its end."""
    rng = np.random.default_rng(1)
    guide = performance(2, 200)
    for offset in (37, -25, 60):
        read = np.full((240, len(NAMES)), np.nan)
        g0, g1 = max(0, -offset), min(200, 240 - offset)
        read[g0 + offset:g1 + offset] = guide[g0:g1] * rng.uniform(0.5, 1.2, len(NAMES))
        read += rng.normal(0, 0.05, read.shape)
        read[100:104] = np.nan  # frames without a face
        found, r = find_offset(guide, read)
        assert found == offset and r > 0.7, (offset, found, r)
    with pytest.raises(FacecapError, match="film at least 160 frames"):
        find_offset(guide, read[:100])
    with pytest.raises(FacecapError, match="moves no shape"):
        find_offset(np.zeros_like(guide), read)


def test_a_performer_who_drifts_from_a_long_guide_is_followed_frame_by_frame():
    """40 s of guide performed 4 % slow (1.6 s late by its end, no single placement fits it): each clip frame is
    matched to the guide frame it performs (median within a frame, every frame within 5: the last windows' drift
    is held, not extrapolated, to the clip's ends); a performer on time keeps the placement."""
    rng = np.random.default_rng(3)
    guide = performance(4, 1200)
    start, tempo = 20, 1.04
    clip_frames = np.arange(1300)
    performs = (clip_frames - start) / tempo  # the guide frame each clip frame performs
    read = np.full((1300, len(NAMES)), np.nan)
    inside = (performs >= 0) & (performs <= 1199)
    for k in range(len(NAMES)):
        read[inside, k] = np.interp(performs[inside], np.arange(1200), guide[:, k])
    read += rng.normal(0, 0.05, read.shape)
    offset, _ = find_offset(guide, read)
    when = follow_timing(guide, read, offset, FPS)
    both = inside & np.isfinite(when)
    assert both.sum() > 0.95 * inside.sum()
    err = np.abs(when[both] - performs[both])
    assert np.median(err) <= 1.0 and np.max(err) <= 5.0, (np.median(err), np.max(err))
    assert np.max(np.abs(clip_frames[both] - offset - performs[both])) > 20  # what one placement would miss
    on_time = np.full((1300, len(NAMES)), np.nan)
    on_time[start:start + 1200] = guide + rng.normal(0, 0.05, guide.shape)
    when = follow_timing(guide, on_time, find_offset(guide, on_time)[0], FPS)
    err = np.abs(when[start:start + 1200] - np.arange(1200.0))
    assert np.nanmedian(err) == 0.0 and np.nanmax(err) <= 1.0 and np.isfinite(err).mean() > 0.99


def test_a_guide_at_another_rate_is_resampled_in_time():
    guide = np.c_[np.arange(61.0), np.linspace(0, 1, 61)]  # 1 s at 60 frames/s
    out = resample(guide, 60.0, 30.0)
    assert out.shape == (31, 2)
    np.testing.assert_allclose(out[:, 0], np.arange(0, 61, 2.0))
    np.testing.assert_allclose(resample(guide, 60.0, 24.0)[:, 1], np.linspace(0, 1, 25), atol=1e-12)


def test_a_performer_who_followed_a_guide_is_read_closer_to_the_truth():
    """A performer whose head under-reads every score and whose solve mixes in a neighbour follows a guide for
    8 s (late by 11 frames): with that clip in the map, another performance of theirs is read closer to its truth
    than through the tuning faces' map alone, and the guide is placed to a frame."""
    reads = performer(5)
    guide = performance(6, 240)
    late = 11
    scores, solved = filmed(np.r_[np.zeros((late, len(NAMES))), guide], reads, 7)
    fit = fit_follow(guide, NAMES, FPS, solved, NAMES, scores_of(scores))
    assert abs(fit.offset - (HOLD + late)) <= 1 and fit.correlation > 0.5
    assert abs(fit.frames - 240) <= 2 and fit.performer.clips == FOLLOW_SHARE * len(TABLE.measured_on["map_clips"])
    truth = performance(8, 300)
    s2, l2 = filmed(truth, reads, 9)
    before, _ = fuse(l2, NAMES, scores_of(s2), table=TABLE)
    after, _ = fuse(l2, NAMES, FaceScores(s2, NAMES, np.arange(HOLD), fps=FPS, performer=fit.performer), table=TABLE)
    err_before, err_after = rmse(before[HOLD:], truth), rmse(after[HOLD:], truth)
    print(f"another performance: RMSE {err_before:.3f} -> {err_after:.3f}")
    assert err_after < 0.85 * err_before  # measured 0.132 -> 0.107 (0.103 when the clip taught the eyes too)
    # weighing as one tuning clip instead of a few: closer than without, not as close
    one, _ = fuse(l2, NAMES, FaceScores(s2, NAMES, np.arange(HOLD), fps=FPS,
                                        performer=replace(fit.performer, clips=1.0)), table=TABLE)
    assert err_after < rmse(one[HOLD:], truth) < err_before


def test_the_performers_own_blinks_and_gaze_teach_the_map_nothing(monkeypatch):
    """A performer following a guide blinks when they blink and looks at the screen, whatever the guide's eyes do:
    the guide's blinks and looks are no truth for their clip. The map with their clip in it reads the eyes as the
    tuning faces' map does (each eye shape's weights within 0.05), while the shapes they followed change; taught the
    guide's eyes instead, the same clip moves the blinks' weights by far more."""
    from facecap.solvers.video import follow

    reads = performer(5)
    guide = performance(6, 240)
    performed = guide.copy()
    eyes = [j for j, n in enumerate(NAMES) if n in follow.NOT_FOLLOWED]
    assert len(eyes) == 10
    performed[:, eyes] = performance(11, 240)[:, eyes] * 0.2  # their own, not the guide's
    scores, solved = filmed(performed, reads, 7)
    ones = np.ones(len(NAMES), bool)

    def moved(fit):
        before = TABLE.map.weights(TABLE, ones, ones)
        after = fit.performer(TABLE).map.weights(TABLE, ones, ones)
        change = np.abs(after - before).max(axis=0)
        return change[eyes].max(), np.delete(change, eyes).max()

    eyes_moved, others_moved = moved(fit_follow(guide, NAMES, FPS, solved, NAMES, scores_of(scores), offset=HOLD))
    print(f"eye shapes' weights moved {eyes_moved:.3f}, the others up to {others_moved:.3f}")
    assert eyes_moved <= 0.05 and others_moved >= 0.2  # measured 0.022 (the ridge's pull) and 0.61
    monkeypatch.setattr(follow, "NOT_FOLLOWED", ())
    taught, _ = moved(fit_follow(guide, NAMES, FPS, solved, NAMES, scores_of(scores), offset=HOLD))
    print(f"taught the guide's eyes: moved {taught:.3f}")
    assert taught >= 5 * max(eyes_moved, 0.01)


def test_a_clip_that_does_not_follow_the_guide_is_refused():
    reads = performer(5)
    scores, solved = filmed(performance(11, 240), reads, 7)
    with pytest.raises(FacecapError, match="does not follow the guide"):
        fit_follow(performance(12, 200), NAMES, FPS, solved, NAMES, scores_of(scores))
    with pytest.raises(FacecapError, match="the guide lacks 2 of the ARKit shapes"):
        fit_follow(performance(12, 200)[:, 2:], NAMES[2:], FPS, solved, NAMES, scores_of(scores))
    # placed by hand: used as given, even where the clip does not follow
    fit = fit_follow(performance(12, 200), NAMES, FPS, solved, NAMES, scores_of(scores), offset=40)
    assert fit.offset == 40 and np.isnan(fit.correlation) and fit.frames == 200


def test_the_performers_map_goes_into_the_profile_and_back(tmp_path):
    reads = performer(5)
    guide = performance(6, 240)
    scores, solved = filmed(guide, reads, 7)
    fit = fit_follow(guide, NAMES, FPS, solved, NAMES, scores_of(scores), guide_label="guide.csv")
    path = tmp_path / "performer.npz"
    save_profile(path, performer=fit.performer)
    assert profile_contents(path) == (False, None)
    back = profile_performer(path)
    assert back.guide == "guide.csv" and back.names == fit.performer.names and back.clips == fit.performer.clips
    np.testing.assert_array_equal(back.gram, fit.performer.gram)
    a, b = fit.performer(TABLE), back(TABLE)
    np.testing.assert_array_equal(a.map.moment, b.map.moment)
    assert a.map.ridge == pytest.approx(TABLE.map.ridge + back.clips * TABLE.measured_on["map_ridge"])
    # a map of other names adds only where the names meet
    few = PerformerMap(NAMES[:2], back.gram[np.ix_([0, 1, len(NAMES), len(NAMES) + 1], [0, 1, len(NAMES),
                                                                                     len(NAMES) + 1])],
                       back.moment[np.ix_([0, 1, len(NAMES), len(NAMES) + 1], [0, 1])], back.ridge)
    added = few(TABLE).map.gram - TABLE.map.gram
    assert np.count_nonzero(added) == np.count_nonzero(few.gram)
    # a damaged one names the file
    np.savez(tmp_path / "bad.npz", performer_names=np.array(NAMES), performer_gram=np.zeros((3, 3)),
             performer_moment=np.zeros((2, 2)), performer_ridge=0.01, performer_clips=1.0)
    with pytest.raises(InputFileError, match="bad.npz.*performer's map is damaged"):
        profile_performer(tmp_path / "bad.npz")


# -- config and the headless take -----------------------------------------------------------------------------------
TAKE = ('[target]\nobject = "Face"\n[source]\nvideo = "clip.mp4"\n[tracking]\nmethod = "landmarks"\n'
        '[output]\nweights = "w.csv"\n')


def load(tmp_path, extra, take=TAKE):
    from facecap.solvers.config import load_take_config

    path = tmp_path / "take.toml"
    path.write_text(take + extra, encoding="utf-8")
    return load_take_config(path)


def test_a_guide_config_names_its_clip_guide_and_start(tmp_path):
    from facecap.solvers.config.paths import take_inputs

    take = TAKE.replace('weights = "w.csv"\n', 'weights = "w.csv"\nprofile = "p.npz"\n')
    c = load(tmp_path, '[calibration]\nvideo = "follow.mp4"\nguide = "guides/g.csv"\nguide_start = 41\n'
                       'neutral = [1, 20]\n', take=take)
    rom = c.video_rom
    assert rom.path == str(tmp_path / "follow.mp4") and rom.guide == str(tmp_path / "guides" / "g.csv")
    assert rom.guide_start == 41.0 and rom.neutral == (1, 20) and rom.poses == ()
    assert c.output_profile == tmp_path / "p.npz"
    inputs = take_inputs(c)
    assert inputs["[calibration.guide]"] == tmp_path / "guides" / "g.csv"
    assert load(tmp_path, '[calibration]\nguide = "g.csv"\n').video_rom.path is None  # the take itself follows it


@pytest.mark.parametrize("take, extra, key, match", [
    (TAKE, '[calibration]\nguide = "g.csv"\nsequence = "facecap-24"\n', "calibration.sequence", "not both"),
    (TAKE, '[calibration]\nguide = "g.csv"\nguide_start = 0\n', "calibration.guide_start", "a number >= 1"),
    (TAKE.replace('method = "landmarks"', 'method = "dis"'), '[calibration]\nguide = "g.csv"\n', "calibration.guide",
     "landmark take's blendshape scores"),
    (TAKE.replace('method = "landmarks"', 'method = "landmarks"\nblendshapes = "ignore"'),
     '[calibration]\nguide = "g.csv"\n', "calibration.guide", "the scores fused"),
])
def test_guide_config_errors_name_the_key(tmp_path, take, extra, key, match):
    with pytest.raises(ConfigError, match=match) as err:
        load(tmp_path, extra, take=take)
    keys = [getattr(e, "key", None) for e in getattr(err.value, "problems", [err.value])]
    assert key in keys or f"[{key}]" in str(err.value), (keys, str(err.value))


def test_a_later_take_reads_the_performers_map_from_the_profile(tmp_path):
    from facecap.facecap_addon.headless.landmark_take import performer_of, score_response

    reads = performer(5)
    guide = performance(6, 240)
    scores, solved = filmed(guide, reads, 7)
    save_profile(tmp_path / "p.npz", performer=fit_follow(guide, NAMES, FPS, solved, NAMES, scores_of(scores),
                                                          guide_label="g.csv").performer)
    later = load(tmp_path, '[actor]\nprofile = "p.npz"\n')
    found = SimpleNamespace(blendshapes=scores, blendshape_names=NAMES,
                            markers=SimpleNamespace(frames=np.arange(1.0, len(scores) + 1), fps=FPS))
    assert score_response(later, found, print) == (None, None, ())  # no "holds no response" note: it holds a map
    source = {}
    assert performer_of(later, source).guide == "g.csv"
    assert source["guide_followed"] == {"from": str(tmp_path / "p.npz"), "guide": "g.csv", "weighs_as_clips": 8.0}
