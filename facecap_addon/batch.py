"""``python -m facecap batch``: many takes, each isolated, on worker processes here or on a Dask farm.

The batch process itself never imports Blender: it reads the take configs (with a batch file's
defaults), refuses takes that would write the same file before any work, hashes every take's
inputs and effective config (for ``--resume``), hands the takes to workers (``batch_pool`` here,
``batch_farm`` on Dask; both run ``batch_worker.run_one`` in a long-lived Blender process), and
keeps the summary (``solvers.tools.batch_summary``) and the progress display up to date.
"""

import dataclasses
import hashlib
import json
import os
import shutil
import sys
import time
from pathlib import Path

from ..solvers.config import load_take_config
from ..solvers.config.batch import InputDigests, collect_takes, config_digest
from ..solvers.config.paths import check_across_takes, resolved, take_inputs, take_outputs
from ..solvers.errors import ConfigError, FacecapError
from ..solvers.tools.batch_summary import Summary, iso_time, new_record, one_line, read_previous, table
from ..solvers.tools.report.index import TakeSummary, write_batch_index
from . import console
from .batch_farm import FarmPool
from .batch_pool import LocalPool
from .batch_progress import Progress

#: The summary's default name (in the current folder)
DEFAULT_SUMMARY = "facecap-batch.json"
#: Input keys whose size estimates a take's length (the longest takes are started first)
LENGTH_INPUTS = ("[source.markers]", "[source.weights]", "[source.video]")


@dataclasses.dataclass
class Planned:
    """A take that can run: its (possibly completed) tables, parsed config and record."""

    take: object  # BatchTake
    config: object  # TakeConfig
    record: dict


def default_jobs():
    """The cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # no affinity on this platform
        return max(1, os.cpu_count() or 1)


def run_batch(args, *, out=None, err=None):
    """Run the batch ``args`` (``takes``, ``jobs``, ``scheduler``, ``summary``, ``resume``, ``replace``);
    returns the exit status: 0 all ok (or up to date), 1 any failed, 130 cancelled."""
    out, err = out or sys.stdout, err or sys.stderr
    if args.jobs is not None and args.jobs < 1:
        raise FacecapError(f"--jobs must be at least 1; got {args.jobs}")
    takes = collect_takes(args.takes)
    if not takes:
        raise ConfigError("no take configs (.toml) in " + ", ".join(map(str, args.takes)) + " nor in the folders "
                          "one level down; name take configs, folders of them, or a batch file")
    summary_path = Path(os.path.expanduser(args.summary or DEFAULT_SUMMARY)).resolve()
    records, planned = plan(takes, open_blend=_open_blend())
    check_summary_path(summary_path, planned)
    specs = to_run(planned, records, read_previous(summary_path) if args.resume else {}, replace=args.replace)
    jobs = args.jobs or default_jobs()
    header = {"command": ["facecap", "batch", *map(str, getattr(args, "argv", []))], "cwd": os.getcwd(),
              "jobs": None if args.scheduler else jobs, "scheduler": args.scheduler, "resume": bool(args.resume)}
    summary = Summary(summary_path, header, records)
    summary.write()
    _say_plan(records, specs)
    progress = Progress(len(specs), err, quiet=console.quiet())
    finished = True
    if specs:
        logs = summary_path.parent / f"{summary_path.stem}-logs"
        shutil.rmtree(logs, ignore_errors=True)
        events = Events(summary, progress)
        if args.scheduler:
            finished = FarmPool(args.scheduler).run(specs, events)
        else:
            finished = LocalPool(min(jobs, len(specs)), logs).run(specs, events)
    progress.close()
    return _finish(summary, finished, out, err)


def write_index(summary):
    """The batch's index page beside its summary (``<summary>.html``) when a take wrote a review page:
    each take's status, frames, residual sparkline and a link to its page. Returns its path or None."""
    records = list(summary.records.values())
    if not any(r.get("outputs", {}).get("html") for r in records):
        return None
    rows = []
    for r in records:
        outputs, status = r.get("outputs") or {}, "ok" if r["status"] == "ok" else r["status"]
        row = {"take": r["take"], "status": status, "frames": r.get("frames"), "report": outputs.get("html"),
               "message": r.get("error") or r.get("note") or "", "strategy": r.get("strategy") or "",
               "seconds": (r.get("seconds") or {}).get("total"), "warnings": r.get("warnings") or 0}
        if outputs.get("report") and Path(outputs["report"]).is_file():  # the per-frame residual for the line
            try:
                report = TakeSummary.from_report(r["take"], status, outputs["report"], html=outputs.get("html"))
                row["residual_mm"] = report.residual_mm
            except FacecapError:
                pass
        rows.append(row)
    path = summary.path.with_suffix(".html")
    write_batch_index(path, rows)
    return path


def to_run(planned, records, previous, *, replace=False):
    """The specs of the takes to run, longest first; the up-to-date ones (``previous``: the earlier
    summary's records, ``--resume``) are recorded as skipped in ``records`` instead."""
    specs = []
    for p in planned:
        prev = previous.get(str(p.take.path))
        if prev is not None and up_to_date(prev, p):
            records[str(p.take.path)] = skipped(prev, p.record)
        else:
            specs.append({"config": str(p.take.path), "data": p.take.data, "replace": bool(replace),
                          "record": p.record, "length": _length(p.config)})
    specs.sort(key=lambda s: -s["length"])  # the longest first: the last take to finish is a short one
    return specs


def _finish(summary, finished, out, err):
    """The last summary, the table; the exit status."""
    records = summary.records
    if not finished:
        summary.cancelled = True
        for record in records.values():
            if record["status"] in ("queued", "running"):
                record.update(status="cancelled", error="not started: the batch was cancelled")
    summary.write()
    width = shutil.get_terminal_size().columns if getattr(out, "isatty", lambda: False)() else None
    print(table(list(records.values()), width), file=out)
    print(f"summary: {summary.path} (and {summary.csv_path.name})", file=out, flush=True)
    index = write_index(summary)
    if index is not None:
        print(f"review pages: {index}", file=out, flush=True)
    if not finished:
        console.log.warning("batch cancelled; finished takes are kept, running ones wrote nothing unfinished")
        return 130
    return 1 if any(r["status"] in ("failed", "cancelled") for r in records.values()) else 0


def plan(takes, *, open_blend=None):
    """Read every take: ({config path: record}, [Planned]). A take that cannot be read or parsed
    is recorded failed; takes that would write the same file (or one another's inputs) raise
    ConfigError before any work."""
    records, planned = {}, []
    digests = InputDigests()
    for take in takes:
        record = records[str(take.path)] = new_record(take)
        if take.error is not None:
            record.update(status="failed", error=one_line(take.error))
            continue
        try:
            take, config = _parse(take, open_blend)
            record["digest"] = _digest(take, config, digests)
        except FacecapError as exc:
            record.update(status="failed", error=one_line(exc))
            continue
        planned.append(Planned(take, config, record))
    check_across_takes([p.config for p in planned], names=[p.take.name for p in planned])
    return records, planned


def _parse(take, open_blend):
    config = load_take_config(take.path, take.data)
    if config.target_blend is None:
        if not open_blend:
            raise ConfigError("a batch take needs [target] blend: each worker opens it", path=take.path,
                              key="target.blend")
        data = {**take.data, "target": {**take.data.get("target", {}), "blend": open_blend}}
        take = dataclasses.replace(take, data=data)
        config = load_take_config(take.path, data)
    return take, config


def _digest(take, config, digests):
    parts = {"config": config_digest(take), "inputs": digests.of_config(config)}
    combined = hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()
    return {"combined": combined, **parts}


def _open_blend():
    """The .blend open in this Blender (``blender -b file.blend -P cli.py -- batch``), else None."""
    bpy = sys.modules.get("bpy")  # read only: the batch process does not start Blender
    path = getattr(getattr(bpy, "data", None), "filepath", "") if bpy is not None else ""
    return path or None


def check_summary_path(path, planned):
    """The summary (JSON, CSV and the index page) must not be a take's input or output."""
    mine = {resolved(path.with_suffix(suffix)) for suffix in (".json", ".csv", ".html")} | {resolved(path)}
    for p in planned:
        for key, file in {**take_inputs(p.config), **take_outputs(p.config)}.items():
            if resolved(file) in mine:
                raise ConfigError(f"the batch summary {path.name} is take '{p.take.name}' {key}; give another "
                                  "--summary", path=path)


def up_to_date(previous, planned):
    """Whether a take finished in the run that wrote ``previous`` (its record) and nothing it depends
    on changed since: same inputs and effective config (digests), every output still there."""
    digest = previous.get("digest") or {}
    same = digest.get("combined") == planned.record["digest"]["combined"]
    return (previous.get("status") in ("ok", "skipped") and same
            and all(Path(p).exists() for p in take_outputs(planned.config).values()))


def skipped(previous, record):
    """The record of an up-to-date take: its earlier results, status ``skipped``."""
    when = previous.get("finished") or "an earlier run"
    return {**previous, "take": record["take"], "listed_by": record["listed_by"], "status": "skipped", "error": None,
            "note": f"up to date: inputs, config and outputs unchanged since {when}"}


def _length(config):
    """Bytes of the take's source (markers, weights or video): longer takes first."""
    inputs = take_inputs(config)
    total = 0
    for key in LENGTH_INPUTS:
        try:
            total += inputs[key].stat().st_size
        except (KeyError, OSError):
            pass
    return total


def _say_plan(records, specs):
    n = len(records)
    failed = sum(r["status"] == "failed" for r in records.values())
    up = sum(r["status"] == "skipped" for r in records.values())
    parts = [f"{len(specs)} to run"] + ([f"{up} up to date"] if up else []) \
        + ([f"{failed} failed to read"] if failed else [])
    console.log.info(f"batch of {n} take{'s' if n != 1 else ''}: {', '.join(parts)}")
    for r in records.values():
        if r["status"] == "failed":
            console.log.error(f"FAILED {r['take']}: {r['error']}")


class Events:
    """What the pools report, kept in the summary and shown by the progress display."""

    def __init__(self, summary, progress):
        self.summary, self.progress = summary, progress

    def started(self, spec, worker):
        record = self.summary.records[spec["config"]]
        record.update(status="running", worker=worker, started=iso_time(time.time()))
        self.summary.dirty = True

    def finished(self, record):
        self.summary.records[record["config"]] = record
        self.summary.dirty = True
        self.progress.finished(record)
        self.summary.write(force=False)

    def tick(self):
        self.summary.write(force=False)
