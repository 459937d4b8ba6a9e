"""The strategy comparison table: every strategy runs on the same synthetic takes."""

from facecap.solvers.tools import compare


def test_main_prints_a_markdown_row_per_strategy(capsys):
    assert compare.main(["--frames", "300", "--examples", "30"]) == 0
    out = capsys.readouterr().out
    assert "| strategy | weights RMSE | max error | fit time (s) | solve time (s) |" in out
    rows = [line for line in out.splitlines() if line.startswith("| ") and "strategy |" not in line]
    names = [r.split("|")[1].strip() for r in rows]
    assert names == ["geometric", "calibrated", "refine", "linear", "rbf", "pca (related)", "pca (posed)", "parallel"]
    for row in rows:
        rmse = float(row.split("|")[2])
        assert 0.0 <= rmse < 0.5
