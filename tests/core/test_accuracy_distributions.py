"""Issue 21: right on takes nobody tuned for. Auto stable markers and LK tracking judged on the median
and the worst case over many seeded random draws (solvers.tools.synthetic.scenarios*), side by side with the true
rigid set and with a plain pyramidal LK (solvers/tools/bench/reference_trackers.py)."""

import numpy as np
import pytest

from facecap.solvers import FacecapError
from facecap.solvers.capture.stable_markers import suggest_stable_markers
from facecap.solvers.pipeline import RetargetSettings, retarget
from facecap.solvers.tools.bench.accuracy_bench import stable_rows, summary
from facecap.solvers.tools.synthetic.scenarios import marker_scenario

DRAWS = range(30)


@pytest.fixture(scope="module")
def stable():
    return stable_rows(DRAWS, n_frames=240)


def test_auto_stable_set_is_as_good_as_the_true_rigid_set_over_30_random_takes(stable):
    ratios = [r["ratio"] for r in stable]
    med, p90, worst = summary(ratios)
    declined = [r for r in stable if not np.isfinite(r["ratio"])]
    print(f"auto / true rigid set weights RMSE over {len(stable)} draws: median {med:.3f}x, p90 {p90:.3f}x, "
          f"worst {worst:.3f}x; declined {len(declined)}")
    assert med <= 1.15 and worst <= 1.5
    assert len(declined) <= 2  # "auto" may decline (naming candidates) on a few hard takes, never silently fail
    for r in declined:
        assert "best candidates" in r["declined"] and not r["ok"]
    kinds = {r["params"]["coverage"] for r in stable}
    assert kinds == {"full", "lower_mid", "lower"}  # upper face rigid in some draws, moving in others
    assert any(r["params"]["head_markers"] == 0 for r in stable) and any(r["params"]["long_gaps"] for r in stable)


def test_auto_stable_report_has_per_marker_scores_visibility_and_conditioning():
    s = marker_scenario(3, n_frames=200)
    sug = suggest_stable_markers(s.markers, reference_frames=s.neutral_frames)
    rep = sug.report()
    assert rep["ok"] and rep["markers"] == list(sug.names) and len(rep["per_marker"]) == s.markers.n_markers
    chosen = rep["per_marker"][sug.names[0]]
    assert {"score", "visible", "residual_mm"} <= set(chosen) and 0 < chosen["visible"] <= 1
    c = rep["conditioning"]
    assert c["frames_below_3"] == 0 and c["face_error_mm"] > 0 and 0 < c["isotropy"] <= 1
    assert c["residual_ratio"] < 1.5


def test_no_rigid_markers_says_so_and_names_candidates():
    s = marker_scenario(5, n_frames=200, with_head=False, coverage="full")
    rng = np.random.default_rng(0)
    F, M, _ = s.markers.positions.shape
    # every marker slides on its own (2-3 mm, smooth): no set moves with the head alone
    t = np.arange(F)[:, None, None]
    slide = 2.5 * np.sin(2 * np.pi * t / rng.uniform(40, 90, (1, M, 3)) + rng.uniform(0, 6.3, (1, M, 3)))
    markers = s.markers.with_positions(s.markers.positions + slide)
    sug = suggest_stable_markers(markers)
    assert not sug.ok and sug.problems and len(sug.candidates) >= 3
    assert "best candidates" in sug.message()
    with pytest.raises(FacecapError, match=r'markers = "auto": no reliable stable set .* best candidates'):
        retarget(markers, s.character.basis, RetargetSettings((), s.neutral_frames, auto_stable=True))


# -- tracking: the project's LK beside the plain reference on every footage kind --------------------------
def kinds_here():
    """Every footage kind, but the photographed ones where the photographs are missing: they ship in the bpy
    wheel, which the README's test command installs (there every kind runs) and CI's core tests on the
    second Python do not (the core never needs Blender)."""
    import importlib.util

    from facecap.solvers.tools.synthetic.scenarios_footage import KINDS, photograph_files

    try:
        photograph_files()
    except FileNotFoundError:
        assert importlib.util.find_spec("bpy") is None  # with bpy installed the photographs must be found
        print("no bpy wheel here: the photographed footage kinds are left to the run with bpy")
        return [k for k, spec in KINDS.items() if spec["texture"] != "photo"]
    return list(KINDS)


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    pytest.importorskip("cv2")
    from facecap.solvers.tools.synthetic.scenarios_footage import footage_scenario

    d = tmp_path_factory.mktemp("kinds")
    # every kind x 3 draws, small so the suite stays quick (the benchmark has 480p-1080p)
    return [footage_scenario(seed, kind, d, size=(320, 240), n_frames=30) for kind in kinds_here()
            for seed in range(3)]


@pytest.fixture(scope="module")
def tracks(clips):
    from facecap.solvers.tools.bench.accuracy_bench import track_row

    return [track_row(sc, max_points=32) for sc in clips]  # against the textbook LK (reference_trackers)


def test_tracker_matches_or_beats_plain_lk_on_every_footage_kind(tracks):
    from facecap.solvers.tools.synthetic.scenarios_footage import UNTUNED

    kinds = kinds_here()
    assert len(tracks) >= 3 * len(kinds)
    for kind in kinds:
        k = [r for r in tracks if r["kind"] == kind]
        ours, plain = np.median([r["ours_median_px"] for r in k]), np.median([r["plain_median_px"] for r in k])
        lost_ours = np.mean([r["ours_lost_pct"] for r in k])
        lost_plain = np.mean([r["plain_lost_pct"] for r in k])
        print(f"{kind:18s} median error ours {ours:.3f} px, plain LK {plain:.3f} px; lost ours {lost_ours:.2f}%, "
              f"plain {lost_plain:.2f}%; worst draw ours {max(r['ours_median_px'] for r in k):.3f} px")
        if kind in UNTUNED:  # footage nobody tuned for: within 0.02 px of the reference (the bar)
            assert ours <= plain + 0.02, kind  # measured: photographs in VP8 0.113 against 0.111 px
        else:
            assert ours <= plain, kind  # at or below the reference on every kind (measured 2-91 % below)
        # the worst draw: no blow-up (one rich MJPG draw is 5 % above the plain LK's worst: 0.124 vs 0.117 px)
        assert max(r["ours_median_px"] for r in k) <= 1.1 * max(r["plain_median_px"] for r in k), kind
        assert lost_ours <= max(1.0, lost_plain), kind  # false losses: at most 1 % where the reference keeps all
        assert lost_ours <= 0.5, kind  # every kind, the ones the generator does not make included
        assert sum(r["ours_wrong_hidden"] for r in k) <= sum(r["plain_wrong_hidden"] for r in k), kind


def test_dense_flow_matches_or_beats_plain_dis_on_every_footage_kind(clips):
    from facecap.solvers.tools.bench.accuracy_bench import flow_row

    rows = [flow_row(sc, grid_step=4) for sc in clips if sc.seed == 0]  # one per kind: time
    for kind in kinds_here():
        k = [r for r in rows if r["kind"] == kind]
        ours, plain = np.median([r["ours_median_px"] for r in k]), np.median([r["plain_median_px"] for r in k])
        print(f"{kind:18s} flow end-point error on the face: ours {ours:.4f} px, plain DIS {plain:.4f} px")
        assert ours <= plain * 1.01 + 1e-3, kind
