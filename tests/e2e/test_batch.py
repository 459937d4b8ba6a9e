"""``python -m facecap batch`` as a TD runs it: a shoot folder with broken takes among good ones, two
workers, results bit-identical to single ``retarget`` runs, --resume, a worker killed with SIGKILL,
Ctrl-C, clashing outputs refused before any work, and the Blender script entry."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from batch_shoot import GOOD, ROOT, cut_take, facecap, shoot, solve_curves, standalone, summary, take

from facecap.solvers.io.files import TMP_MARK

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    """The shoot run with --jobs 2, and the good takes run one by one with ``retarget`` (at once)."""
    folder = tmp_path_factory.mktemp("shoot")
    batch = shoot(folder)
    singles = [subprocess.Popen([sys.executable, "-m", "facecap", "retarget", "--config",
                                 str(standalone(folder, name, folder / "single_out"))],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) for name in GOOD]
    proc = facecap("batch", batch, "--jobs", "2", "--summary", folder / "summary.json", cwd=folder)
    for p in singles:
        assert p.wait(timeout=900) == 0, p.stderr.read()
    return folder, proc


def test_a_shoot_with_broken_takes_runs_the_good_ones_and_names_the_broken(ran):
    folder, proc = ran
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    data, takes = summary(folder / "summary.json")
    assert data["status"] == "failed" and data["counts"] == {"ok": 4, "failed": 2, "skipped": 0, "cancelled": 0}
    assert set(takes) == set(GOOD) | {"take_missing", "take_badvalue"}
    for name, (frames, drop, _) in GOOD.items():
        t = takes[name]
        assert t["status"] == "ok" and t["error"] is None, t
        assert t["frames"] == frames and t["shapes"] == 52 and 0.2 < t["residual_mm"] < 1.0
        assert set(t["outputs"]) == {"action", "blend", "weights", "report"}
        assert all(Path(t["outputs"][k]).is_file() for k in ("blend", "weights", "report"))
        assert t["warnings"] == len(t["warning_messages"]) > 0 and t["seconds"]["total"] > 0
    assert takes["take_missing"]["status"] == "failed"
    assert takes["take_missing"]["error"].endswith("captures/not_there.csv: file not found")
    assert takes["take_badvalue"]["error"].endswith(
        "[solve.regularisation] expected a number >= 0 and <= 100; got -1.0")
    assert not (folder / "out" / "take_missing.csv").exists()
    # both workers ran takes; the table and the plain progress lines name the failures
    assert len({t["worker"] for t in takes.values() if t["status"] == "ok"}) == 2
    row = next(line for line in proc.stdout.splitlines() if line.startswith("take_missing "))
    assert row.split()[1] == "failed" and row.endswith("not_there.csv: file not found")
    assert proc.stdout.splitlines()[-2] == "4 ok, 2 failed of 6 takes"
    # the bad value failed while the configs were read; the missing file in a worker
    assert "FAILED take_badvalue" in proc.stderr and "facecap: [5/5]" in proc.stderr
    csv_rows = (folder / "summary.csv").read_text().splitlines()
    assert len(csv_rows) == 7 and csv_rows[0].startswith("take,status,error,frames")


def test_every_good_take_is_bit_identical_to_its_single_retarget(ran, tmp_path):
    folder, _ = ran
    blends = []
    for name in GOOD:
        batch_csv, single_csv = folder / "out" / f"{name}.csv", folder / "single_out" / f"{name}.csv"
        assert batch_csv.read_bytes() == single_csv.read_bytes(), name
        blends += [folder / "out" / f"{name}.blend", folder / "single_out" / f"{name}.blend"]
    curves = solve_curves(blends, tmp_path)
    for i, name in enumerate(GOOD):
        (batch_action, batch), (single_action, single) = curves[2 * i], curves[2 * i + 1]
        assert batch_action == single_action == name
        assert set(batch) == set(single) and len(batch) >= 52
        for path in batch:
            assert np.array_equal(batch[path], single[path], equal_nan=True), (name, path)


def test_resume_skips_what_is_done_and_redoes_what_changed(tmp_path):
    good = {k: GOOD[k] for k in ("take_a", "take_c", "take_d")}
    batch = shoot(tmp_path, good=good, broken=False)
    first = facecap("batch", batch, "--jobs", "2", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    again = facecap("batch", batch, "--resume", cwd=tmp_path)
    assert again.returncode == 0, again.stderr
    assert "0 to run, 3 up to date" in again.stderr
    _, takes = summary(tmp_path / "facecap-batch.json")
    assert {t["status"] for t in takes.values()} == {"skipped"} and takes["take_a"]["frames"] == 400
    before = (tmp_path / "out" / "take_d.csv").read_bytes()
    cut_take(tmp_path / "captures" / "take_a.csv", 300)  # an input changed
    (tmp_path / "out" / "take_c.json").unlink()  # an output is gone
    third = facecap("batch", batch, "--resume", "--jobs", "2", cwd=tmp_path)
    assert third.returncode == 0, third.stderr
    assert "2 to run, 1 up to date" in third.stderr
    _, takes = summary(tmp_path / "facecap-batch.json")
    assert takes["take_a"]["status"] == "ok" and takes["take_a"]["frames"] == 300
    assert takes["take_c"]["status"] == "ok" and (tmp_path / "out" / "take_c.json").is_file()
    assert takes["take_d"]["status"] == "skipped" and (tmp_path / "out" / "take_d.csv").read_bytes() == before
    # a changed default is a changed config: every take is redone
    text = batch.read_text()
    batch.write_text(text.replace("[defaults.neutral]\nframes = [1, 50]", "[defaults.neutral]\nframes = [1, 40]"))
    fourth = facecap("batch", batch, "--resume", "--jobs", "2", cwd=tmp_path)
    assert fourth.returncode == 0 and "3 to run" in fourth.stderr, fourth.stderr


def wait_for(predicate, what, timeout=300):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def running(summary_path, name):
    """The pid of the worker running take ``name``, once the summary says it runs."""
    try:
        _, takes = summary(summary_path)
    except (OSError, ValueError):
        return None
    t = takes.get(name)
    return int(t["worker"].rsplit(" ", 1)[1]) if t and t["status"] == "running" else None


def long_shoot(folder, shorts=2):
    """A long take (the sample take 32 times: 23,040 frames, started first; at 5,760 frames an idle machine
    finished it within the second the tests wait before interrupting it) and short ones."""
    cut_take(folder / "captures" / "take_long.csv", 720, tile=32)
    take(folder / "takes" / "take_long.toml", "../captures/take_long.csv")
    for i in range(shorts):
        cut_take(folder / "captures" / f"take_s{i}.csv", 300)
        take(folder / "takes" / f"take_s{i}.toml", f"../captures/take_s{i}.csv")
    from batch_shoot import batch_file

    return batch_file(folder)


def no_temporaries(folder):
    return [p.name for p in Path(folder).rglob("*") if TMP_MARK in p.name]


def test_a_worker_killed_with_sigkill_fails_only_its_take(tmp_path):
    batch = long_shoot(tmp_path)
    log = tmp_path / "stderr.txt"
    with open(log, "w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "facecap", "batch", str(batch), "--jobs", "1"], cwd=tmp_path,
                                stdout=subprocess.PIPE, stderr=err, text=True)
        pid = wait_for(lambda: running(tmp_path / "facecap-batch.json", "take_long"), "take_long to run")
        time.sleep(1.0)  # inside the take (reading or solving), not starting Blender
        os.kill(pid, signal.SIGKILL)
        out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 1, log.read_text()
    _, takes = summary(tmp_path / "facecap-batch.json")
    error = takes["take_long"]["error"]
    assert takes["take_long"]["status"] == "failed" and f"pid {pid}) was killed by SIGKILL (signal 9)" in error
    assert takes["take_s0"]["status"] == takes["take_s1"]["status"] == "ok"
    assert takes["take_s0"]["worker"] != takes["take_long"]["worker"]  # a new worker took over
    assert not (tmp_path / "out" / "take_long.csv").exists() and (tmp_path / "out" / "take_s1.csv").is_file()
    assert "Traceback" not in log.read_text()


def test_ctrl_c_keeps_finished_takes_and_leaves_nothing_half_written(tmp_path):
    batch = long_shoot(tmp_path, shorts=3)
    log = tmp_path / "stderr.txt"
    with open(log, "w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "facecap", "batch", str(batch), "--jobs", "2"], cwd=tmp_path,
                                stdout=subprocess.PIPE, stderr=err, text=True)
        wait_for(lambda: running(tmp_path / "facecap-batch.json", "take_long") and "] ok take_s" in log.read_text(),
                 "a short take done while the long one runs")
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=300)
    text = log.read_text()
    assert proc.returncode == 130, text
    assert "batch cancelled" in text and "Traceback" not in text
    data, takes = summary(tmp_path / "facecap-batch.json")
    assert data["status"] == "cancelled"
    assert takes["take_long"]["status"] == "cancelled"
    assert "not finished were not written" in takes["take_long"]["error"]
    done = [n for n, t in takes.items() if t["status"] == "ok"]
    assert done and all((tmp_path / "out" / f"{n}.blend").is_file() for n in done)
    assert {t["status"] for t in takes.values()} <= {"ok", "cancelled"}
    assert not (tmp_path / "out" / "take_long.csv").exists() and not (tmp_path / "out" / "take_long.blend").exists()
    assert not no_temporaries(tmp_path)
    pids = {int(t["worker"].rsplit(" ", 1)[1]) for t in takes.values() if t["worker"]}
    assert pids and not [p for p in pids if alive(p)]  # no worker outlives the batch


def alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"


def test_two_takes_writing_one_file_are_refused_before_any_work(tmp_path):
    from batch_shoot import batch_file

    good = {k: GOOD[k] for k in ("take_a", "take_c")}
    shoot(tmp_path, good=good, broken=False)
    batch = batch_file(tmp_path, outputs={"weights": "out/weights.csv"})  # no {take}: one file for both
    proc = facecap("batch", batch, cwd=tmp_path)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines()[-1] == (
        f"facecap: error: {tmp_path / 'takes' / 'take_c.toml'}: takes 'take_a' [output.weights] and 'take_c' "
        f"[output.weights] write the same file ({tmp_path / 'out' / 'weights.csv'}): one would be lost")
    assert not (tmp_path / "out").exists() and not (tmp_path / "facecap-batch.json").exists()


def test_the_blender_script_entry_runs_a_batch(tmp_path):
    """``blender -b -P facecap_addon/cli.py -- batch ...`` runs cli.py as a script; so do we."""
    batch = shoot(tmp_path, good={"take_a": GOOD["take_a"]}, broken=False)
    proc = subprocess.run([sys.executable, str(ROOT / "facecap_addon" / "cli.py"), "--", "batch", str(batch),
                           "--jobs", "1", "--summary", "s.json"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    _, takes = summary(tmp_path / "s.json")
    assert takes["take_a"]["status"] == "ok" and (tmp_path / "out" / "take_a.blend").is_file()


def test_review_pages_share_one_plotly_and_the_index_links_them(tmp_path):
    """Takes with [output] html: one plotly.min.js beside their pages, and the index page beside the
    summary lists every take (the failed one with its error) and links each page."""
    good = {k: GOOD[k] for k in ("take_a", "take_c")}
    shoot(tmp_path, good)
    batch = tmp_path / "batch.toml"
    text = batch.read_text().replace('report = "out/{take}.json"\n', 'report = "out/{take}.json"\nhtml = "out/{take}.html"\n')
    batch.write_text(text)
    proc = facecap("batch", batch, "--jobs", "2", "--summary", tmp_path / "summary.json", cwd=tmp_path)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    out = tmp_path / "out"
    pages = sorted(p.name for p in out.glob("*.html"))
    assert pages == ["take_a.html", "take_c.html"]
    assert (out / "plotly.min.js").stat().st_size > 1_000_000
    for page in pages:  # loaded from beside the page, not embedded
        text = (out / page).read_text()
        assert 'src="plotly.min.js"' in text and len(text) < 3_000_000
    index = (tmp_path / "summary.html").read_text()
    assert 'href="out/take_a.html"' in index and 'href="out/take_c.html"' in index
    assert "take_missing" in index and "not_there.csv: file not found" in index
    assert "review pages:" in proc.stdout
