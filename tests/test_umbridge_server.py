"""``uqflow serve``: a study's solver as a UM-Bridge model (uqflow/umbridge_server.py;
docs/umbridge.md). Real servers in subprocesses on 127.0.0.1, called by the umbridge package's
own client and by hand-made requests."""

import json
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from uqflow.cli import main
from uqflow.study import load_study

umbridge = pytest.importorskip("umbridge")

ROOT = Path(__file__).resolve().parent.parent
ISHIGAMI = ROOT / "studies" / "ishigami_mc.toml"
EULER = ROOT / "studies" / "multilevel" / "euler_mlmc.toml"
START_TIMEOUT = 120          # s: a spawned worker imports uqflow and numba before it answers


class Server:
    """``uqflow serve STUDY --port 0`` in a subprocess; ``url`` from the line it prints."""

    def __init__(self, study, *args):
        self.process = subprocess.Popen(
            [sys.executable, "-c", "import sys; from uqflow.cli import main; "
             "sys.exit(main(sys.argv[1:]))", "serve", str(study), "--port", "0", *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        line = self.process.stdout.readline()
        if "serving model" not in line:
            self.process.kill()
            raise RuntimeError(f"no server: {line!r} {self.process.stderr.read()!r}")
        self.url = line.split(" on ")[1].split()[0]

    def post(self, path, body=None, raw=None):
        data = raw if raw is not None else json.dumps(body).encode()
        request = urllib.request.Request(self.url + path, data=data, method="POST")
        try:
            with urllib.request.urlopen(request, timeout=START_TIMEOUT) as answer:
                return answer.status, json.loads(answer.read())
        except urllib.error.HTTPError as error:
            return error.code, json.loads(error.read())

    def stop(self):
        self.process.kill()
        self.process.wait()


@pytest.fixture(scope="module")
def ishigami():
    server = Server(ISHIGAMI, "--workers", "2")
    yield server
    server.stop()


@pytest.fixture(scope="module")
def euler():
    server = Server(EULER)
    yield server
    server.stop()


POINTS = [[0.1, 0.2, 0.3], [-3.0, 1.5707963267948966, 2.9], [1e-300, -0.0, 3.141592653589793]]


def test_the_umbridge_client_gets_the_in_process_outputs_bit_for_bit(ishigami):
    model = umbridge.HTTPModel(ishigami.url, "ishigami-mc")
    assert model.get_input_sizes() == [3] and model.get_output_sizes() == [1]
    assert model.supports_evaluate()
    solver = load_study(ISHIGAMI).solver
    for point in POINTS:
        served = model([point])
        here = float(solver.run(dict(zip(["x1", "x2", "x3"], point)))["y"])
        assert served == [[here]]           # JSON's shortest repr round-trips every bit


def test_a_level_and_an_output_are_chosen_by_config(euler):
    model = umbridge.HTTPModel(euler.url, "euler-mlmc")
    study = load_study(EULER)
    status, info = euler.post("/ModelInfo", {"name": "euler-mlmc"})
    assert status == 200 and info["uqflow"]["levels"] == {"key": "steps",
                                                          "values": [4, 8, 16, 32, 64, 128]}
    assert info["uqflow"]["outputs"]["path"]["dims"] == list(study.solver.outputs()["path"].dims)
    assert info["uqflow"]["input_units"] == {"k": study.solver.parameter_units().get("k", "")}
    for level in (0, 5):
        expected = study.levels.aligned_solver(level).run({"k": 0.75})
        served = model([[0.75]], {"level": level})
        assert served[0] == [float(expected["y"])]
        assert served[1] == np.asarray(expected["path"], dtype=float).ravel().tolist()
    assert model([[0.75]], {"outputs": ["path"]}) == [model([[0.75]])[1]]
    assert model.get_output_sizes({"outputs": ["y"]}) == [1]


@pytest.mark.parametrize("path,body,raw,kind", [
    ("/Evaluate", None, b"{not json", "InvalidInput"),
    ("/Evaluate", {"input": [[0.0, 0.0, 0.0]]}, None, "InvalidInput"),              # no name
    ("/Evaluate", {"name": "other", "input": [[0.0, 0.0, 0.0]]}, None, "ModelNotFound"),
    ("/Evaluate", {"name": "ishigami-mc", "input": [[0.0, 0.0]]}, None, "InvalidInput"),
    ("/Evaluate", {"name": "ishigami-mc", "input": [[0.0, "a", 0.0]]}, None, "InvalidInput"),
    ("/Evaluate", {"name": "ishigami-mc", "input": [[0.0, 0.0, 1e999]]}, None, "InvalidInput"),
    ("/Evaluate", None, b'{"name": "ishigami-mc", "input": [[0, 0, 1' + b"0" * 400 + b']]}',
     "InvalidInput"),                                     # an integer past a float's range
    ("/Evaluate", {"name": "ishigami-mc", "input": [[0.0] * 3], "config": {"level": 1}}, None,
     "InvalidInput"),                                                    # no [levels]
    ("/Evaluate", {"name": "ishigami-mc", "input": [[0.0] * 3], "config": {"outputs": ["z"]}},
     None, "InvalidInput"),
    ("/Evaluate", {"name": "ishigami-mc", "input": [[0.0] * 3], "config": []}, None,
     "InvalidInput"),
    ("/ApplyHessian", {"name": "ishigami-mc"}, None, "UnsupportedFeature"),
    ("/Gradient", {"name": "ishigami-mc", "input": [[0.0] * 3], "outWrt": 1, "inWrt": 0,
                   "sens": [1.0]}, None, "InvalidInput"),             # one output: index 0
    ("/Gradient", {"name": "ishigami-mc", "input": [[0.0] * 3], "outWrt": 0, "inWrt": 0,
                   "sens": [1.0, 2.0]}, None, "InvalidInput"),
    ("/ApplyJacobian", {"name": "ishigami-mc", "input": [[0.0] * 3], "outWrt": 0, "inWrt": 1,
                        "vec": [1.0, 0.0, 0.0]}, None, "InvalidInput"),
    ("/Nowhere", {"name": "ishigami-mc"}, None, "UnsupportedFeature"),
])
def test_a_bad_request_gets_the_protocols_error_object_and_the_server_serves_on(
        ishigami, path, body, raw, kind):
    status, answer = ishigami.post(path, body, raw)
    assert status >= 400 and set(answer) == {"error"}
    assert answer["error"]["type"] == kind and answer["error"]["message"]
    assert ishigami.post("/Evaluate", {"name": "ishigami-mc", "input": [[0.0] * 3]}) == \
        (200, {"output": [[0.0]]})


def test_info_names_the_model(ishigami):
    # GET /Info, through the client's discovery call
    assert umbridge.supported_models(ishigami.url) == ["ishigami-mc"]


SCENES = ROOT / "studies" / "scenes"


@pytest.mark.parametrize("argv,says", [
    (["serve", str(ISHIGAMI), "--workers", "0"], "--workers"),
    (["serve", str(ISHIGAMI), "--port", "70000"], "--port"),
    (["serve", str(ROOT / "studies" / "sph" / "composite_kl_fields.toml")], "fields"),
    (["serve", str(SCENES / "sph_example1.toml")], "name its solver with --solver"),
    (["serve", str(ISHIGAMI), "--solver", "analytic"], "this study names its own solver"),
    (["serve", str(SCENES / "sph_example1.toml"), "--solver", "nosuch"], "unknown solver"),
    (["serve", str(SCENES / "sph_example1.toml"), "--solver", "mpm"], "sph_example1.toml: "),
    (["serve", str(SCENES / "sph_example1.toml"), "--solver", "sph", "--set", "a=1"],
     "--set applies to a study file"),
])
def test_bad_serve_options_are_one_line_errors(argv, says, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err


@pytest.fixture(scope="module")
def faulty(tmp_path_factory):
    """A scene file served with --solver: the analytic model that raises above 1 and gives
    NaN below -1."""
    scene = tmp_path_factory.mktemp("faulty") / "faulty.toml"
    scene.write_text('model = "faulty"\nraise_above = 1.0\nnan_below = -1.0\n')
    server = Server(scene, "--solver", "analytic")
    yield server, scene
    server.stop()


def test_a_scene_file_is_served_with_its_solvers_every_parameter_and_output(faulty):
    from solvers.analytic import AnalyticSolver

    server, scene = faulty
    status, info = server.post("/ModelInfo", {"name": "faulty"})     # named after the file
    assert status == 200 and info["uqflow"]["parameters"] == ["x"]
    assert list(info["uqflow"]["outputs"]) == ["y"]
    here = AnalyticSolver.from_scene({"model": "faulty", "raise_above": 1.0,
                                      "nan_below": -1.0}).run({"x": 0.3})
    assert umbridge.HTTPModel(server.url, "faulty")([[0.3]]) == [[float(here["y"])]]


def test_a_failed_run_is_an_error_object_with_its_message_and_the_next_run_is_served(faulty):
    server, _ = faulty
    request = {"name": "faulty"}
    status, answer = server.post("/Evaluate", {**request, "input": [[1.5]]})
    assert status == 500 and answer["error"]["type"] == "ModelError"
    assert "diverged: x = 1.5 exceeds 1" in answer["error"]["message"]
    status, answer = server.post("/Evaluate", {**request, "input": [[-1.5]]})
    assert status == 500 and "non-finite output 'y'" in answer["error"]["message"]
    assert server.post("/Evaluate", {**request, "input": [[0.25]]}) == (200, {"output":
                                                                            [[0.25]]})


def test_a_served_mpm_run_returns_the_in_process_outputs_bit_for_bit():
    # the quickstart's thin plate (8,400 particles, one thread: one order of operations)
    quickstart = ROOT / "studies" / "quickstart.toml"
    study = load_study(quickstart)
    nominal = study.solver.nominal()
    point = [nominal[name] * 1.05 for name in study.space.names]   # off the nominal values
    here = study.solver.run(dict(zip(study.space.names, point)))
    server = Server(quickstart)
    try:
        model = umbridge.HTTPModel(server.url, study.name)
        served = model([point])
        status, info = server.post("/ModelInfo", {"name": study.name})
        assert info["uqflow"]["input_units"] == {
            name: study.solver.parameter_units()[name] for name in study.space.names}
        # frozen-state constitutive sensitivities are not the run's gradient: none served
        assert not model.supports_gradient() and not model.supports_apply_jacobian()
        status, answer = server.post("/Gradient", {"name": study.name, "input": [point],
                                                   "outWrt": 0, "inWrt": 0, "sens": [1.0]})
        assert status == 400 and answer["error"]["type"] == "UnsupportedFeature"
    finally:
        server.stop()
    for name, vector in zip(study.outputs, served):
        assert vector == np.asarray(here[name].values, dtype=float).ravel().tolist(), name


def test_qmcpys_wrapper_gets_the_in_process_outputs_bit_for_bit(ishigami):
    # QMCPy's own UM-Bridge client (a test extra)
    qmcpy = pytest.importorskip("qmcpy")
    net = qmcpy.DigitalNetB2(dimension=3, seed=7)
    measure = qmcpy.Uniform(net, lower_bound=-np.pi, upper_bound=np.pi)
    integrand = qmcpy.UMBridgeWrapper(measure, umbridge.HTTPModel(ishigami.url, "ishigami-mc"),
                                      {}, parallel=False)
    served = np.asarray(integrand(16), dtype=float).ravel()
    solver = load_study(ISHIGAMI).solver
    here = [float(solver.run(dict(zip(["x1", "x2", "x3"], x)))["y"]) for x in measure(16)]
    assert served.tolist() == here


def test_gradient_and_jacobian_of_a_closed_form_are_the_in_process_derivatives(ishigami):
    model = umbridge.HTTPModel(ishigami.url, "ishigami-mc")
    assert model.supports_gradient() and model.supports_apply_jacobian()
    solver = load_study(ISHIGAMI).solver
    names = ["x1", "x2", "x3"]
    for point in POINTS:
        here = solver.run_with_sensitivities(dict(zip(names, point)), wrt=names,
                                             outputs=["y"])
        jacobian = np.asarray(here["y__gradient"], dtype=float).reshape(1, 3)
        assert model.gradient(0, 0, [point], [2.5]) == (jacobian.T @ [2.5]).tolist()
        vec = [0.5, -1.0, 3.0]
        assert model.apply_jacobian(0, 0, [point], vec) == (jacobian @ vec).tolist()
