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

from ...solvers.config import load_take_config
from ...solvers.config.batch import InputDigests, collect_takes, config_digest
from ...solvers.config.paths import check_across_takes, check_outputs, take_inputs, take_outputs
from ...solvers.errors import ConfigError, FacecapError
from ...solvers.io.outputs import Output
from ...solvers.io.outputs import check_outputs as check_output_policy
from ...solvers.tools.batch_summary import Summary, iso_time, new_record, one_line, read_previous, table
from ...solvers.tools.report.index import TakeSummary, write_batch_index
from ..headless import console
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
    summary_path = Path(os.path.expanduser(args.summary or DEFAULT_SUMMARY))
    overwrite = bool(getattr(args, "overwrite", False))
    records, planned = plan(takes, open_blend=_open_blend(), overwrite=overwrite)
    logs = summary_path.parent / f"{summary_path.stem}-logs"
    previous = read_previous(summary_path, done=logs / "done") if args.resume else {}  # says when it is not one
    check_summary_path(summary_path, planned, takes, overwrite=overwrite)
    summary_path = summary_path.resolve()
    logs = summary_path.parent / f"{summary_path.stem}-logs"
    check_logs_folder(logs)
    specs = to_run(planned, records, previous, replace=args.replace, overwrite=overwrite, done=logs / "done")
    jobs = args.jobs or default_jobs()
    header = {"command": ["facecap", "batch", *map(str, getattr(args, "argv", []))], "cwd": os.getcwd(),
              "jobs": None if args.scheduler else jobs, "scheduler": args.scheduler, "resume": bool(args.resume)}
    summary = Summary(summary_path, header, records)
    summary.write()
    _say_plan(records, specs)
    progress = Progress(len(specs), err, quiet=console.quiet())
    finished = True
    if specs:
        shutil.rmtree(logs, ignore_errors=True)  # facecap's own (check_logs_folder)
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


def to_run(planned, records, previous, *, replace=False, overwrite=False, done=None):
    """The specs of the takes to run, longest first; the up-to-date ones (``previous``: the earlier
    summary's records, ``--resume``) are recorded as skipped in ``records`` instead. ``done``: the
    folder where each take's worker records it finished (``batch_worker.run_one``)."""
    specs = []
    for p in planned:
        prev = previous.get(str(p.take.path))
        if prev is not None and up_to_date(prev, p):
            records[str(p.take.path)] = skipped(prev, p.record)
        else:
            specs.append({"config": str(p.take.path), "data": p.take.data, "replace": bool(replace),
                          "overwrite": bool(overwrite), "record": p.record, "length": _length(p.config),
                          "done": None if done is None else str(done / done_name(p.take.path))})
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


def plan(takes, *, open_blend=None, overwrite=False):
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
            check_outputs(config, overwrite=overwrite)  # the output policy, before any take runs
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


def check_summary_path(path, planned, takes=(), *, overwrite=False):
    """The summary (JSON, CSV and the index page) through the output policy: not a take's input or
    output, nor a batch file or take config, not a folder or a special file, and an existing file only
    when it is the summary of an earlier batch (or ``overwrite``)."""
    inputs = {}
    for t in takes:
        inputs[f"take '{t.name}' config"] = t.path
        if t.listed_by is not None:
            inputs[f"the batch file {t.listed_by.name}"] = t.listed_by
    for p in planned:
        for key, file in {**take_inputs(p.config), **take_outputs(p.config)}.items():
            inputs[f"take '{p.take.name}' {key}"] = file
    outputs = [Output("--summary", path, "batch_summary"), Output("--summary (its CSV)", path.with_suffix(".csv"),
                                                                  "batch_csv"),
               Output("--summary (its index page)", path.with_suffix(".html"), "html")]
    check_output_policy(outputs, inputs, overwrite=overwrite)


def check_logs_folder(folder):
    """The worker logs' folder beside the summary is emptied at the start of a run: refuse when it holds
    anything facecap did not put there (it may be someone's folder that happens to have that name)."""
    if not folder.exists() and not folder.is_symlink():
        return
    if folder.is_symlink() or not folder.is_dir():
        raise FacecapError(f"{folder}: the batch keeps its worker logs here, but it is not a folder of facecap's; "
                           "give another --summary")
    for entry in folder.iterdir():
        ours = (entry.is_file() and entry.name.startswith("worker-") and entry.suffix == ".log") or \
            (entry.name == "done" and entry.is_dir() and not entry.is_symlink())
        if not ours:
            raise FacecapError(f"{folder}: the batch keeps its worker logs here and empties it, but it holds "
                               f"{entry.name}, which facecap did not write; give another --summary")


def done_name(config_path):
    """The file name of a take's completion record (``batch_worker.run_one`` writes it)."""
    return hashlib.sha256(str(config_path).encode("utf-8")).hexdigest()[:24] + ".json"


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
        self.summary.write()  # at once: a batch killed now still knows this take finished

    def tick(self):
        self.summary.write(force=False)
