"""The summary of a batch: one record per take, written as JSON and CSV and printed as a table.

The JSON file is the batch's record (``docs/batch.md`` gives its schema; a batch index page reads
it). It is rewritten atomically while the batch runs (at most once a second), so a batch killed
outright still leaves what it finished, and ``batch --resume`` reads it back.
"""

import csv
import io
import json
import math
import time
from pathlib import Path

import numpy as np

from ..errors import FacecapError
from ..io.csv_write import formula_safe
from ..io.files import write_json_atomic, write_text_atomic
from ..io.limits import MAX_TEXT_BYTES, check_input_file

#: The summary's schema version (``"facecap_batch"`` in the JSON)
SCHEMA = 1
#: Statuses a take ends with, and those it has while the batch runs
FINAL = ("ok", "failed", "skipped", "cancelled")
PENDING = ("queued", "running")
CSV_COLUMNS = ("take", "status", "error", "frames", "shapes", "strategy", "residual_mm", "warnings", "seconds",
               "worker", "outputs", "config")


def new_record(take, *, status="queued", error=None, digest=None):
    """The record of a take before it runs. ``take``: a BatchTake."""
    return {
        "take": take.name, "config": str(take.path),
        "listed_by": None if take.listed_by is None else str(take.listed_by),
        "status": status, "error": error, "frames": None, "shapes": None, "strategy": None,
        "residual_mm": None, "residual_max_mm": None, "residual_space": None, "warnings": 0, "warning_messages": [],
        "seconds": {}, "outputs": {}, "worker": None, "started": None, "finished": None,
        "note": None, "digest": digest,
    }


def result_fields(result, outputs, warnings, seconds):
    """The fields a finished take adds to its record (``result``: a RetargetResult)."""
    ok = np.isfinite(result.residual_rms)
    return {
        "frames": int(result.frames.size), "shapes": len(result.shape_names), "strategy": result.strategy,
        "residual_mm": float(np.mean(result.residual_rms[ok]) * 1e3) if ok.any() else None,
        "residual_max_mm": float(np.max(result.residual_rms[ok]) * 1e3) if ok.any() else None,
        "residual_space": result.residual_space,
        "warnings": len(warnings), "warning_messages": list(warnings),
        "seconds": {"stages": {k: float(v) for k, v in result.timings.items()}, **seconds},
        "outputs": dict(outputs),
    }


def one_line(text, limit=400):
    """``text`` on one line (an error from deep inside a take may span lines), at most ``limit`` characters."""
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[: limit - 3] + "..."


def counts(records):
    out = {s: 0 for s in FINAL + PENDING}
    for r in records:
        out[r["status"]] = out.get(r["status"], 0) + 1
    return {k: v for k, v in out.items() if v or k in FINAL}


def overall_status(records, cancelled):
    if cancelled:
        return "cancelled"
    if any(r["status"] in PENDING for r in records):
        return "running"
    return "failed" if any(r["status"] in ("failed", "cancelled") for r in records) else "ok"


class Summary:
    """The batch's summary file(s): ``path`` (JSON) and the same name with ``.csv``."""

    def __init__(self, path, header, records):
        self.path = Path(path)
        self.csv_path = self.path.with_suffix(".csv")
        self.header = dict(header)
        self.records = records  # take config path -> record, in the batch's order
        self.started = time.time()
        self._written = 0.0
        self.cancelled = False
        self.dirty = True  # records changed since the last write

    def document(self):
        records = list(self.records.values())
        return {
            "facecap_batch": SCHEMA, **self.header,
            "status": overall_status(records, self.cancelled),
            "started": iso_time(self.started), "updated": iso_time(time.time()),
            "seconds": round(time.time() - self.started, 3),
            "counts": counts(records), "summary_csv": str(self.csv_path),
            "takes": records,
        }

    def write(self, *, force=True, every=1.0):
        """Write JSON and CSV (atomically); without ``force``, only what changed and at most once
        every ``every`` seconds. Returns whether it wrote."""
        now = time.monotonic()
        if not force and (not self.dirty or now - self._written < every):
            return False
        document = self.document()
        write_json_atomic(self.path, document)
        write_text_atomic(self.csv_path, to_csv(document["takes"]))
        self._written, self.dirty = now, False
        return True


def to_csv(records):
    """The summary as CSV; text cells that a spreadsheet would run as a formula (a take named ``=1+1``) are
    written as text (``csv_write.formula_safe``)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for r in records:
        total = r["seconds"].get("total") if r["seconds"] else None
        outputs = "; ".join(f"{k}={v}" for k, v in r["outputs"].items())
        text = [formula_safe(str(t)) for t in (r["take"], r["status"], r["error"] or "", r["strategy"] or "",
                                               r["worker"] or "", outputs, r["config"])]
        writer.writerow([*text[:3], _blank(r["frames"]), _blank(r["shapes"]), text[3], _number(r["residual_mm"], 4),
                         r["warnings"], _number(total, 3), *text[4:]])
    return out.getvalue()


def read_previous(path, done=None):
    """{take config path: record} of an earlier summary (``--resume``), with the completion records in
    the folder ``done`` (each written by its worker the moment the take finished: newer than the
    summary, which may lag) over them. {} when there is no summary.

    Raises
    ------
    FacecapError (one line naming the file) when ``path`` is not a facecap batch summary: resuming
    from it would run every take again and write over it.
    """
    path = Path(path)
    records = {}
    if path.exists():
        check_input_file(path, limit=MAX_TEXT_BYTES)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise FacecapError(f"{path}: --resume needs the batch's summary; this is not one (not JSON: {exc})") \
                from None
        if not isinstance(data, dict) or data.get("facecap_batch") != SCHEMA or not isinstance(data.get("takes"), list):
            raise FacecapError(f"{path}: --resume needs the batch's summary; this is not one (no \"facecap_batch\": "
                               f"{SCHEMA} with a list of \"takes\"); give the summary the batch wrote, or drop "
                               "--resume")
        for r in data["takes"]:
            record = valid_record(r)
            if record is not None:
                records[record["config"]] = record
    for file in sorted(Path(done).glob("*.json")) if done is not None and Path(done).is_dir() else ():
        try:
            record = valid_record(json.loads(file.read_text(encoding="utf-8")))
        except (OSError, ValueError):
            continue  # unreadable: that take is simply run again
        if record is not None:
            records[record["config"]] = record
    return records


def valid_record(record):
    """A take record read back from disk with every field of the expected type (else its default), or
    None when it names no take config."""
    if not isinstance(record, dict) or not isinstance(record.get("config"), str):
        return None
    template = new_record(_Named(str(record.get("take") or Path(record["config"]).stem), Path(record["config"])))
    out = {}
    for key, default in template.items():
        value = record.get(key, default)
        kinds = _FIELD_KINDS.get(key, (type(default),) if default is not None else (str,))
        out[key] = value if value is None or (isinstance(value, kinds) and not isinstance(value, bool)) else default
    out["outputs"] = {str(k): v for k, v in out["outputs"].items() if isinstance(v, str)}
    if not isinstance(out["seconds"].get("total", 0), (int, float)):
        out["seconds"] = {}
    if out["status"] not in FINAL + PENDING:
        out["status"] = "failed"
    if not isinstance((out["digest"] or {}).get("combined", ""), str):
        out["digest"] = None
    return out


class _Named:
    """The two fields of a BatchTake that ``new_record`` reads."""

    def __init__(self, name, path):
        self.name, self.path, self.listed_by = name, path, None


#: Record fields and the types they may hold when read back (others: the default's type)
_FIELD_KINDS = {"frames": (int,), "shapes": (int,), "residual_mm": (int, float), "residual_max_mm": (int, float),
                "warnings": (int,), "warning_messages": (list,), "seconds": (dict,), "outputs": (dict,),
                "digest": (dict,), "error": (str,), "note": (str,), "worker": (str,), "started": (str,),
                "finished": (str,), "strategy": (str,), "residual_space": (str,), "listed_by": (str,)}


def table(records, width=None):
    """The printed summary: one line per take and a totals line; errors shortened in the middle to
    fit ``width`` characters (None: whole)."""
    rows = [("take", "status", "frames", "shapes", "resid mm", "warn", "seconds", "error")]
    for r in records:
        total = r["seconds"].get("total") if r["seconds"] else None
        rows.append((r["take"], r["status"], _blank(r["frames"]), _blank(r["shapes"]), _number(r["residual_mm"], 3),
                     str(r["warnings"] or ""), _number(total, 1), r["error"] or ""))
    widths = [max(len(str(row[c])) for row in rows) for c in range(7)]
    lines = []
    for row in rows:
        head = "  ".join(str(v).ljust(w) if c < 2 else str(v).rjust(w) for c, (v, w) in enumerate(zip(row, widths)))
        room = None if width is None else max(30, width - len(head) - 2)
        lines.append((head + "  " + _clip(row[7], room)).rstrip())
    c = {k: v for k, v in counts(records).items() if v or k in ("ok", "failed")}
    lines.append(", ".join(f"{v} {k}" for k, v in c.items()) + f" of {len(records)} takes")
    return "\n".join(lines)


def _clip(text, room):
    if room is None or len(text) <= room:
        return text
    tail = (room - 5) // 2
    return text[: room - 5 - tail] + " ... " + text[-tail:]


def _blank(value):
    return "" if value is None else str(value)


def _number(value, digits):
    return "" if value is None or (isinstance(value, float) and not math.isfinite(value)) else f"{value:.{digits}f}"


def iso_time(t):
    return time.strftime("%Y-%m-%dT%H:%M:%S%z", time.localtime(t))
