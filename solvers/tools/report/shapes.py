"""The review page's per-shape view: one small plot per shape (small multiples), every shape on the same
0-1 scale and the same time axis, most active first, or worst first when the take's true weights are
known. Plain HTML and SVG, so fifty of them cost the page nothing to draw; clicking one shows that
shape alone in the weights plot.
"""

import numpy as np

from .blob import envelope
from .sections import esc

#: Size of one small plot (pixels) and the most buckets its min/max envelope keeps.
SMALL_W, SMALL_H, SMALL_BUCKETS = 150, 44, 75


def _polyline(frames, values, lo, hi, top):
    """SVG polyline runs of ``values`` over ``frames`` scaled into the small plot (gaps break the line)."""
    xs, ys = envelope(frames, values, SMALL_BUCKETS)
    span = max(hi - lo, 1e-9)
    runs, run = [], []
    for x, y in zip(xs, ys):
        if np.isfinite(y):
            px = 2 + (x - lo) / span * (SMALL_W - 4)
            py = SMALL_H - 2 - min(max(y, 0.0), top) / top * (SMALL_H - 4)
            run.append(f"{px:.1f},{py:.1f}")
        elif run:
            runs.append(run)
            run = []
    if run:
        runs.append(run)
    return [r for r in runs if len(r) > 1]


def shape_order(weights, truth=None):
    """Indices of the shapes, worst first against ``truth`` (RMSE over its finite cells) when given,
    else the most active first (peak weight)."""
    if truth is not None:
        err = np.where(np.isfinite(truth) & np.isfinite(weights), weights - truth, np.nan)
        with np.errstate(invalid="ignore"):
            score = np.sqrt(np.nanmean(err ** 2, axis=0)) if np.isfinite(err).any() else np.zeros(weights.shape[1])
    else:
        score = np.nanmax(np.where(np.isfinite(weights), weights, -np.inf), axis=0) if weights.size else []
    score = np.nan_to_num(np.asarray(score, dtype=np.float64), nan=-np.inf)
    return [int(k) for k in np.argsort(-score, kind="stable")]


def shapes_html(review):
    """The per-shape section's body: a grid of small plots, one per shape."""
    result = review.result
    weights = np.asarray(result.weights, dtype=np.float64)
    if not weights.size:
        return '<p class="note">No weights to show.</p>'
    frames = np.asarray(result.frames, dtype=np.float64)
    truth = review.truth_values
    lo, hi = float(frames[0]), float(frames[-1])
    top = max(1.0, float(np.nanmax(weights)) if np.isfinite(weights).any() else 1.0)
    order = shape_order(weights, truth)
    tiles = []
    for k in order:
        name = result.shape_names[k]
        w = weights[:, k]
        lines = "".join(f'<polyline points="{" ".join(r)}"/>' for r in _polyline(frames, w, lo, hi, top))
        truth_lines, figures = "", []
        if np.isfinite(w).any():
            figures.append(f"peak {np.nanmax(w):.2f}")
            figures.append(f"active {np.mean(np.nan_to_num(w) > 0.05):.0%}")
        if truth is not None and np.isfinite(truth[:, k]).any():
            truth_lines = "".join(f'<polyline points="{" ".join(r)}"/>'
                                  for r in _polyline(frames, truth[:, k], lo, hi, top))
            err = w - truth[:, k]
            figures.insert(0, f"RMSE {np.sqrt(np.nanmean(err ** 2)):.3f}")
        svg = (f'<svg width="{SMALL_W}" height="{SMALL_H}" viewBox="0 0 {SMALL_W} {SMALL_H}" role="img" '
               f'aria-label="{esc(name)} over the take">'
               f'<line x1="0" y1="{SMALL_H - 2}" x2="{SMALL_W}" y2="{SMALL_H - 2}" stroke="#ddd"/>'
               f'<g class="truth" fill="none" stroke="#999" stroke-dasharray="2 2">{truth_lines}</g>'
               f'<g fill="none" stroke="#1f5fa8" stroke-width="1.2">{lines}</g></svg>')
        tiles.append(f'<button class="small" data-shape="{k}" title="show {esc(name)} alone in the weights plot">'
                     f'<span class="name">{esc(name)}</span>{svg}<span class="figs">{esc(", ".join(figures))}</span>'
                     "</button>")
    what = ("worst first: the error against the true weights (dotted)" if truth is not None
            else "most active first (the highest peak)")
    note = (f"Every shape over the whole take, on the same scale (0 to {top:g}), {what}. Click one to show it "
            "alone in the weights plot.")
    return f'<p class="note">{esc(note)}</p><div class="smalls">{"".join(tiles)}</div>'
