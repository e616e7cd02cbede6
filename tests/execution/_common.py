"""Helpers shared by the execution tests: comparing results, running the real CLI."""

import os
import signal
import subprocess
import sys
import time

import uqflow
from uqflow.store import read_runs


def comparable(path):
    """The runs and statistics of a result, without what may differ between equal runs
    (wall times)."""
    tree = uqflow.open_result(path)
    runs = tree["runs"].to_dataset().drop_vars("wall_time")
    stats = tree["statistics"].to_dataset()
    stats.attrs.pop("solver_wall_time")
    return runs, stats


def uqflow_cli(*args, **kw):
    """``uqflow ARGS`` as a child process (text pipes)."""
    return subprocess.Popen([sys.executable, "-m", "uqflow.cli", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def run_and_kill(study, result, at_least):
    """Start ``uqflow run STUDY`` and SIGKILL it (with its dask workers) as soon as the
    result file holds ``at_least`` finished realizations; returns the runs and root
    attributes left on disk."""
    proc = uqflow_cli("run", study, "--quiet", start_new_session=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if result.exists() and (read_runs(result)[0]["status"].values == "ok").sum() >= at_least:
            break
        time.sleep(0.05)
    assert proc.poll() is None, f"the study ended before it could be killed: {proc.stderr.read()}"
    os.killpg(proc.pid, signal.SIGKILL)  # the whole group: CLI and its dask workers
    proc.wait()
    return read_runs(result)
