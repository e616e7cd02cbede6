"""Compiling before the first run (uqflow/warm_up.py): a solver's shares of compilation spread
over this process and a subprocess, or over the dask workers, before any realization; the cost
recorded in the result and its summary (issue 19)."""

from __future__ import annotations

import os
import textwrap

import pytest

import uqflow
from uqflow.execute import run_study
from uqflow.layout import WARM_UP_PROCESSES
from uqflow.report.summary import summary_table
from uqflow.study import load_study

# A solver whose "compilation" leaves a marker per share (which share, of how many, in which
# process, when), and whose runs leave one each: written to a file so that the warm-up's
# subprocess and dask's workers, which import it by name, find it.
RECORDER = textwrap.dedent('''
    import os, time
    from pathlib import Path

    import xarray as xr

    from uqflow.solver import Solver


    class ShareRecorder(Solver):
        name = "share-recorder-test"

        def __init__(self, folder, shares, fail):
            self.folder, self.shares, self.fail = Path(folder), shares, fail

        @classmethod
        def from_scene(cls, scene):
            return cls(scene["folder"], scene["shares"], scene.get("fail", False))

        def nominal(self):
            return {"x": 1.0}

        def outputs(self):
            return xr.Dataset({"y": ((), 0.0)})

        def _mark(self, what):
            (self.folder / f"{time.time_ns()}-{what}-pid{os.getpid()}").touch()

        def run(self, params, fields=None):
            self._mark("run")
            return xr.Dataset({"y": ((), params["x"])})

        def compile_shares(self):
            return self.shares

        def warm_up(self, part, parts):
            self._mark(f"share{part}of{parts}")
            if self.fail:
                raise RuntimeError("cannot compile")
''')


@pytest.fixture
def recorder(tmp_path, monkeypatch):
    """(study writer, marker folder): the recorder solver importable here, in subprocesses
    and in dask's workers."""
    (tmp_path / "share_recorder_test.py").write_text(RECORDER)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(
        [str(tmp_path), *filter(None, [os.environ.get("PYTHONPATH")])]))
    import share_recorder_test
    if "share-recorder-test" not in uqflow.solver.solver_registry.names():
        uqflow.register_solver("share-recorder-test")(share_recorder_test.ShareRecorder)
    marks = tmp_path / "marks"
    marks.mkdir()

    def write(shares, workers, fail=False):
        path = tmp_path / f"s{shares}w{workers}.toml"
        path.write_text(textwrap.dedent(f"""\
            name = "warm"
            solver = "share-recorder-test"
            scene = {{ folder = "{marks}", shares = {shares}, fail = {str(fail).lower()} }}
            [[inputs]]
            name = "x"
            distribution = "uniform"
            lower = 0.0
            upper = 1.0
            [method]
            kind = "monte-carlo"
            samples = 6
            [execution]
            workers = {workers}
            [output]
            path = "out/s{shares}w{workers}.nc"
            figures = false
            """))
        return path

    return write, marks


def _marks(folder):
    """[(kind, pid)] in the order they were written."""
    names = sorted(p.name for p in folder.iterdir())
    return [(kind, int(pid[3:])) for _, kind, pid in (n.split("-") for n in names)]


def test_shares_compile_here_and_in_a_subprocess_before_the_first_run(recorder):
    write, marks = recorder
    outcome = run_study(load_study(write(shares=3, workers=0)), show_progress=False)
    parts = min(3, os.cpu_count() or 1)
    seen = _marks(marks)
    shares = [(kind, pid) for kind, pid in seen if kind.startswith("share")]
    assert sorted(kind for kind, _ in shares) == [f"share{k}of{parts}" for k in range(parts)]
    assert dict(shares)[f"share0of{parts}"] == os.getpid()          # share 0 here
    assert all(pid != os.getpid() for kind, pid in shares if kind != f"share0of{parts}")
    # every share finished before the first run started
    assert sorted(kind for kind, _ in seen[:parts]) == sorted(kind for kind, _ in shares)
    assert sum(kind == "run" for kind, _ in seen) == 6
    assert outcome.attrs[WARM_UP_PROCESSES] == parts
    assert f"on {parts} process" in summary_table(uqflow.open_result(outcome.path))


def test_nothing_to_compile_starts_no_process_and_records_nothing(recorder):
    write, marks = recorder
    outcome = run_study(load_study(write(shares=0, workers=0)), show_progress=False)
    assert {kind for kind, _ in _marks(marks)} == {"run"}
    assert WARM_UP_PROCESSES not in outcome.attrs
    assert "warm-up" not in summary_table(uqflow.open_result(outcome.path))


def test_a_failed_warm_up_leaves_the_runs_to_go_on(recorder):
    # what failed in the warm-up fails again in a run, where it is recorded (here the runs
    # do not fail: the warm-up's error is not the study's)
    write, marks = recorder
    outcome = run_study(load_study(write(shares=2, workers=0, fail=True)), show_progress=False)
    assert sum(kind == "run" for kind, _ in _marks(marks)) == 6
    assert (outcome.runs["status"].values == "ok").all()
    assert WARM_UP_PROCESSES not in outcome.attrs


@pytest.mark.slow
def test_each_dask_worker_compiles_its_own_share_before_any_realization(recorder):
    write, marks = recorder
    outcome = run_study(load_study(write(shares=5, workers=2)), show_progress=False)
    seen = _marks(marks)
    shares = [(kind, pid) for kind, pid in seen if kind.startswith("share")]
    assert sorted(kind for kind, _ in shares) == ["share0of2", "share1of2"]
    assert len({pid for _, pid in shares} | {os.getpid()}) == 3     # two workers, not here
    assert sorted(kind for kind, _ in seen[:2]) == sorted(kind for kind, _ in shares)
    assert outcome.attrs[WARM_UP_PROCESSES] == 2
