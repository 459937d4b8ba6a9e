"""``batch --scheduler`` on a real Dask cluster: a scheduler and two workers on loopback (subprocesses, as a
studio starts them), a shoot with a broken take run through it, outputs checked against a single
``retarget``, the broken take named with its reason."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from batch_shoot import GOOD, facecap, shoot, standalone, summary

pytestmark = pytest.mark.slow


def require_distributed():
    """Dask distributed, or a skip; in CI (FACECAP_CI=1) its absence is a failure, not a skip."""
    try:
        import distributed
    except ImportError:
        if os.environ.get("FACECAP_CI"):
            pytest.fail("dask[distributed] is not installed: the test extra must install it (pyproject.toml)")
        pytest.skip("dask[distributed] is not installed (pip install -e '.[farm]')")
    return distributed


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """(scheduler address, worker processes): `dask scheduler` and two `dask worker`s on 127.0.0.1."""
    distributed = require_distributed()
    folder = tmp_path_factory.mktemp("dask")
    file = folder / "scheduler.json"
    logs = [open(folder / name, "w") for name in ("scheduler.log", "worker1.log", "worker2.log")]
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                               "--port", "0", "--dashboard-address", ":0", "--scheduler-file", str(file)],
                              stdout=logs[0], stderr=subprocess.STDOUT, cwd=folder)]
    try:
        deadline = time.monotonic() + 120
        while not file.exists() and time.monotonic() < deadline:
            assert procs[0].poll() is None, (folder / "scheduler.log").read_text()
            time.sleep(0.2)
        address = json.loads(file.read_text())["address"]
        for i in (1, 2):
            procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads",
                                           "1", "--name", f"node{i}", "--no-dashboard"],
                                          stdout=logs[i], stderr=subprocess.STDOUT, cwd=folder))
        with distributed.Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=180)
        yield address, procs
    finally:
        for proc in reversed(procs):
            proc.send_signal(signal.SIGTERM)
        for proc in reversed(procs):
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for log in logs:
            log.close()


def test_a_shoot_runs_on_a_dask_cluster(cluster, tmp_path):
    address, procs = cluster
    good = {k: GOOD[k] for k in ("take_a", "take_c", "take_d")}
    batch = shoot(tmp_path, good=good, broken=True)
    single = subprocess.Popen([sys.executable, "-m", "facecap", "retarget", "--config",
                               str(standalone(tmp_path, "take_c", tmp_path / "single_out"))],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    proc = facecap("batch", batch, "--scheduler", address, cwd=tmp_path)
    assert single.wait(timeout=600) == 0, single.stderr.read()
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    data, takes = summary(tmp_path / "facecap-batch.json")
    assert data["scheduler"] == address and data["counts"]["ok"] == 3 and data["counts"]["failed"] == 2
    for name, (frames, _, _) in good.items():
        t = takes[name]
        assert t["status"] == "ok" and t["frames"] == frames, t
        assert t["worker"].startswith("tcp://127.0.0.1:")  # the Dask worker that ran it, and its facecap process
        assert all(Path(t["outputs"][k]).is_file() for k in ("blend", "weights", "report"))
    # the farm's result is the single run's, to the bit
    assert (tmp_path / "out" / "take_c.csv").read_bytes() == (tmp_path / "single_out" / "take_c.csv").read_bytes()
    # the broken takes: one found on a farm node (its markers file is missing), one when the configs were read
    assert takes["take_missing"]["status"] == "failed"
    assert takes["take_missing"]["error"].endswith("captures/not_there.csv: file not found")
    assert takes["take_missing"]["worker"].startswith("tcp://127.0.0.1:")
    assert "[solve.regularisation] expected a number >= 0" in takes["take_badvalue"]["error"]
    assert "facecap: [4/4]" in proc.stderr
    assert all(p.poll() is None for p in procs)  # the cluster is still up


def test_an_unreachable_scheduler_is_one_line(tmp_path):
    require_distributed()
    batch = shoot(tmp_path, good={"take_a": GOOD["take_a"]}, broken=False)
    env = {**os.environ, "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "3s"}  # Dask's own setting
    proc = facecap("batch", batch, "--scheduler", "tcp://127.0.0.1:9", cwd=tmp_path, env=env)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines()[-1].startswith("facecap: error: cannot reach the Dask scheduler at "
                                                           "tcp://127.0.0.1:9")
    assert "Traceback" not in proc.stderr
