"""Benchmark: the review page of a take against the naive page (plotly's own ``write_html`` of every frame).

    .venv/bin/python tests/core/bench_review_page.py [--frames 36000] [--repeat 5] [--result solved.pkl]

Prints the median time and the size of both pages, and their ratios. The take is ``review_takes``'s
fabricated result (a solve's sizes and noise) unless ``--result`` names a pickled (RetargetResult,
truth weights, shape names) of a real solve. Times are medians: the machine is shared.
"""

import argparse
import pickle
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import plotly.graph_objects as go

sys.path.insert(0, str(Path(__file__).resolve().parent))
from review_takes import fabricated_result  # noqa: E402

from facecap.solvers.tools.report import Review, Truth, head_motion, write_review_page  # noqa: E402


def naive_page(path, result, truth):
    """Every frame of every curve, as plotly.py writes it: the baseline."""
    f = result.frames
    figs = [go.Figure([go.Scatter(x=f, y=result.weights[:, k], name=n) for k, n in enumerate(result.shape_names)]
                      + [go.Scatter(x=f, y=truth[:, k], name=f"{n} truth") for k, n in enumerate(result.shape_names)]),
            go.Figure([go.Scatter(x=f, y=result.residual_rms * 1e3)]),
            go.Figure([go.Heatmap(z=result.frame_marker_residual.T * 1e3, x=f)])]
    head = head_motion(result.stabilise)
    figs.append(go.Figure([go.Scatter(x=f, y=head["rotation"][:, i]) for i in range(3)]))
    html = "".join(fig.to_html(full_html=False, include_plotlyjs=(i == 0)) for i, fig in enumerate(figs))
    Path(path).write_text(f"<html><body>{html}</body></html>", encoding="utf-8")


def median_run(fn, repeat):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=36_000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--result", default=None, help="pickled (RetargetResult, truth, names) of a real solve")
    args = parser.parse_args(argv)
    if args.result:
        with open(args.result, "rb") as fh:
            result, truth, names = pickle.load(fh)
        what = f"real solve from {args.result}"
    else:
        result, truth = fabricated_result(args.frames)
        names, what = result.shape_names, "fabricated solve"
    review = Review(result=result, take="bench", fps=60.0, truth=Truth(result.frames, tuple(names), truth))
    F, K = result.weights.shape
    with tempfile.TemporaryDirectory() as tmp:
        page, naive = Path(tmp) / "review.html", Path(tmp) / "naive.html"
        t_page = median_run(lambda: write_review_page(page, review), args.repeat)
        t_naive = median_run(lambda: naive_page(naive, result, truth), max(1, args.repeat // 2))
        s_page, s_naive = page.stat().st_size, naive.stat().st_size
    print(f"review page, {F} frames x {K} shapes x {len(result.marker_names)} markers + truth ({what}):")
    print(f"  facecap page: {t_page:.2f} s median, {s_page / 1e6:.2f} MB (plotly.js embedded: 4.8 MB of it)")
    print(f"  naive page (plotly write_html, every frame): {t_naive:.2f} s median, {s_naive / 1e6:.1f} MB")
    print(f"  ratios: {t_naive / t_page:.1f}x faster, {s_naive / s_page:.1f}x smaller")
    return 0


if __name__ == "__main__":
    sys.exit(main())
