"""The benchmark module runs (a smoke test on a short take; timings are printed, never asserted)."""

from facecap.solvers.tools.bench.bench import main, make_take, run_benchmarks


def test_bench_quick_per_frame_case(capsys):
    rows = run_benchmarks(["per-frame"], quick=True)
    assert len(rows) == 1 and rows[0]["frames"] == 3600 and rows[0]["ratio"] > 0
    assert main(["--quick", "--case", "per-frame"]) == 0
    assert "per-frame bounded solve" in capsys.readouterr().out


def test_synthetic_take_shape_and_gaps():
    A, D, W = make_take(600, 52, 80)
    assert A.shape == (240, 52) and D.shape == (600, 240) and W.shape == (600, 52)
    gaps = (D != D).mean()
    assert 0.01 < gaps < 0.1
    assert (W == 0).mean() > 0.5 and W.max() <= 1.0
