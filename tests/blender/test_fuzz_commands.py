"""A seeded fuzz campaign over every command, as an adversarial user would try it: hostile configs of
``retarget``, ``tune``, ``track`` and ``batch``, damaged capture files through ``inspect`` and ``convert``,
output paths that name inputs, folders, special files, links, loops or other people's files, the template
command on damaged and hostile ICT-FaceKit archives, folders and downloads from a local server, and rig targets
whose drivers cannot run (``fuzz_template.py``).

Every case runs the command line in this process (``facecap_addon.cli.main``) and must end in exit status
0 (done), 1 (one line per problem, each starting ``facecap``) or 2 (a usage error), never with a
traceback, an "internal error" or an exception out of ``main``, within ``CASE_SECONDS``; no input, special
file or file nobody asked to replace may change, no temporary file (a partial download, an output's) may be
left, nothing from the rig's .blend may run, and no case may grow this process by more than ``GROWTH_BYTES`` (its
peak resident size, reset before each case, over its resident size then: a command's own process, Blender loaded,
holds about 460 MB, so a command stays within 1 GB; the peak itself depends on what earlier tests left in the
process). Valid configs are solved to the end (the first ``FULL_RUNS`` of them, ``RIG_FULL_RUNS`` of the rig's,
which must warn about the drivers they leave out; later ones are checked up to the preflight, the solve itself
being the one the other tests cover).
The figures per command are printed (``-s``). Signals at random moments are in ``tests/e2e/test_fuzz_signals.py``.
"""

import contextlib
import io
import json
import random
import shutil
import signal
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest

from facecap.facecap_addon.batch import batch as batch_module
from facecap.facecap_addon import cli
from facecap.facecap_addon.headless.headless import preflight
from facecap.solvers.errors import FacecapError

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
from fuzz_commands import PATHS, Case, Workspace, mutate_tables, toml_dumps  # noqa: E402
from fuzz_template import Seeds, litter, make_rig_blend, rig_cases, template_cases  # noqa: E402
from test_fuzz_io import mutate, original  # noqa: E402

from facecap.solvers.tools import template as template_tool  # noqa: E402

SEED = 29
#: Cases per family (2,570 in all)
COUNTS = {"retarget": 800, "track": 300, "batch": 200, "readers": 450, "outputs": 300, "template": 460, "rig": 60}
FULL_RUNS = 40
RIG_FULL_RUNS = 3
CASE_SECONDS = 30  # a case still running after this is stopped and counted as a hang
GROWTH_BYTES = 512 << 20
#: The download's bounds in the campaign: the mechanism is the one users get, its figures small enough that a
#: server sending without end costs a case a second, not the 768 MiB and the hour of a real download
DOWNLOAD_BOUNDS = {"MAX_DOWNLOAD_BYTES": 8 << 20, "DOWNLOAD_SECONDS": 3.0, "TIMEOUT_S": 2.0}


class Hang(Exception):
    pass


def retarget_cases(ws, rng, n):
    for _ in range(n):
        base = ws.retarget_config("geometric" if rng.random() < 0.2 else "parallel")
        data = mutate_tables(base, rng)
        if rng.random() < 0.3:  # a path key set to a path case
            section, key = rng.choice([("source", "markers"), ("source", "weights"), ("target", "blend"),
                                       ("output", "weights"), ("output", "report"), ("output", "blend"),
                                       ("neutral", "file"), ("controls", "preset"), ("calibration", "basis")])
            data.setdefault(section, {})[key] = rng.choice(PATHS) if isinstance(data.get(section, {}), dict) else 1
        argv = ["tune" if rng.random() < 0.05 else "retarget", "--config", "cfg.toml"]
        argv += rng.sample(["--replace", "--overwrite"], rng.randint(0, 1)) if argv[0] == "retarget" else []
        yield Case("retarget", argv, {"cfg.toml": toml_dumps(data).encode()})


def track_cases(ws, rng, n):
    for _ in range(n):
        data = mutate_tables(ws.track_config(), rng)
        if rng.random() < 0.3:
            section, key = rng.choice([("source", "video"), ("tracking", "points"), ("output", "markers"),
                                       ("output", "confidence"), ("output", "report")])
            if isinstance(data.get(section, {}), dict):
                data.setdefault(section, {})[key] = rng.choice(PATHS + ["seq/f%03d.png", "seq/*.png"])
        yield Case("track", ["track", "--config", "cfg.toml", "--quiet"], {"cfg.toml": toml_dumps(data).encode()})


def batch_cases(ws, rng, n):
    for _ in range(n):
        files = {"batch.toml": toml_dumps(mutate_tables(ws.batch_file(), rng)).encode()}
        summary = rng.choice(["s.json", "o/s.json", "notes.txt", "adir", "fifo", "batch.toml", "shoot/take_a.toml",
                              "loop/s.json", "take.csv", "seq"])
        argv = ["batch", "batch.toml", "--jobs", str(rng.choice([1, 2, 0, -1])), "--summary", summary]
        if rng.random() < 0.4:
            argv.append("--resume")
            if summary in ("s.json", "o/s.json"):
                files[summary] = rng.choice([b"", b"garbage", b"{}", b'{"facecap_batch": 1, "takes": 5}',
                                             b'{"facecap_batch": 1, "takes": [{"config": 1}, 5, {"config": "x", '
                                             b'"seconds": 5, "outputs": "x", "status": 7}]}', b"[1, 2]"])
        yield Case("batch", argv, files)


def reader_cases(ws, rng, n, tmp):
    seeds = {kind: original(kind, tmp) for kind in ("csv", "c3d", "trc", "json", "long", "llf")}
    suffix = {"csv": ".csv", "c3d": ".c3d", "trc": ".trc", "json": ".json", "long": ".csv", "llf": ".csv"}
    nrng = np.random.default_rng(rng.randrange(2 ** 32))
    for _ in range(n):
        kind = rng.choice(sorted(seeds))
        name = "cap" + suffix[kind]
        data = mutate(seeds[kind], nrng)
        if rng.random() < 0.5:
            argv = ["inspect", name] + (["--json"] if rng.random() < 0.3 else [])
        else:
            out = rng.choice(["o/c.csv", "o/c.c3d", "o/c.trc", "o/c.json", "o/c.txt", name, "notes.txt", "adir",
                              "fifo", "take.csv"])
            argv = ["convert", name, out] + rng.sample(["--out-units", "mm"], rng.choice([0, 2]))
        yield Case("readers", argv, {name: data})


def output_cases(ws, rng, n):
    for i in range(n):
        path = rng.choice(PATHS)
        family = rng.choice(["retarget", "track", "convert", "batch"])
        if family == "retarget":
            data = ws.retarget_config("parallel")
            data["output"] = {rng.choice(["weights", "report", "blend", "html", "gltf", "actor_basis"]): path}
            if rng.random() < 0.5:
                data["output"][rng.choice(["weights", "report", "blend"])] = rng.choice(PATHS)
            yield Case("outputs", ["retarget", "--config", "cfg.toml"], {"cfg.toml": toml_dumps(data).encode()})
        elif family == "track":
            data = ws.track_config()
            data["output"][rng.choice(["markers", "confidence", "report"])] = path
            yield Case("outputs", ["track", "--config", "cfg.toml", "--quiet"], {"cfg.toml": toml_dumps(data).encode()})
        elif family == "convert":
            yield Case("outputs", ["convert", rng.choice(["take.csv", "weights.csv"]), path])
        else:
            yield Case("outputs", ["batch", "shoot/take_a.toml", "--summary", path],
                       {"shoot/take_a.toml": ws.folder.joinpath("shoot/take_a.toml").read_bytes()})


def run_case(case, folder, counts):
    """(exit status, stderr, exception or None) of one case run in ``folder``."""
    for name, data in case.files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(data)
    if case.setup is not None:
        case.setup(folder)
    err, out = io.StringIO(), io.StringIO()
    previous = signal.signal(signal.SIGALRM, _hang)
    signal.alarm(CASE_SECONDS)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            rc = cli.main(list(case.argv))
        exc = None
    except SystemExit as stop:  # argparse: a usage error
        rc, exc = stop.code, None
    except BaseException as caught:  # noqa: BLE001 - anything out of main is a finding
        rc, exc = None, caught
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    counts[(case.family, "exit", rc)] += 1
    if case.scratch:
        shutil.rmtree(folder / case.scratch, ignore_errors=True)
    return rc, err.getvalue(), exc


def reset_peak():
    """Reset this process's peak resident size (Linux: ``clear_refs`` 5); False where it cannot be."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def memory(field="VmHWM"):
    """This process's peak resident size since the last ``reset_peak`` (``VmHWM``) or its resident size now
    (``VmRSS``), bytes; None where /proc cannot tell."""
    try:
        line = next(x for x in Path("/proc/self/status").read_text().splitlines() if x.startswith(field + ":"))
        return int(line.split()[1]) * 1024
    except (OSError, StopIteration, ValueError):
        return None


def _hang(signum, frame):
    raise Hang(f"still running after {CASE_SECONDS} s")


def findings_of(case, rc, err, exc, before, after, files_before, folder):
    found = []
    if exc is not None:
        found.append(f"{type(exc).__name__} out of main: {exc}")
    if "Traceback" in err or "internal error" in err:
        found.append(f"traceback or internal error: {err.strip().splitlines()[-1][:200]}")
    if rc not in (0, 1, 2, None):
        found.append(f"exit status {rc}")
    if rc == 1 and not [line for line in err.splitlines() if line.startswith("facecap")]:
        found.append(f"exit 1 without a 'facecap' line: {err.strip()[-200:]!r}")
    changed = sorted(k for k in before if before[k] != after.get(k))
    if changed:
        found.append(f"inputs changed: {changed}")
    for name, data in files_before.items():
        if (folder / name).is_file() and (folder / name).read_bytes() != data:
            found.append(f"its own input {name} changed")
    return found


def test_every_command_under_hostile_input_ends_in_one_line_and_changes_no_input(tmp_path, monkeypatch):
    ws = Workspace(tmp_path / "ws")
    make_rig_blend(ws.folder)
    ws.freeze()
    monkeypatch.setenv("FACECAP_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("FACECAP_DATA", str(tmp_path / "data"))
    for name, value in DOWNLOAD_BOUNDS.items():
        monkeypatch.setattr(template_tool, name, value)
    rng = random.Random(SEED)
    nrng = np.random.default_rng(SEED)
    seeds = Seeds(tmp_path)
    with seeds.server() as url:
        cases = (list(retarget_cases(ws, rng, COUNTS["retarget"])) + list(track_cases(ws, rng, COUNTS["track"]))
                 + list(batch_cases(ws, rng, COUNTS["batch"]))
                 + list(reader_cases(ws, rng, COUNTS["readers"], tmp_path))
                 + list(output_cases(ws, rng, COUNTS["outputs"]))
                 + list(template_cases(ws, seeds, rng, nrng, COUNTS["template"], url))
                 + list(rig_cases(ws, rng, COUNTS["rig"])))
        rng.shuffle(cases)
        _campaign(ws, cases, tmp_path, monkeypatch)


def _campaign(ws, cases, tmp_path, monkeypatch):
    solved, rig_solved, silent = [0], [0], []
    real_run_take = cli.run_take

    def run_take(config, **options):  # the first FULL_RUNS valid takes are solved; then the checks only
        if config.rig is not None and rig_solved[0] < RIG_FULL_RUNS:
            rig_solved[0] += 1
            out = real_run_take(config, **options)
            if not any("could not be evaluated" in w for w in out[0].warnings):
                silent.append(str(config.path))
            return out
        if solved[0] >= FULL_RUNS or config.rig is not None:
            preflight(config, tune=options.get("tune", False), replace=options.get("replace", False),
                      overwrite=options.get("overwrite", False))
            raise FacecapError("fuzz: every check passed (not solved)")
        solved[0] += 1
        return real_run_take(config, **options)

    def no_workers(self, specs, events):  # the batch front end only: workers run run_take, fuzzed above
        for spec in specs:
            events.finished(dict(spec["record"], status="failed", error="fuzz: not run"))
        return True

    monkeypatch.setattr(cli, "run_take", run_take)
    monkeypatch.setattr(batch_module.LocalPool, "run", no_workers)
    monkeypatch.chdir(ws.folder)
    counts, findings = Counter(), []
    figures = defaultdict(lambda: {"cases": 0, "seconds": 0.0, "slowest": 0.0, "peak_mb": 0.0, "grew_mb": 0.0})
    start = time.monotonic()
    for i, case in enumerate(cases):
        own = {name: data for name, data in case.files.items()}
        measured, before = reset_peak(), memory("VmRSS")
        began = time.monotonic()
        rc, err, exc = run_case(case, ws.folder, counts)
        took, peak = time.monotonic() - began, memory() if measured else None
        f = figures[case.argv[0] if case.family not in ("outputs", "rig") else case.family]
        f["cases"] += 1
        f["seconds"] += took
        f["slowest"] = max(f["slowest"], took)
        f["peak_mb"] = max(f["peak_mb"], (peak or 0) / 2**20)
        f["grew_mb"] = max(f["grew_mb"], ((peak or 0) - (before or 0)) / 2**20)
        after = ws.snapshot()
        found = findings_of(case, rc, err, exc, ws.digest, after, own, ws.folder)
        left = litter(ws.folder) + litter(tmp_path / "cache") + litter(tmp_path / "data")
        found += [f"left behind: {left[:5]}"] if left else []
        grew = None if peak is None or before is None else peak - before
        found += [f"peak memory {peak / 2**20:.0f} MB, {grew / 2**20:.0f} MB over its start"] \
            if grew is not None and grew > GROWTH_BYTES else []
        for problem in found:
            findings.append(f"case {i} ({case.family}: {' '.join(case.argv)[:300]}; files {sorted(case.files)}): "
                            f"{problem}")
        for name in left:  # so that one finding does not hide the next
            for root in (ws.folder, tmp_path / "cache", tmp_path / "data"):
                (root / name).unlink(missing_ok=True)
        if after != ws.digest:  # put the inputs back so one finding does not hide the next
            pytest.fail("an input changed (the campaign cannot go on):\n" + "\n".join(findings[-5:]))
    seconds = time.monotonic() - start
    table = {f"{family} exit {rc}": n for (family, _, rc), n in sorted(counts.items(), key=str)}
    print(f"\nfuzz campaign: {len(cases)} cases in {seconds:.0f} s, {solved[0]} solved to the end (and {rig_solved[0]} "
          f"rig takes); {json.dumps(table)}")
    print("per command: cases, seconds in all, slowest case (s), peak memory of a case (MB: the whole process, "
          "Blender and the campaign's inputs included; and its growth over the case)")
    for command, f in sorted(figures.items()):
        print(f"  {command:16s} {f['cases']:5d} {f['seconds']:7.1f} {f['slowest']:7.2f} {f['peak_mb']:7.0f} "
              f"{f['grew_mb']:7.0f}")
    assert len(cases) >= 2500 and figures["template"]["cases"] >= 300 and figures["rig"]["cases"] > 0
    assert not findings, f"{len(findings)} findings:\n" + "\n".join(findings[:40])
    assert not silent, f"rig takes solved without a warning about their drivers: {silent}"
    assert solved[0] > 0 and counts[("retarget", "exit", 1)] > 0 and counts[("track", "exit", 0)] > 0
    assert rig_solved[0] == RIG_FULL_RUNS and counts[("template", "exit", 1)] > 0
