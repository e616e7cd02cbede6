"""The result file under faults (issue 8, point 9): a path that cannot take a result, a disk
that fills up, a resume that must not be trusted. Each is one line on stderr, exit 2 before
anything runs or 1 mid-run, no ``*.tmp`` left behind, the last good checkpoint kept."""

import errno
import os
import tempfile

from pathlib import Path

import netCDF4
import pytest
import xarray as xr

import uqflow
from uqflow.cli import main
from uqflow.store import read_runs, runs_checksum

from ._common import comparable

SMALL = 'kind = "monte-carlo"\nsamples = 64\nrule = "lhs"'


def _read_only_folder(tmp_path):
    """A folder no one may write in: as root (for whom permissions are no obstacle) the
    read-only sysfs, else a folder without write permission."""
    if os.geteuid() != 0:
        folder = tmp_path / "locked"
        folder.mkdir()
        folder.chmod(0o500)
        return folder
    try:
        fd, probe = tempfile.mkstemp(dir="/sys")
    except OSError:
        return Path("/sys")
    os.close(fd)
    os.remove(probe)
    pytest.skip("running as root, and /sys takes writes here: no folder on this machine "
                "refuses root a file, so the refusal cannot be shown")


def _cli(capsys, *args):
    code = main([str(a) for a in args])
    err = capsys.readouterr().err.strip()
    return code, err


def _no_temporary_files(root):
    return [p for p in root.rglob("*") if p.name.endswith((".tmp", ".probe"))]


def _below_a_file(tmp_path):
    (tmp_path / "blocker").write_text("x")
    return tmp_path / "blocker" / "r.nc"


def _a_folder(tmp_path):
    (tmp_path / "dir.nc").mkdir()
    return tmp_path / "dir.nc"


def _an_existing_file(tmp_path):
    (tmp_path / "r.nc").write_bytes(b"keep")
    return tmp_path / "r.nc"


# (case, how to make the path from tmp_path, extra CLI flags, what the one line says)
BEFORE_RUNNING = [
    ("below a regular file", _below_a_file, [], "blocker is a file, not a folder"),
    ("onto a folder", _a_folder, [], "is a folder, not a result file"),
    ("onto a folder with --force", _a_folder, ["--force"], "is a folder, not a result file"),
    ("onto a folder with --resume", _a_folder, ["--resume"], "is a folder, not a result file"),
    ("in a read-only folder", lambda t: _read_only_folder(t) / "deep" / "r.nc", [],
     "cannot write in"),
    ("not a .nc path", lambda t: t / "r.txt", [], "a result file ends in .nc"),
    ("an existing result", _an_existing_file, [], "exists: add --resume"),
]


@pytest.mark.parametrize("case, make, flags, says", BEFORE_RUNNING,
                         ids=[c[0] for c in BEFORE_RUNNING])
def test_an_unusable_result_path_is_refused_before_running(write_study, tmp_path, capsys,
                                                            case, make, flags, says):
    study = write_study(method=SMALL)
    target = make(tmp_path)
    before = {p: (p.stat().st_mtime_ns, p.is_file() and p.read_bytes())
              for p in tmp_path.rglob("*") if p != study}
    code, err = _cli(capsys, "run", study, "-o", target, "--quiet", "--no-figures", *flags)
    assert code == 2, err
    assert err.count("\n") == 0 and err.startswith("uqflow: error: --output: ") and says in err
    after = {p: (p.stat().st_mtime_ns, p.is_file() and p.read_bytes())
             for p in tmp_path.rglob("*") if p != study}
    assert after == before  # nothing created, nothing changed
    assert not (tmp_path / "out").exists()


def test_the_study_output_path_is_named_as_the_key_it_came_from(write_study, tmp_path, capsys):
    (tmp_path / "out").write_text("a file where the folder should be")
    study = write_study(method=SMALL)
    code, err = _cli(capsys, "run", study, "--quiet")
    assert code == 2
    assert err == f"uqflow: error: {study}: output.path: {tmp_path / 'out' / 's.nc'}: " \
                  f"{tmp_path / 'out'} is a file, not a folder"


def _disk_fills_at(monkeypatch, call):
    """Make the netCDF writer fail with ENOSPC from its ``call``-th call on, after writing a
    partial temporary file (as a full disk does)."""
    real = xr.DataTree.to_netcdf
    calls = []

    def filling(self, path, *args, **kw):
        calls.append(path)
        if len(calls) >= call:
            with open(path, "wb") as f:
                f.write(b"\x89HDF\r\n\x1a\n partial")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(self, path, *args, **kw)

    monkeypatch.setattr(xr.DataTree, "to_netcdf", filling)
    return calls


def test_a_full_disk_at_the_first_write_is_a_user_error(write_study, tmp_path, capsys,
                                                        monkeypatch):
    study = write_study(method=SMALL)
    _disk_fills_at(monkeypatch, 1)
    code, err = _cli(capsys, "run", study, "--quiet", "--no-figures")
    assert code == 2
    assert err.count("\n") == 0 and "No space left on device" in err
    assert not _no_temporary_files(tmp_path) and not (tmp_path / "out" / "s.nc").exists()


def test_a_full_disk_mid_run_exits_1_and_keeps_the_last_checkpoint(write_study, tmp_path,
                                                                   capsys, monkeypatch):
    scene = '{ model = "ishigami", delay = 0.002 }'
    execution = "workers = 0\ncheckpoint_interval = 0.02\nseed = 2"
    study = write_study(name="full", scene=scene, method=SMALL, execution=execution)
    whole = write_study(name="whole", scene=scene, method=SMALL, execution=execution)
    calls = _disk_fills_at(monkeypatch, 3)  # the initial write and one checkpoint succeed
    code, err = _cli(capsys, "run", study, "--quiet", "--no-figures")
    assert len(calls) == 3
    assert code == 1
    assert err.count("\n") == 0 and "No space left on device" in err and "full.nc" in err
    assert not _no_temporary_files(tmp_path)
    runs, attrs = read_runs(tmp_path / "out" / "full.nc", verify=True)
    assert attrs["complete"] == 0
    assert 0 < (runs["status"].values == "ok").sum() < 64

    monkeypatch.undo()
    assert _cli(capsys, "run", study, "--resume", "--quiet", "--no-figures")[0] == 0
    assert _cli(capsys, "run", whole, "--quiet", "--no-figures")[0] == 0
    runs_f, stats_f = comparable(tmp_path / "out" / "full.nc")
    runs_w, stats_w = comparable(tmp_path / "out" / "whole.nc")
    xr.testing.assert_identical(runs_f, runs_w)
    xr.testing.assert_identical(stats_f, stats_w)


def _partial(write_study, tmp_path, capsys, **kw):
    """A study and its result, made partial again (complete = 0, the last rows pending)."""
    study = write_study(method=SMALL, **kw)
    assert _cli(capsys, "run", study, "--quiet", "--no-figures")[0] == 0
    result = tmp_path / "out" / "s.nc"
    with netCDF4.Dataset(result, "r+") as nc:
        nc.setncattr("complete", 0)
    return study, result


def _damage_a_value(result):
    with netCDF4.Dataset(result, "r+") as nc:
        nc["runs"]["y"][3] = 42.0


def _drop_the_checksum(result):
    with netCDF4.Dataset(result, "r+") as nc:
        nc.delncattr("runs_sha256")


def _another_design(result):
    """A consistent file (checksum recomputed) whose design is not this study's plan, as a
    partial result of another uqflow version that planned differently would be."""
    with netCDF4.Dataset(result, "r+") as nc:
        nc["runs"]["inputs"][0, 0] = 0.125
    runs, _ = read_runs(result)
    with netCDF4.Dataset(result, "r+") as nc:
        nc.setncattr("runs_sha256", runs_checksum(runs))


def _truncate(result):
    data = result.read_bytes()
    result.write_bytes(data[:len(data) // 2])


RESUME_REFUSED = [
    ("a damaged value", _damage_a_value, "do not match their checksum"),
    ("no checksum", _drop_the_checksum, "has no checksum of its runs"),
    ("a truncated file", _truncate, "not a uqflow result file"),
    ("another design", _another_design, "does not hold this study's design (its 'inputs'"),
]


@pytest.mark.parametrize("case, damage, says", RESUME_REFUSED,
                         ids=[c[0] for c in RESUME_REFUSED])
def test_resume_refuses_a_result_it_cannot_trust(write_study, tmp_path, capsys, case, damage,
                                                 says):
    study, result = _partial(write_study, tmp_path, capsys)
    damage(result)
    before = result.read_bytes()
    code, err = _cli(capsys, "run", study, "--resume", "--quiet", "--no-figures")
    assert code == 2 and err.count("\n") == 0 and says in err, err
    assert result.read_bytes() == before
    assert not _no_temporary_files(tmp_path)


def test_resume_refuses_a_changed_scene_file_and_names_it(write_study, tmp_path, capsys):
    scene = tmp_path / "scene.toml"
    scene.write_text('model = "ishigami"\na = 7.0\n')
    study, result = _partial(write_study, tmp_path, capsys, scene='"scene.toml"')
    before = result.read_bytes()
    scene.write_text('model = "ishigami"\na = 5.0\n')  # same study text, another scene
    code, err = _cli(capsys, "run", study, "--resume", "--quiet", "--no-figures")
    assert code == 2 and err.count("\n") == 0
    assert f"{study}: scene: the scene file {scene} changed since" in err
    assert result.read_bytes() == before
    scene.write_text('model = "ishigami"\na = 7.0\n')  # put back: resumes
    assert _cli(capsys, "run", study, "--resume", "--quiet", "--no-figures")[0] == 0
    assert uqflow.open_result(result).attrs["complete"] == 1
