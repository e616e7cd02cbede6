"""``uqflow run -o/--output``, scheduler addresses that cannot be used, and the last line of
defence against tracebacks (issue 8, points 8 and 10, and the exit codes of uqflow.cli)."""

import socket

import pytest

import uqflow
from uqflow.cli import EXIT_INTERNAL, main

SMALL = 'kind = "monte-carlo"\nsamples = 64\nrule = "lhs"'


def _cli(capsys, *args):
    code = main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err.strip()


def test_output_overrides_the_study_path_with_figures_beside_it(write_study, tmp_path, capsys):
    study = write_study(method=SMALL, output='path = "out/s.nc"\nfigures = true')
    target = tmp_path / "elsewhere" / "mine.nc"
    code, out, err = _cli(capsys, "run", study, "--output", target, "--quiet")
    assert code == 0, err
    assert f"result: {target}" in out
    assert uqflow.open_result(target).attrs["complete"] == 1
    figures = sorted(p.name for p in (tmp_path / "elsewhere" / "mine_figures").iterdir())
    # a scalar output's histogram and exceedance curve (the report's choice, docs/results.md)
    assert {"y_histogram.png", "y_exceedance.png"} <= set(figures)
    assert not (tmp_path / "out").exists()  # the study's own path is left alone

    code, out, _ = _cli(capsys, "report", target, "--no-figures")
    assert code == 0 and "monte-carlo, complete" in out

    # --resume and --force apply to the path given, not to the study's.
    code, _, err = _cli(capsys, "run", study, "-o", target, "--quiet", "--no-figures")
    assert code == 2 and f"--output: {target}: exists" in err
    code, out, _ = _cli(capsys, "run", study, "-o", target, "--resume", "--quiet",
                        "--no-figures")
    assert code == 0 and "resumed: 64 realizations were already done" in out
    code, out, _ = _cli(capsys, "run", study, "-o", target, "--force", "--quiet",
                        "--no-figures")
    assert code == 0 and "resumed" not in out
    assert not (tmp_path / "out").exists()


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("address, says", [
    ("tcp://127.0.0.1:notaport", "is not a scheduler address"),
    ("nothing-like-an-address", "is not a scheduler address"),
    ("carrier-pigeon://127.0.0.1:8786", "is not a scheduler address"),
    ("tcp://127.0.0.1:99999", "is not a scheduler address"),
    (None, "cannot reach dask scheduler"),
])
def test_an_unusable_scheduler_is_one_line_and_exit_2(write_study, tmp_path, capsys,
                                                      monkeypatch, address, says):
    monkeypatch.setattr("uqflow.execute.CONNECT_TIMEOUT_S", 1.0)
    address = address or f"tcp://127.0.0.1:{_free_port()}"  # nobody listens there
    study = write_study(method=SMALL)
    code, _, err = _cli(capsys, "run", study, "--scheduler", address, "--quiet")
    assert code == 2
    assert err.count("\n") == 0
    assert err.startswith("uqflow: error: --scheduler: ") and says in err and address in err
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_a_bug_is_one_line_with_the_debug_hint_and_exit_3(write_study, capsys, monkeypatch):
    def broken(*args, **kw):
        raise ZeroDivisionError("division by zero\nsecond line")

    monkeypatch.setattr("uqflow.execute.run_study", broken)
    study = write_study(method=SMALL)
    monkeypatch.delenv("UQFLOW_DEBUG", raising=False)
    code, _, err = _cli(capsys, "run", study, "--quiet")
    assert code == EXIT_INTERNAL == 3
    assert err == ("uqflow: internal error: ZeroDivisionError: division by zero second line "
                   "(a bug: rerun with UQFLOW_DEBUG=1 for the traceback and report it)")
    monkeypatch.setenv("UQFLOW_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        main(["run", str(study), "--quiet"])


def test_a_scheduler_in_the_study_is_named_by_its_key(write_study, tmp_path, capsys):
    study = write_study(method=SMALL, execution='scheduler = "tcp://127.0.0.1:notaport"')
    code, _, err = _cli(capsys, "run", study, "--quiet")
    assert code == 2 and err.count("\n") == 0
    assert err.startswith(f"uqflow: error: {study}: execution.scheduler: ")
    assert not (tmp_path / "out").exists()


def test_a_dask_task_that_dies_stops_the_study_with_exit_1(write_study, tmp_path, capsys,
                                                           monkeypatch):
    from dask.distributed import LocalCluster

    def unbuildable(solver_class, scene):  # a worker without the solver's package, say
        raise ImportError("No module named 'solvers'")

    # Threads in this process, so the patched worker function is the one the tasks call.
    monkeypatch.setattr("uqflow.execute._worker_solver", unbuildable)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=":0") as cluster:
        study = write_study(method=SMALL)
        code, _, err = _cli(capsys, "run", study, "--scheduler", cluster.scheduler_address,
                            "--quiet")
    assert code == 1 and err.count("\n") == 0
    assert "a dask task failed (ImportError: No module named 'solvers')" in err
    assert uqflow.open_result(tmp_path / "out" / "s.nc").attrs["complete"] == 0


@pytest.mark.parametrize("workers", ["-1", "513"])
def test_workers_out_of_range_on_the_command_line_is_one_line_and_exit_2(
        write_study, tmp_path, capsys, workers):
    study = write_study(method=SMALL, output='path = "out/s.nc"')
    code, out, err = _cli(capsys, "run", study, "--workers", workers, "--quiet")
    assert code == 2 and err.count("\n") == 0
    assert err.startswith("uqflow: error: --workers: must be between 0 and 512")
    assert not (tmp_path / "out").exists()
