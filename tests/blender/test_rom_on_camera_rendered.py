"""The performer's ROM on camera from rendered footage: the ICT face performs a short sheet imperfectly in front of
the camera, the headless landmark take finds and names its poses in the blendshape scores (checked against the
rendered truth) and writes the response into the performer profile."""

import json

import numpy as np
import pytest

from face_clips import ict_available, ict_character, ict_face, landmark_models
from render_child import in_child

#: A short sheet of poses the camera sees well, as a config writes it (labels where a pose is a combination).
SHEET = ['"jawOpen"', '{ mouthSmileLeft = 1.0, mouthSmileRight = 1.0, label = "smile" }',
         '{ eyeBlinkLeft = 1.0, eyeBlinkRight = 1.0, label = "eyes shut" }', '"browInnerUp"', '"mouthPucker"',
         '{ mouthFrownLeft = 1.0, mouthFrownRight = 1.0, label = "frown" }']
FPS = 24.0


@pytest.fixture(scope="module")
def rom_clip(tmp_path_factory):
    """(folder, the session's holds (H, 2) frame numbers, the poses performed) of a rendered ROM clip."""
    import tomllib

    from facecap.facecap_addon.bench.fusion_bench import ROM_TIMING, _head_and_gaze
    from facecap.facecap_addon.render.face_footage import Shot, render_face_clip
    from facecap.solvers.rom import sequence_poses
    from facecap.solvers.tools.synthetic.realism.rom import rom_weights

    ict_available()
    landmark_models()
    face = ict_face()
    folder = tmp_path_factory.mktemp("rom_on_camera")
    poses = sequence_poses(tomllib.loads("s = [" + ", ".join(SHEET) + "]")["s"])
    rng = np.random.default_rng(12)
    names = list(face.shape_names)
    weights, performed, holds, _ = rom_weights(names, poses, rng, fps=FPS, timing=ROM_TIMING)
    head, gaze = _head_and_gaze(weights, names, rng, FPS)
    in_child(lambda: render_face_clip(folder / "rom.mp4", face.neutral, face.polygons, face.deltas, weights, head=head,
                                      gaze=gaze, shot=Shot(distance=0.5, azimuth=15.0, fps=FPS)), label="the ROM clip")
    ict_character(folder / "person.blend", face)
    return folder, holds, [poses[j].label for j in performed]


def test_a_filmed_rom_is_found_named_and_stored_as_the_performers_response(rom_clip):
    from facecap.facecap_addon.headless.headless import run_take
    from facecap.solvers.config import load_take_config
    from facecap.solvers.video.response import profile_contents

    folder, holds, labels = rom_clip
    config = folder / "rom.toml"
    config.write_text('[target]\nblend = "person.blend"\nobject = "ICT"\n[source]\nvideo = "rom.mp4"\n'
                      '[tracking]\nmethod = "landmarks"\n[calibration]\nsequence = [' + ", ".join(SHEET) + ']\n'
                      '[output]\nweights = "rom.csv"\nreport = "rom.json"\nprofile = "performer.npz"\n',
                      encoding="utf-8")
    run_take(load_take_config(config), quiet=True)
    report = json.loads((folder / "rom.json").read_text(encoding="utf-8"))["source"]["score_response"]
    print(report["summary"], report["notes"])
    where = {p["label"]: p["frames"] for p in report["poses"]}
    truth = {label: 0.5 * (h[0] + h[1]) - 1 for label, h in zip(labels, holds)}  # as frame indices
    near = [label for label in labels if where[label] is not None and abs(0.5 * sum(where[label]) - truth[label]) <= 5]
    print({label: (where[label], truth[label]) for label in labels})
    assert len(near) >= len(labels) - 1, (near, where, truth)  # every pose but at most one, none misplaced
    assert all(where[label] is None or label in near for label in labels), where
    shapes, response = profile_contents(folder / "performer.npz")
    assert not shapes and response is not None and "jawOpen" in response.changed()
