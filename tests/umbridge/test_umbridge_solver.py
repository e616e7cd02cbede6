"""``solver = "umbridge"``: studies propagating through a remote UM-Bridge model
(solvers/umbridge/solver.py; docs/umbridge.md), against an independent server — the umbridge
package's own ``serve_models`` with models written in ``independent_server.py`` — started in a
subprocess on 127.0.0.1."""

import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from solvers.umbridge import UMBridgeSolver
from uqflow.cli import main
from uqflow.errors import SceneError, SolverError
from uqflow.testing import check_solver

pytest.importorskip("umbridge")

SERVER = Path(__file__).with_name("independent_server.py")
START_TIMEOUT = 60.0         # s for the server to answer /Info


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    def __init__(self, port=None):
        self.port = port or free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.process = subprocess.Popen([sys.executable, str(SERVER), str(self.port)],
                                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + START_TIMEOUT
        while True:
            try:
                with urllib.request.urlopen(self.url + "/Info", timeout=1):
                    return
            except OSError:
                if time.monotonic() > deadline or self.process.poll() is not None:
                    self.stop()
                    raise RuntimeError("the independent UM-Bridge server did not start")
                time.sleep(0.1)

    def stop(self):
        self.process.kill()
        self.process.wait()


@pytest.fixture(scope="module")
def server():
    s = Server()
    yield s
    s.stop()


def ishigami_scene(url, **extra):
    return {"url": url, "model": "ishigami", "inputs": {"x1": 0.0, "x2": 0.0, "x3": 0.0},
            "outputs": [{"name": "y", "long_name": "Ishigami function"}], **extra}


INPUTS = "".join(f"""
[[inputs]]
name = "x{i}"
distribution = "uniform"
lower = -3.141592653589793
upper = 3.141592653589793
""" for i in (1, 2, 3))


def study_text(name, solver, scene, samples=64, execution=""):
    return (f'name = "{name}"\nsolver = "{solver}"\nscene = {scene}\n{INPUTS}\n'
            f'[method]\nkind = "monte-carlo"\nsamples = {samples}\n{execution}')


def toml_inline(table: dict) -> str:
    def value(v):
        if isinstance(v, dict):
            return toml_inline(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, str):
            return f'"{v}"'
        return repr(v)
    return "{ " + ", ".join(f"{k} = {value(v)}" for k, v in table.items()) + " }"


def run(tmp_path, name, text, *args):
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    code = main(["run", str(path), "--quiet", "--no-figures", *args])
    return code, tmp_path / "results" / f"{name}.nc"


def test_a_study_through_the_server_gives_the_in_process_statistics(server, tmp_path):
    remote = study_text("remote", "umbridge", toml_inline(ishigami_scene(server.url)))
    local = study_text("local", "analytic", '{ model = "ishigami", a = 7.0, b = 0.1 }')
    (tmp_path / "results").mkdir()
    assert run(tmp_path, "remote", remote.replace('[method]', '[output]\npath = '
                                                   '"results/remote.nc"\n[method]'))[0] == 0
    # the remote study on 2 dask workers (a client each), the local one in this process
    assert run(tmp_path, "local", local.replace('[method]', '[output]\npath = '
                                                '"results/local.nc"\n[method]'),
               "--workers", "0")[0] == 0
    with xr.open_datatree(tmp_path / "results" / "remote.nc") as a, \
            xr.open_datatree(tmp_path / "results" / "local.nc") as b:
        remote_stats = a["statistics"].to_dataset()
        local_stats = b["statistics"].to_dataset()
        # the server's formula is the analytic model's, operation for operation: same bits
        for name in local_stats.data_vars:
            np.testing.assert_array_equal(remote_stats[name].values, local_stats[name].values)
        description = a.attrs["solver_description"]
    assert server.url in description and "'ishigami'" in description
    assert '"Evaluate": true' in description               # the model's own info


def test_levels_go_in_the_config_and_outputs_take_their_dims(server):
    scene = {"url": server.url, "model": "decay", "inputs": {"k": 1.0},
             "outputs": [{"name": "y", "units": "1"},
                         {"name": "path", "dims": ["time"], "shape": [5], "units": "1"}]}
    for level in (0, 3):
        result = UMBridgeSolver.from_scene({**scene, "level": level}).run({"k": 0.7})
        steps = 2 ** (level + 2)
        y = [1.0]
        for _ in range(steps):
            y.append(y[-1] * (1.0 - 0.7 / steps))
        assert float(result["y"]) == y[-1]
        assert result["path"].dims == ("time",) and result["path"].attrs["units"] == "1"
        assert result["path"].values[-1] == y[-1]


def test_a_model_error_fails_the_realization_with_its_message(server):
    solver = UMBridgeSolver.from_scene(ishigami_scene(server.url,
                                                      config={"raise_above": 1.0}))
    assert float(solver.run({"x1": 0.5, "x3": 0.5})["y"]) == pytest.approx(
        np.sin(0.5) + 0.1 * 0.5**4 * np.sin(0.5), rel=0, abs=0)
    with pytest.raises(SolverError, match="HTTP 500"):
        solver.run({"x3": 2.0})


def test_declared_sizes_are_checked_against_the_models(server):
    solver = UMBridgeSolver.from_scene({**ishigami_scene(server.url),
                                        "inputs": {"x1": 0.0, "x2": 0.0}})
    with pytest.raises(SolverError, match=r"takes inputs of sizes \[3\]; the scene declares "
                                          r"one of 2"):
        solver.run({})
    solver = UMBridgeSolver.from_scene({**ishigami_scene(server.url),
                                        "outputs": [{"name": "y", "dims": ["i"],
                                                     "shape": [2]}]})
    with pytest.raises(SolverError, match=r"outputs of sizes \[1\]; the scene declares \[2\]"):
        solver.run({})


@pytest.mark.parametrize("change,key", [
    ({"url": "ftp://x"}, "scene.url"),
    ({"inputs": {}}, "scene.inputs"),
    ({"outputs": [{"name": "y", "dims": ["t"]}]}, "scene.outputs[0].shape"),
    ({"outputs": [{"name": "y"}, {"name": "y"}]}, "scene.outputs"),
    ({"timeout": 0}, "scene.timeout"),
    ({"level": 1, "config": {"level": 2}}, "scene.level"),
    ({"urls": "http://x"}, "scene.urls"),
])
def test_a_bad_scene_names_its_key(change, key):
    with pytest.raises(SceneError) as caught:
        UMBridgeSolver.from_scene({**ishigami_scene("http://127.0.0.1:1"), **change})
    assert caught.value.key == key


def test_a_server_killed_mid_study_stops_it_and_resume_finishes_it(tmp_path):
    server = Server()
    port = server.port
    scene = ishigami_scene(server.url, config={"delay": 0.05}, retries=0)
    text = study_text("killed", "umbridge", toml_inline(scene), samples=60,
                      execution="[execution]\nworkers = 0\nbatch = 4\n"
                                "checkpoint_interval = 0\n")
    path = tmp_path / "killed.toml"
    path.write_text(text.replace("[method]", '[output]\npath = "killed.nc"\n[method]'))
    study = subprocess.Popen([sys.executable, "-c", "import sys; from uqflow.cli import main; "
                              "sys.exit(main(sys.argv[1:]))", "run", str(path), "--quiet",
                              "--no-figures"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    time.sleep(2.0)
    server.stop()
    _, err = study.communicate(timeout=120)
    assert study.returncode == 1, err
    assert "could not run realization" in err and "unreachable after 1 attempts" in err
    assert "finish with --resume" in err
    with xr.open_datatree(tmp_path / "killed.nc") as tree:        # the partial result
        status, message = tree["runs"]["status"].values, tree["runs"]["message"].values
    stopped = np.flatnonzero(np.char.startswith(message.astype(str), "not run: "))
    assert stopped.size == 1 and status[stopped[0]] == "pending"
    assert "unreachable after 1 attempts" in str(message[stopped[0]])
    assert (status[:stopped[0]] == "ok").all() and (status[stopped[0]:] == "pending").all()
    server = Server(port)
    try:
        assert main(["run", str(path), "--resume", "--quiet", "--no-figures"]) == 0
    finally:
        server.stop()
    with xr.open_datatree(tmp_path / "killed.nc") as tree:
        status, message = tree["runs"]["status"].values, tree["runs"]["message"].values
    assert (status == "ok").all() and status.size == 60 and not any(message.astype(str))


def test_a_model_slower_than_the_timeout_fails_the_realization_naming_it(server):
    solver = UMBridgeSolver.from_scene(ishigami_scene(server.url, config={"delay": 2.0},
                                                      timeout=0.3))
    t0 = time.monotonic()
    with pytest.raises(SolverError, match=r"no answer within 0.3 s \(scene.timeout\)"):
        solver.run({})
    assert time.monotonic() - t0 < 2.0                       # not waited out, not retried


def test_the_umbridge_solver_passes_check_solver(server):
    # tests/test_conformance.py checks the other built-in solvers; this one needs the server
    outcome = check_solver(UMBridgeSolver, ishigami_scene(server.url))
    assert set(outcome) >= {"contract", "deterministic", "failure_capture", "pickle",
                            "bad_scene", "run_matches_template"}
    assert all(v == "ok" or v.startswith("not applicable") for v in outcome.values()), outcome
