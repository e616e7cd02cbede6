"""MPM particle snapshots (scene key ``snapshots``, solvers/mpm/snapshots.py): legacy binary
VTK files per snapshot time, the ParaView ``.series`` file, run tags, scene validation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from solvers.mpm import MPMSolver
from solvers.mpm.scene import DEFAULT_SNAPSHOT_FIELDS
from solvers.mpm.snapshots import SERIES_NAME, run_tag, vtk_bytes
from uqflow.errors import SceneError

DT_OUT = 0.0005
END = 0.002


def scene(snapshots=None):
    s = dict(domain=dict(x=[0.0, 0.1], y=[0.0, 0.1]), cell_size=0.01, particles_per_cell=2,
             materials=dict(m=dict(model="elastic", rho0=1000.0, E=1e6, nu=0.3)),
             bodies=[dict(name="disk", material="m", shape="circle", center=[0.05, 0.05],
                          radius=0.015),
                     dict(name="block", material="m", shape="rectangle", min=[0.02, 0.02],
                          max=[0.08, 0.08], velocity=[1.0, 0.5])],
             end_time=END, output_interval=DT_OUT,
             outputs=["position_x", "position_y", "pressure", "velocity_x", "velocity_y",
                      "density"],
             probes=[dict(name="a", point=[0.025, 0.025], body="block"),
                     dict(name="b", point=[0.075, 0.03], body="block"),
                     dict(name="c", point=[0.05, 0.05], body="disk"),
                     dict(name="d", point=[0.06, 0.045], body="disk")])
    if snapshots is not None:
        s["snapshots"] = snapshots
    return s


def read_vtk(path):
    """Minimal reader of the legacy binary POLYDATA files the writer makes."""
    data = path.read_bytes()
    pos = 0

    def line():
        nonlocal pos
        end = data.index(b"\n", pos)
        text = data[pos:end].decode("ascii")
        pos = end + 1
        return text

    def block(dtype, count):
        nonlocal pos
        a = np.frombuffer(data, dtype=dtype, count=count, offset=pos)
        pos += a.nbytes
        assert data[pos:pos + 1] == b"\n"
        pos += 1
        return a

    assert line() == "# vtk DataFile Version 3.0"
    title = line()
    assert line() == "BINARY"
    assert line() == "DATASET POLYDATA"
    kw, n, typ = line().split()
    assert (kw, typ) == ("POINTS", "double")
    n = int(n)
    pts = block(">f8", 3 * n).reshape(n, 3)
    kw, ncell, size = line().split()
    assert kw == "VERTICES" and int(ncell) == n and int(size) == 2 * n
    verts = block(">i4", 2 * n).reshape(n, 2)
    assert line() == f"POINT_DATA {n}"
    fields = {}
    types = {"float": ">f4", "int": ">i4", "double": ">f8"}
    while pos < len(data):
        head = line().split()
        if head[0] == "SCALARS":
            assert head[3] == "1" and line() == "LOOKUP_TABLE default"
            fields[head[1]] = block(types[head[2]], n)
        else:
            assert head[0] == "VECTORS"
            fields[head[1]] = block(types[head[2]], 3 * n).reshape(n, 3)
    return title, pts, verts, fields


def series(directory):
    return json.loads((directory / SERIES_NAME).read_text())


# ------------------------------------------------------------------------------------------

def test_files_at_the_snapshot_times(tmp_path):
    sol = MPMSolver.from_scene(scene(dict(interval=2 * DT_OUT, directory=str(tmp_path))))
    sol.run()
    run_dir = tmp_path / "nominal"
    names = sorted(p.name for p in run_dir.glob("*.vtk"))
    assert names == ["particles_00000.vtk", "particles_00001.vtk", "particles_00002.vtk"]
    doc = series(run_dir)
    assert doc["file-series-version"] == "1.0"
    assert [f["name"] for f in doc["files"]] == names
    # bound: k · output_interval in doubles, ≈ eps × 0.002 = 4e-19 s
    assert [f["time"] for f in doc["files"]] == pytest.approx([0.0, 0.001, 0.002], abs=1e-15)
    info = json.loads((run_dir / "run.json").read_text())
    assert info["tag"] == "nominal" and info["parameters"] == {}
    assert info["materials"] == ["m"] and info["bodies"] == ["disk", "block"]
    assert [f["time"] for f in info["frames"]] == [f["time"] for f in doc["files"]]
    assert not list(run_dir.glob(".*tmp"))                 # no temporary file left
    # the default fields, each with one value per particle
    title, pts, verts, fields = read_vtk(run_dir / names[0])
    assert list(fields) == list(DEFAULT_SNAPSHOT_FIELDS)
    n = sol.parts.x.size
    assert pts.shape == (n, 3) and fields["velocity"].shape == (n, 3)
    assert "t = 0.0 s" in title


def test_interval_within_round_off_and_k0_included(tmp_path):
    # 3 × 0.0005 = 0.0015000000000000002: accepted; end 0.002 is not on the interval
    sol = MPMSolver.from_scene(scene(dict(interval=3 * DT_OUT, directory=str(tmp_path),
                                          fields=["density"])))
    assert sol.cfg.snapshots.every == 3
    sol.run()
    doc = series(tmp_path / "nominal")
    # bound: k · output_interval in doubles, ≈ eps × 0.0015 = 3e-19 s
    assert [f["time"] for f in doc["files"]] == pytest.approx([0.0, 0.0015], abs=1e-15)


def test_file_contents_match_the_run(tmp_path):
    fields = ["pressure", "density", "velocity", "material", "body", "velocity_x"]
    sol = MPMSolver.from_scene(scene(dict(interval=END, directory=str(tmp_path),
                                          fields=fields)))
    ds = sol.run()
    run_dir = tmp_path / "nominal"
    assert [f["time"] for f in series(run_dir)["files"]] == [0.0, END]
    # t = 0: every particle against the seeded particles
    _, pts, verts, f0 = read_vtk(run_dir / "particles_00000.vtk")
    p = sol.parts
    assert list(f0) == fields
    np.testing.assert_array_equal(pts[:, 0], p.x)
    np.testing.assert_array_equal(pts[:, 1], p.y)
    assert np.all(pts[:, 2] == 0.0)
    np.testing.assert_array_equal(verts[:, 0], 1)
    np.testing.assert_array_equal(verts[:, 1], np.arange(p.x.size))
    np.testing.assert_array_equal(f0["material"], p.material)
    np.testing.assert_array_equal(f0["body"], p.body)
    # bound: fields are stored as float32, rounding ≤ 2^-24 = 6e-8 relative
    np.testing.assert_allclose(f0["velocity"][:, 0], p.vx, rtol=1e-7)
    np.testing.assert_allclose(f0["velocity"][:, 1], p.vy, rtol=1e-7)
    assert np.all(f0["velocity"][:, 2] == 0.0)
    np.testing.assert_allclose(f0["density"], 1000.0, rtol=1e-7)   # float32: ≤ 6e-8
    # end time: the probe particles against the probe series (same state, same instant)
    _, pts, _, f1 = read_vtk(run_dir / "particles_00001.vtk")
    i = sol.probe_index
    last = ds.isel(time=-1)
    assert not np.allclose(pts[i, 0], p.x[i])                  # the particles did move
    np.testing.assert_array_equal(pts[i, 0], last["position_x"].values)   # doubles: exact
    np.testing.assert_array_equal(pts[i, 1], last["position_y"].values)
    for name, probe in (("pressure", "pressure"), ("density", "density"),
                        ("velocity_x", "velocity_x")):
        np.testing.assert_allclose(f1[name][i], last[probe].values, rtol=1e-6,
                                   atol=1e-6 * float(np.abs(last[probe]).max()))
    np.testing.assert_allclose(f1["velocity"][i, 1], last["velocity_y"].values, rtol=1e-6)
    assert np.abs(last["pressure"].values).max() > 0.0         # a non-trivial comparison


def test_run_tags_name_the_realization(tmp_path):
    sol = MPMSolver.from_scene(scene(dict(interval=END, directory=str(tmp_path),
                                          fields=["pressure"])))
    p1, p2 = {"m.E": 1.1e6, "m.nu": 0.3}, {"m.E": 1.2e6, "m.nu": 0.3}
    sol.run(p1)
    sol.run(p2)
    sol.run(dict(reversed(list(p1.items()))))          # the same values, another order
    tags = sorted(d.name for d in tmp_path.iterdir())
    assert tags == sorted({run_tag(p1), run_tag(p2)})
    assert run_tag(p1) != run_tag(p2) and len(run_tag(p1)) == 12
    assert run_tag({}) == run_tag(None) == "nominal"
    info = json.loads((tmp_path / run_tag(p2) / "run.json").read_text())
    assert info["parameters"] == p2
    assert len(series(tmp_path / run_tag(p1))["files"]) == 2   # rewritten, not appended


def test_relative_directory_is_taken_from_the_cwd(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    sol = MPMSolver.from_scene(scene(dict(interval=END, directory="snaps/thin",
                                          fields=["body"])))
    monkeypatch.chdir("/")                        # resolved when the scene was read
    sol.run()
    assert (tmp_path / "snaps" / "thin" / "nominal" / "particles_00001.vtk").is_file()


def test_nothing_written_without_the_key(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    sol = MPMSolver.from_scene(scene())
    assert sol.cfg.snapshots is None
    sol.run()
    assert list(tmp_path.iterdir()) == []


BAD = [
    ({"interval": 0.0007}, "scene.snapshots.interval"),            # not a multiple
    ({"interval": 0.2 * DT_OUT}, "scene.snapshots.interval"),      # below output_interval
    ({"interval": -DT_OUT}, "scene.snapshots.interval"),
    ({"interval": "1e-3"}, "scene.snapshots.interval"),
    ({"interval": KeyError}, "scene.snapshots.interval"),
    ({"directory": KeyError}, "scene.snapshots.directory"),
    ({"directory": ""}, "scene.snapshots.directory"),
    ({"directory": 3}, "scene.snapshots.directory"),
    ({"fields": ["pressure", "vorticity"]}, "scene.snapshots.fields[1]"),
    ({"fields": ["position_x"]}, "scene.snapshots.fields[0]"),
    ({"fields": []}, "scene.snapshots.fields"),
    ({"fields": "pressure"}, "scene.snapshots.fields"),
    ({"fields": ["pressure", "pressure"]}, "scene.snapshots.fields"),
    ({"every": 2}, "scene.snapshots.every"),                       # unknown key
]


@pytest.mark.parametrize("change, key", BAD)
def test_bad_snapshot_keys_name_the_key(tmp_path, change, key):
    sn = dict(interval=DT_OUT, directory=str(tmp_path))
    for k, v in change.items():
        if v is KeyError:
            del sn[k]
        else:
            sn[k] = v
    with pytest.raises(SceneError) as e:
        MPMSolver.from_scene(scene(sn))
    assert e.value.key == key, str(e.value)
    assert list(tmp_path.iterdir()) == []


def test_snapshots_must_be_a_table(tmp_path):
    with pytest.raises(SceneError) as e:
        MPMSolver.from_scene(scene([str(tmp_path)]))
    assert e.value.key == "scene.snapshots"


def test_vtk_bytes_round_trip(tmp_path):
    x = np.array([0.0, 1.5, -2.25])
    y = np.array([1e-3, 2.0, 3.0])
    s = np.array([1.0, np.nan, -7.5e9])
    v = np.arange(9.0).reshape(3, 3)
    ids = np.array([0, 2, 1])
    path = tmp_path / "a.vtk"
    path.write_bytes(vtk_bytes(x, y, [("s", s), ("v", v), ("id", ids)], title="t\nx"))
    title, pts, verts, f = read_vtk(path)
    assert title == "t x"
    np.testing.assert_array_equal(pts, np.c_[x, y, np.zeros(3)])
    np.testing.assert_array_equal(f["s"], s.astype(np.float32))
    np.testing.assert_array_equal(f["v"], v)
    np.testing.assert_array_equal(f["id"], ids)
    assert f["id"].dtype == np.dtype(">i4") and f["s"].dtype == np.dtype(">f4")
    # big-endian on disk: 1.5 as a big-endian double follows the POINTS line
    raw = path.read_bytes()
    start = raw.index(b"POINTS 3 double\n") + len(b"POINTS 3 double\n")
    assert raw[start + 24:start + 32] == np.array([1.5], dtype=">f8").tobytes()
