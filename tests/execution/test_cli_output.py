"""The installed ``uqflow`` command as a user meets it: a closed output pipe, argument mistakes,
``--version`` and the help of positional arguments (issue 16, Found 4 and 6)."""

import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest

from uqflow.cli import _parser, main
from uqflow.store import open_result

UQFLOW = Path(sys.executable).with_name("uqflow")  # the console script of this environment
EXIT_BROKEN_PIPE = 128 + 13  # the shell's code for a process ended by SIGPIPE (signal 13)
SMALL = 'kind = "monte-carlo"\nsamples = 16\nrule = "lhs"'


def run_uqflow(*args, **kw):
    return subprocess.run([str(UQFLOW), *map(str, args)], capture_output=True, text=True,
                          timeout=300, **kw)


def _closed_stdout(*args, cwd=None):
    """Run ``uqflow ARGS`` with its stdout a pipe whose reader has already gone."""
    proc = subprocess.Popen([str(UQFLOW), *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=cwd)
    proc.stdout.close()  # as `| head` does once it has its lines
    err = proc.stderr.read()
    return proc.wait(timeout=300), err


def test_a_closed_pipe_ends_list_and_run_quietly_with_exit_141(write_study, tmp_path):
    code, err = _closed_stdout("list")
    assert (code, err) == (EXIT_BROKEN_PIPE, "")

    study = write_study(method=SMALL)
    code, err = _closed_stdout("run", study, "--quiet")
    assert (code, err) == (EXIT_BROKEN_PIPE, "")
    # The summary was cut short, not the study: the result is complete.
    assert open_result(tmp_path / "out" / "s.nc").attrs["complete"] == 1


@pytest.mark.parametrize("args, line", [
    (["--workers", "abc"], "uqflow: error: --workers: invalid int value: 'abc'"),
    (["--resume", "--force"], "uqflow: error: --force: not allowed with argument --resume"),
    (["--output"], "uqflow: error: --output: expected one argument"),
    (["--bogus"], "uqflow: error: unrecognized arguments: --bogus"),
])
def test_an_argument_mistake_is_one_line_and_exit_2(write_study, tmp_path, capsys, args,
                                                    line):
    study = write_study(method=SMALL)
    with pytest.raises(SystemExit) as stop:
        main(["run", str(study), *args])
    captured = capsys.readouterr()
    assert stop.value.code == 2 and captured.out == ""
    assert captured.err.count("\n") == 1 and captured.err.startswith(line), captured.err
    assert not (tmp_path / "out").exists()


def test_the_installed_command_has_version_and_one_line_argument_errors(write_study):
    done = run_uqflow("--version")
    assert (done.returncode, done.stdout) == (0, f"uqflow {version('uqflow')}\n")
    done = run_uqflow("run", write_study(method=SMALL), "--workers", "abc")
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr == "uqflow: error: --workers: invalid int value: 'abc' " \
                          "(see uqflow run --help)\n"


def test_every_positional_argument_has_help():
    commands = next(a for a in _parser()._actions if a.dest == "command").choices
    positionals = [(name, action) for name, parser in commands.items()
                   for action in parser._actions if not action.option_strings]
    assert {name for name, _ in positionals} == {"run", "validate", "report", "serve"}
    for name, action in positionals:
        assert action.help and len(action.help.split()) >= 3, (name, action.dest)


def test_the_command_line_starts_without_the_numerical_stack():
    """`uqflow --version`/`--help` answer at once, and a Ctrl-C while scipy, xarray or chaospy
    load lands inside main's handler (one line), not in an import before it (a traceback)."""
    code = ("import sys, uqflow.cli; "
            "print(' '.join(m for m in ('numpy', 'scipy', 'xarray', 'chaospy', 'dask', 'numba')"
            " if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True).stdout.strip()
    assert loaded == ""


def test_an_interrupt_in_another_command_says_nothing_of_resume(monkeypatch, capsys):
    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr("uqflow.cli._list", interrupted)
    assert main(["list"]) == 130
    assert capsys.readouterr().err == "uqflow: interrupted\n"
