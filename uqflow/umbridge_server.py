"""A study's solver served as a UM-Bridge model: ``uqflow serve`` (docs/umbridge.md).

UM-Bridge (Seelinger et al., "Democratizing uncertainty quantification", arXiv 2402.13768) is
HTTP + JSON: ``GET /Info``; ``POST /ModelInfo``, ``/InputSizes``, ``/OutputSizes`` and
``/Evaluate`` with ``{"name", "input": [[...]], "config": {...}}``; errors as
``{"error": {"type", "message"}}``. The umbridge package's own server is not used: a model
that raises, or a request without a "name", gets aiohttp's plain 500 page instead of the
protocol's error object; a NaN output is written into its JSON unquoted (which no JSON parser
reads); and it listens on every interface, with no way to choose one. This server is the
standard library's threaded HTTP server in front of a pool of worker processes, each of which
loads the model once: a run that fails, or kills its worker, is an error object and the server
keeps serving.

The model: one input vector, the study's parameters in its order (its ``[[inputs]]``, in the
solver's units); one output vector per study output, flattened in C order, its dims, shape and
units under ``/ModelInfo``'s "uqflow" key. A scene file served with its solver's name
(``--solver``) is the model of every parameter the solver has, in its ``nominal`` order, and of
every output. ``config``: ``{"level": k}`` runs fidelity level k
of a study with ``[levels]`` (0 the coarsest; default the finest), ``{"outputs": [...]}`` a
subset of the outputs in that order. ``/Gradient`` and ``/ApplyJacobian`` are served for the
outputs whose derivatives are those of the whole run (``Solver.sensitivities_are_total``: the
analytic models' closed forms); the MPM's constitutive sensitivities are local, frozen-state
derivatives (docs/taylor_local.md), not the gradient a UM-Bridge client would take those calls
for, so the MPM serves none.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import threading
from dataclasses import dataclass
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np

from uqflow.errors import StudyError
from uqflow.layout import STATUS_OK

PROTOCOL_VERSION = 1.0
UNSUPPORTED = ("/ApplyHessian", "/EvaluateShMem", "/GradientShMem", "/ApplyJacobianShMem",
               "/TestShMem")


class RequestError(Exception):
    """A request the protocol answers with an error object: (type, message, HTTP status)."""

    def __init__(self, kind: str, message: str, status: int = 400):
        super().__init__(message)
        self.kind, self.status = kind, status


# -- what is served ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Source:
    """What to serve: a study file, or a scene file with the name of its solver."""

    path: str
    overrides: tuple = ()              # a study's (key, value) pairs, as --set gives them
    solver: str | None = None          # a scene file's solver; None: a study file


@dataclass
class Loaded:
    name: str
    parameters: list[str]
    outputs: list[str]
    solver: object
    levels: object = None              # a study's uqflow.levels.Levels, or None

    def solver_at(self, level: int | None):
        return self.solver if level is None else self.levels.aligned_solver(level)


def load(source: Source) -> Loaded:
    """The model of ``source``: a study's inputs and outputs, or a scene's every parameter
    (in its solver's ``nominal`` order) and every output. One-line StudyErrors."""
    from uqflow.solver import get_solver
    from uqflow.study import load_study, read_toml

    path = Path(source.path)
    document, _ = read_toml(path, str(path))
    is_study = "solver" in document and "method" in document
    if source.solver is None:
        if not is_study:
            raise StudyError("a scene file (no 'solver' and 'method'): name its solver with "
                             "--solver", file=str(path))
        study = load_study(path, overrides=dict(source.overrides))
        if study.fields:
            raise StudyError("a study with random fields is not served (a field's germ is "
                             "not one of the model's inputs)", file=str(path), key="fields")
        return Loaded(study.name, list(study.space.names), list(study.outputs), study.solver,
                      study.levels)
    if is_study:
        raise StudyError("--solver is for a scene file: this study names its own solver",
                         file=str(path))
    if source.overrides:
        raise StudyError("--set applies to a study file, not a scene file", file=str(path))
    try:
        solver = get_solver(source.solver).from_scene(document)
    except StudyError as exc:
        raise exc.located(str(path)) from None
    return Loaded(path.stem, list(solver.nominal()), list(solver.outputs().data_vars), solver)


# -- the worker processes ----------------------------------------------------------------------

_loaded: Loaded | None = None


def _load(source: Source) -> None:
    global _loaded
    _loaded = load(source)


def _evaluate(level: int | None, values: list[float], outputs: list[str], seed):
    """(status, message, {output: flat list}) of one run in a worker."""
    from uqflow.realization import run_one, takes_seed

    solver = _loaded.solver_at(level)
    params = dict(zip(_loaded.parameters, values))
    status, message, result, _ = run_one(
        solver, params, None, outputs, seed=seed if takes_seed(solver) else None)
    return status, message, {k: np.asarray(v, dtype=float).ravel().tolist()
                             for k, v in result.items()}


def _jacobian(level: int | None, values: list[float], output: str):
    """(status, message, d output / d inputs as a (output size, inputs) nested list)."""
    from uqflow.layout import gradient_variable
    from uqflow.realization import run_one

    params = dict(zip(_loaded.parameters, values))
    status, message, result, _ = run_one(_loaded.solver_at(level), params, None, [output],
                                         wrt=_loaded.parameters, derived=[output])
    if status != STATUS_OK:
        return status, message, None
    gradient = np.asarray(result[gradient_variable(output)], dtype=float)
    return status, message, gradient.reshape(-1, len(_loaded.parameters)).tolist()


# -- the model ---------------------------------------------------------------------------------

class ServedModel:
    """The model as the protocol describes it; ``evaluate`` runs in the pool."""

    def __init__(self, source: Source, workers: int = 1):
        self.source = source
        loaded = load(source)
        self.name, self.parameters, self.outputs = loaded.name, loaded.parameters, \
            loaded.outputs
        template = loaded.solver.outputs()
        self.shapes = {o: tuple(int(n) for n in template[o].shape) for o in self.outputs}
        units = loaded.solver.parameter_units()
        self.info = {
            "parameters": self.parameters,
            "input_units": {p: units.get(p, "") for p in self.parameters},
            "outputs": {o: {"dims": list(template[o].dims), "shape": list(self.shapes[o]),
                            "units": template[o].attrs.get("units", "")}
                        for o in self.outputs},
            "levels": None if loaded.levels is None else
            {"key": loaded.levels.spec.key, "values": loaded.levels.values},
            "solver": loaded.solver.name,
        }
        self.levels = 0 if loaded.levels is None else len(loaded.levels)
        # derivatives of the whole run only (Solver.sensitivities_are_total), per output
        available = loaded.solver.local_sensitivities() \
            if loaded.solver.sensitivities_are_total else {}
        self.derivable = {o for o in self.outputs
                          if set(self.parameters) <= set(available.get(o, ()))}
        self.info["derivatives"] = sorted(self.derivable)
        self.workers = int(workers)
        self._pool_lock = threading.Lock()
        self._pool = self._new_pool()

    def _new_pool(self):
        # spawned, not forked: a fork of a threaded server (and of numba's thread pools) is
        # not safe; each worker loads the model once
        return ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_load, initargs=(self.source,))

    def close(self):
        self._pool.shutdown(wait=False, cancel_futures=True)

    # -- what a request asks for --

    def selected_outputs(self, config: dict) -> list[str]:
        chosen = config.get("outputs", self.outputs)
        if (not isinstance(chosen, list) or not chosen
                or not all(isinstance(o, str) and o in self.shapes for o in chosen)):
            raise RequestError("InvalidInput", f"config 'outputs' must be a non-empty list of "
                                               f"the model's outputs {self.outputs}, got "
                                               f"{chosen!r}")
        return chosen

    def level(self, config: dict) -> int | None:
        if "level" not in config:
            return None
        k = config["level"]
        if not self.levels:
            raise RequestError("InvalidInput", "config 'level': this study has no [levels]")
        if not isinstance(k, int) or isinstance(k, bool) or not 0 <= k < self.levels:
            raise RequestError("InvalidInput", f"config 'level' must be an integer from 0 to "
                                               f"{self.levels - 1}, got {k!r}")
        return k

    def output_sizes(self, config: dict) -> list[int]:
        return [int(np.prod(self.shapes[o], dtype=np.int64)) for o in
                self.selected_outputs(config)]

    def _values(self, inputs) -> list[float]:
        if (not isinstance(inputs, list) or len(inputs) != 1 or not isinstance(inputs[0], list)
                or len(inputs[0]) != len(self.parameters)):
            raise RequestError("InvalidInput", f"input must be one vector of "
                                               f"{len(self.parameters)} numbers "
                                               f"({', '.join(self.parameters)})")
        try:
            values = [float(v) if isinstance(v, (int, float)) and not isinstance(v, bool)
                      else math.nan for v in inputs[0]]
        except OverflowError:                  # an integer beyond a float's range
            values = [math.nan]
        if not all(math.isfinite(v) for v in values):
            raise RequestError("InvalidInput", "input holds a value that is not a finite number")
        return values

    def _run(self, task, *args):
        """``task(*args)`` in a worker: its answer, or the error object of a failed run."""
        pool = self._pool
        try:
            status, message, answer = pool.submit(task, *args).result()
        except BrokenProcessPool:
            with self._pool_lock:
                if self._pool is pool:
                    self._pool = self._new_pool()
            raise RequestError("ModelError", "the worker running this evaluation died; the "
                                             "server started a new one", 500) from None
        if status != STATUS_OK:
            raise RequestError("ModelError", message or "the run failed", 500)
        return answer

    def evaluate(self, inputs, config: dict) -> list[list[float]]:
        outputs, level = self.selected_outputs(config), self.level(config)
        seed = config.get("seed")
        if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool)):
            raise RequestError("InvalidInput", f"config 'seed' must be an integer, got {seed!r}")
        result = self._run(_evaluate, level, self._values(inputs), outputs, seed)
        return [result[o] for o in outputs]

    def derivative(self, request: dict, config: dict, transpose: bool) -> list[float]:
        """/Gradient (``transpose``: J^T sens) or /ApplyJacobian (J vec) of one output."""
        outputs, level = self.selected_outputs(config), self.level(config)
        out, into = request.get("outWrt"), request.get("inWrt")
        if not isinstance(out, int) or isinstance(out, bool) or not 0 <= out < len(outputs):
            raise RequestError("InvalidInput", f"outWrt must be an output's index from 0 to "
                                               f"{len(outputs) - 1}, got {out!r}")
        if into != 0:
            raise RequestError("InvalidInput", f"inWrt must be 0 (one input vector), got "
                                               f"{into!r}")
        name = outputs[out]
        if name not in self.derivable:
            raise RequestError("UnsupportedFeature", f"no derivative of output {name!r}: the "
                                                     f"solver's are not of the whole run "
                                                     f"(docs/umbridge.md)")
        size = len(self.parameters) if not transpose else \
            int(np.prod(self.shapes[name], dtype=np.int64))
        key = "sens" if transpose else "vec"
        vector = request.get(key)
        if (not isinstance(vector, list) or len(vector) != size
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                           for v in vector)):
            raise RequestError("InvalidInput", f"'{key}' must be a vector of {size} numbers")
        jacobian = np.asarray(self._run(_jacobian, level, self._values(request.get("input")),
                                        name))
        vector = np.asarray(vector, dtype=float)
        return (jacobian.T @ vector if transpose else jacobian @ vector).tolist()


# -- HTTP --------------------------------------------------------------------------------------

def _handler(model: ServedModel):
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args):           # one line per request is noise for a model
            pass

        def _send(self, body: dict, status: int = 200):
            data = json.dumps(body, allow_nan=False).encode()
            self.send_response(status)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def _error(self, exc: RequestError):
            # the protocol's error object (keyword names: "message" is not the result's
            # run-message variable of uqflow.layout)
            self._send({"error": dict(type=exc.kind, message=str(exc))}, exc.status)

        def do_GET(self):
            if self.path == "/Info":
                self._send({"protocolVersion": PROTOCOL_VERSION, "models": [model.name]})
            else:
                self._error(RequestError("UnsupportedFeature", f"no GET {self.path}", 404))

        def do_POST(self):
            try:
                self._send(self._answer())
            except RequestError as exc:
                self._error(exc)
            except Exception as exc:  # a bug here must not end the server: say what it was
                self._error(RequestError("UnknownError", f"{type(exc).__name__}: {exc}", 500))

        def _answer(self) -> dict:
            length = int(self.headers.get("Content-Length") or 0)
            try:
                request = json.loads(self.rfile.read(length) or b"null")
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                raise RequestError("InvalidInput", f"the request is not JSON ({exc})") from None
            if not isinstance(request, dict) or "name" not in request:
                raise RequestError("InvalidInput", "the request must be a JSON object with "
                                                   "the model's 'name'")
            if request["name"] != model.name:
                raise RequestError("ModelNotFound", f"model {request['name']!r} not found; "
                                                    f"this server has {model.name!r}")
            config = request.get("config")
            config = {} if config is None else config
            if not isinstance(config, dict):
                raise RequestError("InvalidInput", "'config' must be a JSON object")
            if self.path == "/ModelInfo":
                derivatives = bool(model.derivable)
                return {"support": {"Evaluate": True, "Gradient": derivatives,
                                    "ApplyJacobian": derivatives, "ApplyHessian": False},
                        "uqflow": model.info}
            if self.path == "/InputSizes":
                return {"inputSizes": [len(model.parameters)]}
            if self.path == "/OutputSizes":
                return {"outputSizes": model.output_sizes(config)}
            if self.path == "/Evaluate":
                return {"output": model.evaluate(request.get("input"), config)}
            if self.path in ("/Gradient", "/ApplyJacobian"):
                return {"output": model.derivative(request, config,
                                                   transpose=self.path == "/Gradient")}
            if self.path in UNSUPPORTED:
                raise RequestError("UnsupportedFeature", f"{self.path[1:]} is not served "
                                                         f"(docs/umbridge.md)")
            raise RequestError("UnsupportedFeature", f"no POST {self.path}", 404)

    return Handler


def serve(path: Path, *, host: str = "127.0.0.1", port: int = 4242, workers: int = 1,
          overrides: dict | None = None, solver: str | None = None, ready=print) -> None:
    """Serve the study (or, with ``solver``, the scene) at ``path`` until interrupted;
    ``ready(line)`` is told where."""
    model = ServedModel(Source(str(path), tuple((overrides or {}).items()), solver), workers)
    server = ThreadingHTTPServer((host, port), _handler(model))
    server.daemon_threads = True
    try:
        ready(f"uqflow: serving model {model.name!r} on http://{host}:{server.server_port} "
              f"({workers} worker{'s' if workers != 1 else ''}; Ctrl-C stops)")
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
        model.close()
