"""Live Link Face timing: timecodes are times of day (~1.4 million frames), compared in frames with
an absolute tolerance; irregular rows are interpolated linearly; long dropouts become gaps."""

import numpy as np
import pytest

from facecap.solvers.io import read_weights
from facecap.solvers.io.timing import MAX_BRIDGE, resample


def write_llf(path, seconds, values, rate=60.0):
    """A Live Link Face CSV with one row per time in ``seconds`` (time of day) and 2 shape columns."""
    rows = []
    for t, (a, b) in zip(seconds, values):
        h, rest = divmod(t, 3600)
        m, rest = divmod(rest, 60)
        s, frac = divmod(rest, 1)
        rows.append(f"{int(h):02d}:{int(m):02d}:{int(s):02d}:{frac * rate:07.4f},61,{a:.10f},{b:.10f}")
    path.write_text("Timecode,BlendShapeCount,EyeBlinkLeft,JawOpen\n" + "\n".join(rows) + "\n")


def reference(t, values, tq):
    """Linear interpolation of the raw rows at ``tq``; NaN between rows more than MAX_BRIDGE frames apart."""
    ref = np.stack([np.interp(tq, t, values[:, j]) for j in range(values.shape[1])], axis=1)
    hi = np.clip(np.searchsorted(t, tq - 1e-9), 1, len(t) - 1)
    wide = (t[hi] - t[hi - 1]) * 30 > MAX_BRIDGE
    inside = (tq > t[hi - 1] + 1e-9) & (tq < t[hi] - 1e-9)
    ref[wide & inside] = np.nan
    return ref


@pytest.mark.parametrize("seed", range(5))
def test_drifting_rows_with_dropouts_match_linear_interpolation(tmp_path, seed):
    rng = np.random.default_rng(seed)
    n = 400
    step = (1 + rng.uniform(-2e-4, 2e-4)) / 30  # the phone clock drifts against the timecode (measured: 1.7e-4)
    t = 13 * 3600 + 13 * 60 + 4.5 + np.arange(n) * step + rng.uniform(-2e-5, 2e-5, n)  # jitter: 20 us
    keep = np.ones(n, bool)
    short = rng.choice(np.arange(20, 150), size=4, replace=False)
    keep[short] = False  # single missing rows: interpolated
    long_at = int(rng.integers(200, 350))
    keep[long_at:long_at + 5] = False  # a 6-frame hole: a gap
    t = t[keep]
    values = np.stack([np.sin(np.arange(n) / 7.0), np.linspace(0, 1, n)], axis=1)[keep]
    write_llf(tmp_path / "take.csv", t, values)
    track = read_weights(tmp_path / "take.csv")
    assert track.fps == 30.0 and track.frames[0] == 1.0
    tc = np.array([_seconds(line.split(",")[0]) for line in (tmp_path / "take.csv").read_text().splitlines()[1:]])
    tq = tc[0] + (track.frames - 1) / track.fps
    ref = reference(tc, values, tq)
    assert np.array_equal(np.isnan(track.values), np.isnan(ref))
    assert np.nanmax(np.abs(track.values - ref)) < 1e-9
    holes = int(np.isnan(track.values[:, 0]).sum())
    assert 4 <= holes <= 6
    assert any(f"{holes} frame(s) in dropouts longer than 2.5 frames left as gaps" in note for note in track.notes)


def _seconds(tc, rate=60.0):
    h, m, s, f = tc.split(":")
    return int(h) * 3600 + int(m) * 60 + int(s) + float(f) / rate


def test_resample_interpolates_at_times_of_day():
    """The old relative tolerance made every frame within ~14 frames of a sample 'exact' at 1.4 M frames."""
    fps = 30.0
    t0 = 47_584.0  # 13:13:04 in seconds: 1.43 million frames
    times = t0 + np.array([0.0, 1.5, 2.5, 3.5]) / fps
    values = np.array([[[0.0]], [[1.5]], [[2.5]], [[3.5]]])
    frames, out = resample(times, values, fps)
    np.testing.assert_allclose(frames - frames[0], [0, 1, 2, 3])
    np.testing.assert_allclose(out[:, 0, 0], [0.0, 1.0, 2.0, 3.0], atol=1e-9)
