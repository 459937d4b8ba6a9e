"""Issue 4 on the sample take and synthetic ground truth: auto stable set, neutral sources, master
T-pose normalisation, similarity / 2D stabilisation, actor -> character alignment."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facecap.solvers import Basis, FacecapError, MarkerSet, load_take_config, read_markers_csv, retarget
from facecap.solvers.capture.align import align_actor, region_patterns
from facecap.solvers.io.csv import read_weights_csv
from facecap.solvers.capture.normalise import detect_neutral_frames, master_offsets, neutral_from_ranges
from facecap.solvers.capture.stabilise import stabilise_2d, stabilise_rigid
from facecap.solvers.capture.stable_markers import suggest_stable_markers

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"


@pytest.fixture(scope="module")
def sample():
    config = load_take_config(SAMPLES / "sample_take.toml")
    basis = Basis.load_npz(SAMPLES / "character_basis.npz")
    _, _, truth = read_weights_csv(SAMPLES / "sample_take_weights.csv")
    markers = read_markers_csv(config.markers_path, units=config.units, fps=config.fps)
    return config, basis, truth, markers


def accuracy(weights, truth):
    err = weights - truth
    return float(np.sqrt(np.mean(err**2))), float(np.abs(err).max())


def settings(config, **changes):
    return dataclasses.replace(config.settings, **changes)


def test_auto_stable_markers_pick_only_head_markers_and_solve_accurately(sample):
    config, basis, truth, markers = sample
    s = suggest_stable_markers(markers)
    print(f"auto stable: {s.names}, gap x{s.gap:.2f}, noise {s.noise_mm:.3f} mm")
    assert len(s.names) >= 3 and all(n.startswith("head_") for n in s.names)
    assert s.clear and s.gap >= 2.0
    assert max(s.scores[n] for n in s.names) < min(v for n, v in s.scores.items() if n not in s.names)
    r = retarget(markers, basis, settings(config, stable_markers=(), auto_stable=True))
    rmse, worst = accuracy(r.weights, truth)
    print(f"auto stable retarget: RMSE {rmse:.4f}, max {worst:.4f}")
    assert rmse <= 0.03 and worst <= 0.2
    assert r.report()["stabilise"]["suggested"]["markers"] == list(s.names)


def test_a_marker_never_seen_does_not_leak_numpy_warnings_from_the_stable_search(sample):
    """A take with a marker missing in every frame (a label nothing wore) printed numpy's
    'Mean of empty slice' RuntimeWarning on the user's console."""
    import warnings

    _, _, _, markers = sample
    pos = markers.positions.copy()
    pos[:, markers.index(["lip_upper_C"])[0]] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = suggest_stable_markers(markers.with_positions(pos))
    assert all(n.startswith("head_") for n in s.names) and "lip_upper_C" not in s.names


def test_neutral_from_several_ranges_and_detected(sample):
    config, basis, truth, markers = sample
    last = int(markers.frames[-1])
    r = retarget(markers, basis, settings(config, neutral_ranges=((1, 50), (last - 49, last))))
    rmse, worst = accuracy(r.weights, truth)
    print(f"start+end T-pose neutral: RMSE {rmse:.4f}, max {worst:.4f}")
    assert rmse <= 0.03 and worst <= 0.2
    assert r.report()["neutral"]["ranges"] == [[1, 50], [last - 49, last]]

    d = retarget(markers, basis, settings(config, neutral_detect=True, neutral_frames=(1, 1)))
    frames = np.array(d.normalise["frames"])
    rows = np.isin(markers.frames, frames)
    print(f"detected {frames.size} neutral frames; max true weight there {truth[rows].max():.3f}")
    true = np.linalg.norm(np.einsum("fk,kmd->fmd", truth[rows], basis.deltas), axis=2)
    assert true.max() <= 0.5e-3  # the detected frames really are (near) rest: < 0.5 mm anywhere
    rmse, worst = accuracy(d.weights, truth)
    print(f"detected neutral: RMSE {rmse:.4f}, max {worst:.4f}")
    assert rmse <= 0.03 and worst <= 0.2


def test_neutral_from_a_separate_file(sample, tmp_path):
    config, basis, truth, markers = sample
    tpose = markers.to_units("m")
    sel = tpose.frame_range_mask(1, 50)
    # the neutral file is the T-pose captured on its own, in another head pose
    R = Rotation.from_euler("xyz", [5, -10, 3], degrees=True).as_matrix()
    pos = tpose.positions[sel] @ R.T + np.array([0.01, -0.02, 0.03])
    neutral = MarkerSet(tpose.names, np.arange(1, sel.sum() + 1), pos, fps=60, units="m", source="neutral.csv")
    r = retarget(markers, basis, settings(config, neutral_file=neutral))
    rmse, worst = accuracy(r.weights, truth)
    print(f"neutral from a file: RMSE {rmse:.4f}, max {worst:.4f}")
    assert rmse <= 0.03 and worst <= 0.2 and r.normalise["source"] == "file"
    with pytest.raises(FacecapError, match="has no marker"):
        retarget(markers, basis, settings(config, neutral_file=neutral.with_positions(pos[:, :-1], names=neutral.names[:-1])))


def _shift_placement(markers, stab, shifts):
    """Markers placed ``shifts`` (M, 3, head frame) away from where they were, carried by the head motion."""
    Rh = stab.head_rotations()
    return markers.with_positions(markers.positions + np.einsum("fij,mj->fmi", Rh, shifts))


def test_master_tpose_normalisation_cancels_marker_placement_shifts(sample):
    config, basis, truth, markers = sample
    m = markers.to_units("m")
    base = retarget(m, basis, config.settings)
    master = m.with_positions(m.positions[m.frame_range_mask(1, 50)], frames=np.arange(1, 51))
    rng = np.random.default_rng(4)
    direction = rng.normal(size=(m.n_markers, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    shifts = direction * rng.uniform(1e-3, 3e-3, size=(m.n_markers, 1))
    stable = [m.names.index(n) for n in config.settings.stable_markers]
    shifts[stable] = 0.0  # the head markers sit on the head rig
    day2 = _shift_placement(m, base.stabilise, shifts)
    r = retarget(day2, basis, settings(config, master=master))
    rmse, worst = accuracy(r.weights, base.weights)
    print(f"1-3 mm placement shifts, master T-pose: vs unshifted RMSE {rmse:.4f}, max {worst:.4f}; "
          f"vs truth {accuracy(r.weights, truth)}")
    assert rmse <= 0.03 and worst <= 0.2
    rep = r.report()["neutral"]["master"]
    assert set(rep["landmarks"]) >= {"eye_outer_L", "eye_outer_R", "mouth_corner_L", "mouth_corner_R"}
    # the alignment onto the character is the master's, not the shifted day's
    assert r.alignment.scale == pytest.approx(base.alignment.scale, rel=2e-3)


def test_master_offsets_interpolate_between_start_and_end_tposes_and_cancel_slip(sample):
    config, basis, truth, markers = sample
    m = markers.to_units("m")
    base = retarget(m, basis, config.settings)
    last = int(m.frames[-1])
    master = m.with_positions(m.positions[m.frame_range_mask(1, 50)], frames=np.arange(1, 51))
    # a cheek marker slides 3 mm over the take (head frame), linearly
    slip = np.zeros((m.n_frames, m.n_markers, 3))
    i = m.names.index("cheek_L")
    slip[:, i, 1] = np.linspace(0, 3e-3, m.n_frames)
    Rh = base.stabilise.head_rotations()
    slid = m.with_positions(m.positions + np.einsum("fij,fmj->fmi", Rh, slip))
    ranges = ((1, 50), (last - 49, last))
    plain = retarget(slid, basis, settings(config, neutral_ranges=ranges))
    fixed = retarget(slid, basis, settings(config, neutral_ranges=ranges, master=master))
    e_plain, e_fixed = accuracy(plain.weights, truth)[0], accuracy(fixed.weights, truth)[0]
    print(f"3 mm slow slip: RMSE without master {e_plain:.4f}, with start/end master offsets {e_fixed:.4f}")
    assert e_fixed < e_plain and e_fixed <= 0.03
    slip_mm = fixed.report()["neutral"]["master"]["slip_mm"]
    assert slip_mm["cheek_L"] == pytest.approx(3.0 * (last - 25 - 25.5) / (last - 1), abs=0.4)


def test_master_needs_landmarks(sample):
    config, basis, _, markers = sample
    m = markers.to_units("m")
    st = stabilise_rigid(m, config.settings.stable_markers, reference_frames=(1, 50))
    with pytest.raises(FacecapError, match="landmarks"):
        master_offsets(st.markers, m, ((1, 50),), landmarks=("nothing*",))


@pytest.mark.parametrize("scale", [0.8, 1.0, 1.3])
def test_actor_scale_is_recovered(sample, scale):
    _, basis, _, _ = sample
    names = basis.marker_names
    R = Rotation.from_euler("xyz", [10, 20, -5], degrees=True).as_matrix()
    actor = (basis.neutral @ R.T) / scale + np.array([0.1, 0.0, -0.2])
    a = align_actor(actor, basis.neutral, names)
    assert a.scale == pytest.approx(scale, rel=5e-3)
    assert not a.flagged and a.residual.max() < 1e-9


def test_regional_alignment_has_separate_scales_and_flags_bad_bindings(sample):
    _, basis, _, _ = sample
    names = basis.marker_names
    regions = region_patterns(True)
    upper = {names[i] for i in align_actor(basis.neutral, basis.neutral, names, regions=regions).regions["upper"][1]}
    actor = basis.neutral.copy()
    centre = actor.mean(axis=0)
    for i, n in enumerate(names):
        actor[i] = centre + (actor[i] - centre) / (1.1 if n in upper else 0.9)
    a = align_actor(actor, basis.neutral, names, regions=regions)
    assert a.regions["upper"][0].scale == pytest.approx(1.1, rel=5e-3)
    assert a.regions["lower"][0].scale == pytest.approx(0.9, rel=5e-3)
    bad = basis.neutral.copy()
    bad[names.index("chin_C")] += np.array([0.0, 0.0, 0.012])
    flagged = align_actor(bad, basis.neutral, names).flagged
    assert flagged == ("chin_C",)


def test_similarity_stabilisation_recovers_a_changing_scale():
    rng = np.random.default_rng(3)
    ref = rng.normal(scale=0.05, size=(8, 3))
    F = 40
    R = Rotation.from_rotvec(rng.normal(scale=0.2, size=(F, 3))).as_matrix()
    R[0] = np.eye(3)
    s = np.linspace(1.0, 1.2, F)
    shift = rng.normal(scale=0.01, size=(F, 1, 3))
    shift[0] = 0
    pos = s[:, None, None] * np.einsum("fij,mj->fmi", R, ref) + shift
    markers = MarkerSet(tuple(f"h{i}" for i in range(8)), np.arange(1, F + 1), pos)
    st = stabilise_rigid(markers, markers.names, reference_frames=(1, 1), mode="similarity")
    np.testing.assert_allclose(st.scales, 1 / s, rtol=1e-9)
    np.testing.assert_allclose(st.markers.positions, np.broadcast_to(ref, pos.shape), atol=1e-12)
    with pytest.raises(FacecapError, match="mode must be"):
        stabilise_rigid(markers, markers.names, mode="affine")


@pytest.mark.parametrize("mode", ["similarity", "affine"])
def test_2d_stabilisation(mode):
    rng = np.random.default_rng(5)
    ref = rng.uniform(0, 100, size=(6, 2))
    F = 30
    A = np.empty((F, 2, 2))
    for f in range(F):
        th, k = rng.normal(scale=0.2), rng.uniform(0.8, 1.2)
        A[f] = k * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        if mode == "affine":
            A[f] = A[f] @ np.array([[1.0, rng.normal(scale=0.1)], [0.0, rng.uniform(0.9, 1.1)]])
    A[0] = np.eye(2)
    shift = rng.normal(scale=5, size=(F, 1, 2))
    shift[0] = 0
    pos = np.einsum("fij,mj->fmi", A, ref) + shift
    pos[7, :] = np.nan  # a frame with nothing visible
    markers = MarkerSet(tuple(f"p{i}" for i in range(6)), np.arange(1, F + 1), pos)
    st = stabilise_rigid(markers, ["p0", "p1", "p2", "p3"], reference_frames=(1, 1), mode=mode)
    ok = ~st.flagged
    np.testing.assert_allclose(st.markers.positions[ok], np.broadcast_to(ref, pos[ok].shape), atol=1e-9)
    assert st.flagged.tolist() == [f == 7 for f in range(F)] and "only 0 of 4" in st.flag_reasons[8]
    with pytest.raises(FacecapError, match="need at least"):
        stabilise_2d(markers, ["p0", "p1"], mode="affine")


def test_all_missing_frames_are_flagged_not_guessed():
    rng = np.random.default_rng(0)
    ref = rng.normal(scale=0.05, size=(5, 3))
    pos = np.broadcast_to(ref, (10, 5, 3)).copy()
    pos[4] = np.nan
    st = stabilise_rigid(MarkerSet(tuple("abcde"), np.arange(1, 11), pos), list("abcde"))
    assert st.flagged.tolist() == [f == 4 for f in range(10)]
    assert "only 0 of 5" in st.flag_reasons[5] and np.isnan(st.markers.positions[4]).all()


def test_detect_neutral_frames_on_a_synthetic_take():
    rng = np.random.default_rng(1)
    rest = rng.normal(scale=0.05, size=(10, 3))
    F = 150
    act = 0.3 + np.abs(np.sin(np.arange(F) / 7.0))
    act[40:70] = 0.0
    pos = rest + act[:, None, None] * rng.normal(scale=0.004, size=(10, 3)) + rng.normal(scale=1e-4, size=(F, 10, 3))
    m = MarkerSet(tuple(f"m{i}" for i in range(10)), np.arange(1, F + 1), pos)
    frames, dev = detect_neutral_frames(m, count=8)
    assert set(frames) <= set(range(41, 71))
    np.testing.assert_allclose(neutral_from_ranges(m, [(41, 45), (46, 50)]), np.median(pos[40:50], axis=0))


def _config(tmp_path, stabilise, neutral, extra=""):
    (tmp_path / "take.csv").write_text("frame,a_x,a_y,a_z\n1,0,0,0\n")
    (tmp_path / "master.csv").write_text("frame,a_x,a_y,a_z\n1,0,0,0\n")
    path = tmp_path / "take.toml"
    path.write_text(f'[target]\nobject = "Face"\n[source]\nmarkers = "take.csv"\n[stabilise]\n{stabilise}\n'
                    f'[neutral]\n{neutral}\n{extra}')
    return load_take_config(path)


def test_config_keys_for_stabilisation_neutral_master_align_and_head(tmp_path):
    from facecap.solvers import ConfigError

    cfg = _config(tmp_path, 'markers = "auto"\nmode = "similarity"',
                  'frames = [[1, 30], [571, 600]]\nmaster = "master.csv"\nlandmarks = ["eye*", "mouth_corner*", "x"]',
                  '[align]\nregions = true\nflag_mm = 4\n[output]\nhead = "Rig:head"\n')
    s = cfg.settings
    assert s.auto_stable and s.stable_markers == () and s.stabilise_mode == "similarity"
    assert s.neutral_ranges == ((1, 30), (571, 600)) and s.neutral_frames == (1, 30)
    assert s.master == str(tmp_path / "master.csv") and s.landmarks == ("eye*", "mouth_corner*", "x")
    assert [name for name, _ in s.align_regions] == ["upper", "lower"] and s.align_flag_mm == 4.0
    assert s.head_target == "Rig:head"
    d = _config(tmp_path, 'markers = ["a", "b", "c"]', "detect = true").settings
    assert d.neutral_detect
    f = _config(tmp_path, 'markers = ["a", "b", "c"]', 'file = "master.csv"').settings
    assert f.neutral_file == str(tmp_path / "master.csv")
    r = _config(tmp_path, 'markers = ["a", "b", "c"]', "frames = [1, 30]", '[align]\nregions = {mouth = ["lip*"]}\n')
    assert r.settings.align_regions == (("mouth", ("lip*",)),)
    for stabilise, neutral, key in [
        ('markers = "all"', "frames = [1, 30]", "stabilise.markers"),
        ('markers = ["a", "b", "c"]\nmode = "affine"', "frames = [1, 30]", "stabilise.mode"),
        ('markers = ["a", "b", "c"]', "frames = [[1, 30], [5]]", "neutral.frames"),
        ('markers = ["a", "b", "c"]', 'file = "nope.csv"', "neutral.file"),
        ('markers = ["a", "b", "c"]', "detect = true\nframes = [1, 2]", "neutral.detect"),
        ('markers = ["a", "b", "c"]', 'detect = true\nmaster = "master.csv"', "neutral.frames"),
        ('markers = ["a", "b", "c"]', "", "neutral.frames"),
    ]:
        with pytest.raises(ConfigError, match=rf"\[{key}\]"):
            _config(tmp_path, stabilise, neutral)
