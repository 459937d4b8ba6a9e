"""Following a guide on camera, from rendered footage: the ICT face performs 5 s of a Live Link Face recording late
and imperfectly (``fusion_bench.follow_performance``); the headless landmark take with ``[calibration] guide``
finds where the guide was performed, adds the clip to the fusion map and stores it in the performer profile, which
a later take reads back."""

import json

import numpy as np
import pytest

from face_clips import ict_available, ict_character, ict_face, landmark_models
from render_child import in_child
from shared_data import REALDATA

GUIDE_START, GUIDE_FRAMES = 3540, 150  # the benchmark's guide window (fusion_clips.GUIDE), shortened


@pytest.fixture(scope="module")
def followed(tmp_path_factory):
    """(folder, the clip frame index where the guide's first frame was performed)."""
    from facecap.facecap_addon.bench.fusion_bench import HOLD, follow_performance
    from facecap.facecap_addon.render.face_footage import Shot, render_face_clip
    from facecap.solvers.io.csv_write import write_weights_csv

    ict_available()
    landmark_models()
    face = ict_face()
    folder = tmp_path_factory.mktemp("follow")
    weights, head, gaze, guide = follow_performance(REALDATA / "llf" / "llf_alex_rom_3.csv", list(face.shape_names),
                                                    GUIDE_START, GUIDE_FRAMES, seed=3)
    in_child(lambda: render_face_clip(folder / "follow.mp4", face.neutral, face.polygons, face.deltas, weights,
                                      head=head, gaze=gaze, shot=Shot(distance=0.5, azimuth=15.0)),
             label="the guide-following clip")
    write_weights_csv(folder / "guide.csv", np.arange(1, GUIDE_FRAMES + 1), [str(n) for n in guide["guide_names"]],
                      guide["guide"])
    ict_character(folder / "person.blend", face)
    return folder, HOLD + guide["lag_s"] * guide["guide_fps"]


def test_a_clip_that_follows_a_guide_is_placed_stored_and_read_back(followed):
    from facecap.facecap_addon.headless.headless import run_take
    from facecap.solvers.config import load_take_config
    from facecap.solvers.video.response import profile_contents, profile_performer

    folder, performed_at = followed
    take = ('[target]\nblend = "person.blend"\nobject = "ICT"\n[source]\nvideo = "follow.mp4"\n'
            '[tracking]\nmethod = "landmarks"\n')
    config = folder / "follow.toml"
    config.write_text(take + '[calibration]\nguide = "guide.csv"\nguide_fps = 30\n'
                      '[output]\nweights = "follow.csv"\nreport = "follow.json"\nprofile = "performer.npz"\n',
                      encoding="utf-8")
    run_take(load_take_config(config), quiet=True)
    report = json.loads((folder / "follow.json").read_text(encoding="utf-8"))
    followed_ = report["source"]["guide_followed"]
    print(followed_["summary"], "performed at", performed_at)
    assert abs(followed_["offset_frames"] - performed_at) <= 2 and followed_["correlation"] > 0.5
    assert abs(followed_["frames"] - GUIDE_FRAMES) <= 3 and followed_["guide"] == "guide.csv"
    assert report["strategy_info"]["fusion"]["shapes"]  # the take's own scores fused, through the performer's map
    assert profile_contents(folder / "performer.npz") == (False, None)
    assert profile_performer(folder / "performer.npz").guide == "guide.csv"

    later = folder / "later.toml"
    later.write_text(take + '[actor]\nprofile = "performer.npz"\n[output]\nweights = "later.csv"\n'
                     'report = "later.json"\n', encoding="utf-8")
    run_take(load_take_config(later), quiet=True)
    report = json.loads((folder / "later.json").read_text(encoding="utf-8"))
    assert report["source"]["guide_followed"] == {"from": str(folder / "performer.npz"), "guide": "guide.csv",
                                                  "weighs_as_clips": 8.0}
    assert "score_response" not in report["source"]
    np.testing.assert_allclose(np.loadtxt(folder / "later.csv", delimiter=",", skiprows=1),
                               np.loadtxt(folder / "follow.csv", delimiter=",", skiprows=1), atol=1e-9)
