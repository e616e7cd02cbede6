"""Kill-and-resume through the real CLI, and a study on a separately started dask cluster."""

import os
import signal
import socket
import subprocess
import sys
import time

import pytest
import xarray as xr

import uqflow
from uqflow.store import read_runs


def _comparable(path):
    tree = uqflow.open_result(path)
    runs = tree["runs"].to_dataset().drop_vars("wall_time")
    stats = tree["statistics"].to_dataset()
    stats.attrs.pop("solver_wall_time")
    return runs, stats


def _uqflow(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "uqflow.cli", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


@pytest.mark.slow
@pytest.mark.parametrize("workers", [0, 2])
def test_killed_study_resumes_to_the_uninterrupted_result(write_study, workers):
    # 600 realizations of 5 ms each in batches of 300, checkpointed every 0.2 s: about 3 s
    # of work.
    execution = f"workers = {workers}\nbatch = 300\ncheckpoint_interval = 0.2\nseed = 11"
    scene = '{ model = "ishigami", delay = 0.005 }'
    method = 'kind = "monte-carlo"\nsamples = 600\nrule = "lhs"'
    killed = write_study(name="killed", scene=scene, method=method, execution=execution)
    whole = write_study(name="whole", scene=scene, method=method, execution=execution)
    result = killed.parent / "out" / "killed.nc"

    proc = _uqflow("run", str(killed), "--quiet", start_new_session=True)
    deadline = time.monotonic() + 120
    done = 0
    while time.monotonic() < deadline and proc.poll() is None:
        if result.exists():
            runs, _ = read_runs(result)
            done = int((runs["status"].values == "ok").sum())
            if done >= 100:
                break
        time.sleep(0.05)
    assert proc.poll() is None, f"the study ended before it could be killed: {proc.stderr.read()}"
    os.killpg(proc.pid, signal.SIGKILL)  # the whole group: CLI and its dask workers
    proc.wait()
    runs, attrs = read_runs(result)
    assert attrs["complete"] == 0
    finished = int((runs["status"].values == "ok").sum())
    # Killed inside the first batches of 300: what finished reached the file anyway.
    assert 100 <= finished < 300

    resumed = _uqflow("run", str(killed), "--resume", "--quiet", "--no-figures")
    out, err = resumed.communicate(timeout=300)
    assert resumed.returncode == 0, err
    assert f"resumed: {finished} realizations were already done" in out

    plain = _uqflow("run", str(whole), "--quiet", "--no-figures")
    _, err = plain.communicate(timeout=300)
    assert plain.returncode == 0, err

    runs_k, stats_k = _comparable(result)
    runs_w, stats_w = _comparable(whole.parent / "out" / "whole.nc")
    xr.testing.assert_identical(runs_k, runs_w)
    xr.testing.assert_identical(stats_k, stats_w)


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_study_on_an_existing_dask_cluster(write_study):
    from dask.distributed import Client

    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, DASK_DISTRIBUTED__WORKER__DAEMON="False")
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler",
                               "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, env=env)]
    try:
        for _ in range(2):
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
                 "--no-dashboard", "--no-nanny"],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env))
        with Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=60)
            n_workers = len(client.scheduler_info()["workers"])
        assert n_workers == 2

        remote = write_study(name="remote", execution="seed = 5\nbatch = 32")
        local = write_study(name="local", execution="workers = 0\nseed = 5\nbatch = 32")
        cmd = _uqflow("run", str(remote), "--scheduler", address, "--quiet", "--no-figures")
        out, err = cmd.communicate(timeout=300)
        assert cmd.returncode == 0, err
        assert cmd.returncode == 0
        cmd = _uqflow("run", str(local), "--quiet", "--no-figures")
        cmd.communicate(timeout=300)

        runs_r, stats_r = _comparable(remote.parent / "out" / "remote.nc")
        runs_l, stats_l = _comparable(remote.parent / "out" / "local.nc")
        xr.testing.assert_identical(runs_r, runs_l)
        xr.testing.assert_identical(stats_r, stats_l)
        assert uqflow.open_result(remote.parent / "out" / "remote.nc").attrs["workers"] == \
            f"scheduler {address}"
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
