"""Kill-and-resume through the real CLI, and a study on a separately started dask cluster."""

import os
import socket
import subprocess
import sys

import pytest
import xarray as xr

import uqflow
from uqflow.cli import main

from ._common import comparable, run_and_kill, uqflow_cli


# In process; the same under 2 dask workers (the CLI and its workers killed as one group) is
# test_stopping.py::test_the_issue_case_is_identical_for_workers_0_and_2_and_after_a_kill
@pytest.mark.slow
def test_killed_study_resumes_to_the_uninterrupted_result(write_study, capsys):
    # 600 realizations of 5 ms each in batches of 300, checkpointed every 0.2 s: about 3 s
    # of work.
    execution = "workers = 0\nbatch = 300\ncheckpoint_interval = 0.2\nseed = 11"
    scene = '{ model = "ishigami", delay = 0.005 }'
    method = 'kind = "monte-carlo"\nsamples = 600\nrule = "lhs"'
    killed = write_study(name="killed", scene=scene, method=method, execution=execution)
    whole = write_study(name="whole", scene=scene, method=method, execution=execution)
    result = killed.parent / "out" / "killed.nc"

    runs, attrs = run_and_kill(killed, result, at_least=100)
    assert attrs["complete"] == 0
    finished = int((runs["status"].values == "ok").sum())
    # Killed inside the first batches of 300: what finished reached the file anyway.
    assert 100 <= finished < 300

    # the rest in this process: the kill is what needs a process of its own
    assert main(["run", str(killed), "--resume", "--quiet", "--no-figures"]) == 0
    assert f"resumed: {finished} realizations were already done" in capsys.readouterr().out
    assert main(["run", str(whole), "--quiet", "--no-figures"]) == 0

    runs_k, stats_k = comparable(result)
    runs_w, stats_w = comparable(whole.parent / "out" / "whole.nc")
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
        cmd = uqflow_cli("run", str(remote), "--scheduler", address, "--quiet", "--no-figures")
        out, err = cmd.communicate(timeout=300)
        assert cmd.returncode == 0, err
        assert main(["run", str(local), "--quiet", "--no-figures"]) == 0

        runs_r, stats_r = comparable(remote.parent / "out" / "remote.nc")
        runs_l, stats_l = comparable(remote.parent / "out" / "local.nc")
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
