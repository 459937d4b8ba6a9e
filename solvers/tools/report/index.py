"""The index page of a batch: one row per take (status, frames, residual, a sparkline of the residual
over the take, a link to its review page), plain HTML and SVG that needs no script library.

The batch gives one ``TakeSummary`` per take, built from its own records or from each take's JSON
report (``TakeSummary.from_report``); its review pages share one ``plotly.min.js``
(``page.shared_plotly_js``) beside them.
"""

import json
import math
import os
import time
from dataclasses import dataclass, fields
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ...errors import InputFileError
from ...io.files import atomic_path
from .blob import envelope
from .sections import esc

#: Sparkline size (pixels) and the most buckets its envelope keeps.
SPARK_W, SPARK_H, SPARK_BUCKETS = 180, 30, 90
OK = ("ok", "done", "solved")
#: Statuses of a take whose outputs from an earlier run are still right (``batch --resume``): done, not redone.
CURRENT = ("skipped", "up to date")


def kind(status):
    """"ok" (solved in this run), "current" (up to date from an earlier run) or "bad" (failed, cancelled...)."""
    status = status.lower()
    return "ok" if status in OK else "current" if status in CURRENT else "bad"


@dataclass(frozen=True)
class TakeSummary:
    """One take of a batch, as its row of the index.

    take : the take's name (shown, and the link text)
    status : "ok" for a solved take, "skipped" for one up to date from an earlier run (``--resume``), else
        what happened ("failed", "cancelled", ...)
    frames : number of frames solved (None: unknown)
    residual_mm : per-frame RMS residual in millimetres (None / NaN for unsolved frames; None: no marker
        residual, e.g. ``parallel``)
    report : path of the take's review page (HTML); None: no link
    message : the error line of a failed take, or a note
    strategy : the strategy used
    seconds : the take's wall time
    warnings : how many warnings its solve gave
    """

    take: str
    status: str
    frames: int = None
    residual_mm: object = None
    report: object = None
    message: str = ""
    strategy: str = ""
    seconds: float = None
    warnings: int = 0

    @classmethod
    def from_mapping(cls, record):
        """From a dict with the field names (e.g. a row of a batch summary JSON); other keys are ignored."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in record.items() if k in names})

    @classmethod
    def from_report(cls, take, status, report_json, *, html=None, message="", seconds=None):
        """From a take's JSON report (``[output] report``): frames, per-frame residual, strategy, warnings,
        and the total time unless ``seconds`` is given."""
        path = Path(report_json)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise InputFileError(path, f"not a readable JSON report ({exc})") from None
        residual = (data.get("residual_rms_mm") or {}).get("per_frame")
        total = (data.get("timings_s") or {}).get("total")
        return cls(take=take, status=status, frames=(data.get("frames") or {}).get("count"), residual_mm=residual,
                   report=html, message=message, strategy=data.get("strategy", ""),
                   seconds=total if seconds is None else seconds, warnings=len(data.get("warnings") or []))

    def residual(self):
        """(F,) float array (NaN where missing) or None."""
        if self.residual_mm is None:
            return None
        values = np.array([np.nan if v is None else v for v in self.residual_mm], dtype=np.float64)
        return values if values.size else None


def sparkline(values, width=SPARK_W, height=SPARK_H, buckets=SPARK_BUCKETS):
    """An inline SVG of ``values`` (its min/max envelope, so a one-frame spike shows), the worst marked."""
    finite = np.isfinite(values)
    if not finite.any():
        return ""
    xs, ys = envelope(np.arange(values.size, dtype=np.float64), values, buckets)
    top = float(np.nanmax(values)) or 1.0
    span = max(values.size - 1, 1)

    def px(x, y):
        return f"{x / span * (width - 4) + 2:.1f},{height - 3 - y / top * (height - 6):.1f}"

    runs, run = [], []
    for x, y in zip(xs, ys):
        if np.isfinite(y):
            run.append(px(x, y))
        elif run:
            runs.append(run)
            run = []
    if run:
        runs.append(run)
    lines = "".join(f'<polyline points="{" ".join(r)}"/>' for r in runs if len(r) > 1)
    dots = "".join(f'<circle cx="{r[0].split(",")[0]}" cy="{r[0].split(",")[1]}" r="1.2"/>' for r in runs if len(r) == 1)
    i = int(np.nanargmax(values))
    wx, wy = px(i, values[i]).split(",")
    return (f'<svg class="spark" width="{width}" height="{height}" viewBox="0 0 {width} {height}" role="img" '
            f'aria-label="residual over the take, worst {top:.3f} mm at row {i + 1}">'
            f'<g fill="none" stroke="#555" stroke-width="1">{lines}</g><g fill="#555">{dots}</g>'
            f'<circle cx="{wx}" cy="{wy}" r="2.2" fill="#d62728"/></svg>')


def _number(value, fmt):
    return "" if value is None or (isinstance(value, float) and not math.isfinite(value)) else format(value, fmt)


def _row(summary, folder):
    res = summary.residual()
    row_kind = kind(summary.status)
    status = "up to date" if row_kind == "current" else summary.status
    name = esc(summary.take)
    if summary.report is not None:
        link = os.path.relpath(Path(summary.report).resolve(), folder).replace(os.sep, "/")
        name = f'<a href="{esc(link)}">{name}</a>'
    mean = float(np.nanmean(res)) if res is not None and np.isfinite(res).any() else None
    worst = float(np.nanmax(res)) if res is not None and np.isfinite(res).any() else None
    spark = sparkline(res) if res is not None else ""
    note = summary.message or (f"{summary.warnings} warning(s)" if summary.warnings else "")
    note_html = f'<span class="{"bad" if row_kind == "bad" else "info"}">{esc(note)}</span>' if note else ""
    cells = [
        (summary.take.lower(), name),
        (status, f'<span class="{row_kind}">{esc(status)}</span>'),
        (summary.frames if summary.frames is not None else -1, _number(summary.frames, "d")),
        (summary.strategy, esc(summary.strategy)),
        (mean if mean is not None else -1, _number(mean, ".3f")),
        (worst if worst is not None else -1, _number(worst, ".3f")),
        ("", spark),
        (summary.seconds if summary.seconds is not None else -1, _number(summary.seconds, ".1f")),
        (note, note_html),
    ]
    tds = "".join(f'<td data-key="{esc(key)}">{html}</td>' for key, html in cells)
    return f'<tr class="{row_kind}">{tds}</tr>'


HEADERS = ("take", "status", "frames", "strategy", "mean residual (mm)", "worst (mm)", "residual over the take",
           "time (s)", "notes")
CSS = """body{font:14px/1.4 system-ui,sans-serif;margin:24px;color:#222;background:#f6f6f4}
table{border-collapse:collapse;background:#fff;border:1px solid #ddd}th,td{padding:4px 10px;text-align:left;
border-bottom:1px solid #eee;vertical-align:middle}th{cursor:pointer;background:#fafafa;user-select:none}
td:nth-child(3),td:nth-child(5),td:nth-child(6),td:nth-child(8){text-align:right;font-variant-numeric:tabular-nums}
.ok{color:#2a7a2a}.current{color:#2a6a8a}.bad{color:#b3261e}.info{color:#666}tr.bad td:first-child{font-weight:600}
a{color:#1f5fa8}
p.note{color:#666}footer{color:#666;font-size:12px;margin-top:12px}"""
SORT_JS = """document.querySelectorAll("th").forEach((th, col) => th.addEventListener("click", () => {
  const body = th.closest("table").tBodies[0], up = th.dataset.dir !== "up";
  th.dataset.dir = up ? "up" : "down";
  const key = r => { const v = r.cells[col].dataset.key, n = Number(v); return v !== "" && !isNaN(n) ? n : v; };
  Array.from(body.rows).sort((a, b) => (key(a) > key(b) ? 1 : key(a) < key(b) ? -1 : 0) * (up ? 1 : -1))
    .forEach(r => body.appendChild(r));
}));"""


def write_batch_index(path, records, *, title="facecap batch"):
    """Write the index page of a batch to ``path`` (atomically); returns {"path", "bytes", "seconds"}.

    records : TakeSummary or dicts with its field names, one per take, in the batch's order (failed ones
        included: they are listed first when sorted by status).
    """
    t0 = time.perf_counter()
    path = Path(path)
    folder = path.resolve().parent
    rows = [r if isinstance(r, TakeSummary) else TakeSummary.from_mapping(r) for r in records]
    counts = {k: sum(kind(r.status) == k for r in rows) for k in ("ok", "current", "bad")}
    frames = sum(r.frames or 0 for r in rows if kind(r.status) != "bad")
    parts = [f"{counts['ok']} solved"] + ([f"{counts['current']} up to date (solved before, unchanged)"]
                                          if counts["current"] else []) + ([f"{counts['bad']} not solved"]
                                                                          if counts["bad"] else [])
    generated = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    head = "".join(f"<th>{esc(h)}</th>" for h in HEADERS)
    body = "".join(_row(r, folder) for r in rows)
    text = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{esc(title)}</title><style>{CSS}</style></head><body>
<h1>{esc(title)}</h1>
<p class="summary">{len(rows)} take(s): {", ".join(parts)}; {frames:,} frames with weights.</p>
<p class="note">Click a take for its review page; click a column heading to sort. The residual is the RMS
distance of the markers from the solve's fit per frame; its line keeps every frame's peak, the red dot is
the worst frame.</p>
<table id="takes"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>
<footer>facecap batch index, {esc(generated)}</footer>
<script>{SORT_JS}</script>
</body></html>
"""
    data = text.encode("utf-8")
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return {"path": path, "bytes": len(data), "seconds": time.perf_counter() - t0}
