"""What a run leaves on disk whatever happens: an empty design refused before any write, no
temporary file after any error, one writer per result (its lock file), a study text too large
to store, and ``report``'s one-line errors about the files it reads and writes (issue 16,
Found 4 and 6)."""

import hashlib
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from uqflow.cli import main
from uqflow.store import open_result, write_result

UQFLOW = Path(sys.executable).with_name("uqflow")  # the console script of this environment
SMALL = 'kind = "monte-carlo"\nsamples = 16\nrule = "lhs"'

# The README's third-party method (docs: "A new propagation method"), installed the way a
# package would be: a module and its entry point in a .dist-info folder on the path.
ANTITHETIC = '''\
import numpy as np
import xarray as xr

import uqflow
from uqflow.methods.base import (MethodOptions, PropagationMethod, finish_statistics,
                                 make_design, ok_mask, output_names)


class Options(MethodOptions):
    pairs: int = 100


@uqflow.register_method("antithetic")
class Antithetic(PropagationMethod):
    """Antithetic Monte Carlo: every point u comes with 1 - u."""
    Options = Options

    def plan(self, space, fields, seed):
        u = np.random.default_rng(seed).random((self.options.pairs, len(space)))
        return make_design(space, space.from_unit_hypercube(np.vstack([u, 1 - u])))

    def analyze(self, design, runs):
        ok = ok_mask(runs)
        data = {o: (("statistic",), [runs[o].values[ok].mean()]) for o in output_names(runs)}
        return finish_statistics(xr.Dataset(data, coords={"statistic": ["mean"]}),
                                 design, runs, self.name, [])
'''


def _install_antithetic(folder: Path) -> dict:
    """The environment of a process in which the 'antithetic' method is installed."""
    (folder / "antithetic_method.py").write_text(ANTITHETIC)
    info = folder / "antithetic_method-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: antithetic-method\n"
                                   "Version: 0.1\n")
    (info / "entry_points.txt").write_text("[uqflow.methods]\n"
                                           "antithetic = antithetic_method:Antithetic\n")
    return {**os.environ, "PYTHONPATH": os.pathsep.join(
        filter(None, [str(folder), os.environ.get("PYTHONPATH")]))}


def test_an_empty_design_is_one_line_before_anything_is_written(write_study, tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    env = _install_antithetic(site)
    study = write_study(name="zero_pairs", method='kind = "antithetic"\npairs = 0')
    done = subprocess.run([str(UQFLOW), "run", study, "--quiet"], capture_output=True,
                          text=True, timeout=300, env=env)
    assert done.returncode == 2, done.stderr
    assert done.stderr == (f"uqflow: error: {study}: method: the 'antithetic' method's design "
                           f"has no realizations with these options; nothing to run\n")
    assert not (tmp_path / "out").exists()  # no result, no .tmp, no lock, no folder


def test_a_write_stopped_by_any_error_leaves_no_temporary_file(tmp_path, monkeypatch):
    runs = xr.Dataset({"status": ("realization", np.array(["ok"], dtype=object)),
                       "y": ("realization", [1.0])})
    write_result(tmp_path / "r.nc", runs, None, {"complete": 0})
    before = (tmp_path / "r.nc").read_bytes()
    original = xr.DataTree.to_netcdf

    def written_then(error):
        def write(self, path, **kw):  # the file exists, then the writer gives up
            original(self, path, **kw)
            raise error
        return write

    for error in (TypeError("a value netCDF cannot hold"), KeyboardInterrupt()):
        monkeypatch.setattr(xr.DataTree, "to_netcdf", written_then(error))
        with pytest.raises(type(error)):
            write_result(tmp_path / "r.nc", runs, None, {"complete": 1})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.nc"]
    assert (tmp_path / "r.nc").read_bytes() == before  # the last checkpoint is untouched


def test_a_second_run_of_the_same_result_is_refused_naming_the_writer(write_study, tmp_path,
                                                                      capsys):
    # 8 runs of 0.25 s: the first run holds the lock for about 2 s after its start-up
    study = write_study(scene='{ model = "ishigami", delay = 0.25 }',
                        method='kind = "monte-carlo"\nsamples = 8\nrule = "lhs"')
    result, lock = tmp_path / "out" / "s.nc", tmp_path / "out" / "s.nc.lock"
    first = subprocess.Popen([str(UQFLOW), "run", study, "--quiet"], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        while not (lock.exists() and lock.read_text()) and first.poll() is None:
            time.sleep(0.01)
        assert lock.read_text() == f"{first.pid} {socket.gethostname()}\n"
        for mode in ("--force", "--resume"):
            assert main(["run", str(study), "--quiet", mode]) == 2
            err = capsys.readouterr().err
            assert err == (f"uqflow: error: {study}: output.path: {result}: another uqflow run "
                           f"(pid {first.pid} on {socket.gethostname()}) is writing this "
                           f"result; wait for it to end (if no run is going on, delete "
                           f"{lock})\n")
    finally:
        out, err = first.communicate(timeout=300)
    assert first.returncode == 0, err
    assert open_result(result).attrs["complete"] == 1
    assert sorted(p.name for p in result.parent.iterdir()) == ["s.nc"]  # the lock is gone


def test_a_lock_left_by_a_killed_run_is_taken_over_with_a_note(write_study, tmp_path, capsys):
    study = write_study(method=SMALL)
    lock = tmp_path / "out" / "s.nc.lock"
    lock.parent.mkdir()
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # its pid now names no process (until the system hands it out again)
    lock.write_text(f"{gone.pid} {socket.gethostname()}\n")
    assert main(["run", str(study), "--quiet"]) == 0
    assert capsys.readouterr().err == (f"uqflow: note: {lock}: took over the lock of pid "
                                       f"{gone.pid}, which is no longer running (a run that "
                                       f"was killed)\n")
    assert not lock.exists()

    # On another host the pid says nothing about the writer: refused, not taken over.
    lock.write_text(f"{gone.pid} elsewhere.example\n")
    assert main(["run", str(study), "--quiet", "--force"]) == 2
    assert f"(pid {gone.pid} on elsewhere.example) is writing this result" in \
        capsys.readouterr().err
    assert lock.read_text() == f"{gone.pid} elsewhere.example\n"


def test_the_lock_goes_when_a_run_ends_in_an_error(write_study, tmp_path, capsys,
                                                   monkeypatch):
    def broken(*args, **kw):
        raise ZeroDivisionError("a bug in a solver outside a realization")

    monkeypatch.setattr("uqflow.execute.run_batch", broken)
    study = write_study(method=SMALL)
    assert main(["run", str(study), "--quiet"]) == 3
    assert "internal error: ZeroDivisionError" in capsys.readouterr().err
    # the first checkpoint (all pending) stays, for --resume; nothing else
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["s.nc"]


def test_a_study_text_over_a_mebibyte_is_stored_by_its_hash_alone(write_study, tmp_path,
                                                                  capsys):
    comment = "# " + "x" * 97 + "\n"  # 100 bytes a line
    study = write_study(method=SMALL, body="\n" + comment * 11_000)  # 1.1 MB
    assert main(["run", str(study), "--quiet"]) == 0
    result = tmp_path / "out" / "s.nc"
    attrs = open_result(result).attrs
    assert "study" not in attrs
    assert attrs["study_text_omitted"].startswith("the study text (11")
    assert "larger than 1048576 bytes" in attrs["study_text_omitted"]
    assert attrs["study_text_sha256"] == hashlib.sha256(study.read_bytes()).hexdigest()
    assert result.stat().st_size < 200_000  # 16 runs of one output, no megabyte of text
    # the hashes alone still identify the study for a resume
    assert main(["run", str(study), "--quiet", "--resume"]) == 0
    assert "resumed: 16 realizations were already done" in capsys.readouterr().out

    small = write_study(name="small", method=SMALL)
    assert main(["run", str(small), "--quiet"]) == 0
    attrs = open_result(tmp_path / "out" / "small.nc").attrs
    assert attrs["study"] == small.read_text() and "study_text_omitted" not in attrs


@pytest.fixture
def small_result(write_study, tmp_path, capsys):
    study = write_study(method=SMALL)
    assert main(["run", str(study), "--quiet"]) == 0
    capsys.readouterr()
    return tmp_path / "out" / "s.nc"


def _report(capsys, *args):
    code = main(["report", *map(str, args)])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_report_refuses_a_file_as_figures_folder_in_one_line(small_result, tmp_path, capsys):
    taken = tmp_path / "notes.txt"
    taken.write_text("mine")
    code, out, err = _report(capsys, small_result, "--figures", taken)
    assert (code, out) == (2, "")
    assert err == f"uqflow: error: --figures: {taken}: is a file, not a folder for the figures\n"
    assert taken.read_text() == "mine"


def test_report_beside_a_result_it_cannot_write_prints_the_table_then_one_line(
        small_result, capsys, monkeypatch):
    folder = small_result.with_name("s_figures")
    mkdir = Path.mkdir

    def read_only(self, *args, **kw):  # as in a folder without write permission
        if self == folder:
            raise PermissionError(13, "Permission denied", str(self))
        return mkdir(self, *args, **kw)

    monkeypatch.setattr(Path, "mkdir", read_only)
    code, out, err = _report(capsys, small_result)
    assert code == 2
    assert "study 's' (monte-carlo, complete)" in out and "figure:" not in out
    assert err == (f"uqflow: error: {folder}: cannot write the figures: Permission denied "
                   f"(the tables above are complete; choose a folder with --figures or leave "
                   f"them out with --no-figures)\n")


def test_report_on_a_netcdf_file_that_is_not_a_result_names_it(tmp_path, capsys):
    other = tmp_path / "other.nc"
    xr.Dataset({"a": ("x", np.arange(3.0))}).to_netcdf(other)
    code, out, err = _report(capsys, other)
    assert (code, out) == (2, "")
    assert err == (f"uqflow: error: {other}: has neither a 'runs' nor a 'statistics' group: "
                   f"not a uqflow result file\n")

