"""Alias tables: Live Link Face, MediaPipe, ARKit raw strings and FACS action units onto ARKit keys."""

from facecap.solvers.character.aliases import canonical_names, match_names, mirror_name
from facecap.solvers.io.arkit import ARKIT_52

# MediaPipe face landmarker blendshape categories (52 = "_neutral" + 51 ARKit names, no tongueOut).
MEDIAPIPE = ("_neutral",) + tuple(n for n in ARKIT_52 if n != "tongueOut")


def test_live_link_face_names_map_onto_every_arkit_key():
    llf = ["Timecode", "BlendShapeCount"] + [n[0].upper() + n[1:] for n in ARKIT_52]
    pairs, unmatched, undriven = match_names(llf, ARKIT_52)
    assert sorted(pairs) == [(i + 2, i) for i in range(52)]
    assert unmatched == [] and undriven == []


def test_mediapipe_names_map_onto_arkit_keys():
    pairs, unmatched, undriven = match_names(MEDIAPIPE, ARKIT_52)
    assert len(pairs) == 51 and all(MEDIAPIPE[i] == ARKIT_52[j] for i, j in pairs)
    assert unmatched == []  # "_neutral" is an ignored channel, not an unmatched one
    assert undriven == ["tongueOut"]


def test_arkit_raw_and_rig_spellings():
    for name in ("eyeBlink_L", "EyeBlinkLeft", "eye_blink_left", "EYEBLINK.L", "eyeBlinkL", "L_eyeBlink"):
        assert canonical_names(name) == ("eyeBlinkLeft",), name
    assert canonical_names("mouthSmile_R") == ("mouthSmileRight",)
    assert canonical_names("jawOpen") == ("jawOpen",)
    assert canonical_names("smile_big") == ()


def test_facs_action_units():
    assert canonical_names("AU45") == ("eyeBlinkLeft", "eyeBlinkRight")
    assert canonical_names("AU26") == ("jawOpen",)
    assert canonical_names("au27") == ("jawOpen",)
    assert canonical_names("AU12L") == ("mouthSmileLeft",)
    assert canonical_names("AU12_R") == ("mouthSmileRight",)
    assert canonical_names("R12") == ("mouthSmileRight",)
    assert canonical_names("AU1") == ("browInnerUp",)
    assert canonical_names("AU4") == ("browDownLeft", "browDownRight")
    assert canonical_names("AU99") == ()


def test_match_names_one_au_drives_both_sides_and_character_spellings():
    character = ("EyeBlink_L", "EyeBlink_R", "JawOpen", "Smile_big")
    pairs, unmatched, undriven = match_names(["AU45", "AU26", "smile_big", "AU9"], character)
    assert sorted(pairs) == [(0, 0), (0, 1), (1, 2), (2, 3)]
    assert unmatched == ["AU9"] and undriven == []
    pairs, _, _ = match_names(["EyeBlinkLeft"], character, aliases=False)
    assert pairs == []


def test_mirror_name():
    assert mirror_name("eyeBlinkLeft") == "eyeBlinkRight"
    assert mirror_name("jawRight") == "jawLeft"
    assert mirror_name("brow_L") == "brow_R"
    assert mirror_name("jawOpen") == "jawOpen"
