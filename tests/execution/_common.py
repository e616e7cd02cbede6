"""Helpers shared by the execution tests: comparing results, running the real CLI."""

import subprocess
import sys

import uqflow


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
