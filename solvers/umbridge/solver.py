"""A remote UM-Bridge model as a uqflow solver: ``solver = "umbridge"`` (docs/umbridge.md).

The scene names the server and the model, the model's input vector by the study's parameter
names (with their nominal values, in the vector's order), and how to unflatten each output
vector into labelled dims. A realization is one ``POST /Evaluate``; the scene's ``config``
goes with it, ``level`` as ``config["level"]`` (so a study's ``[levels]`` with
``key = "level"`` runs a multilevel study through the model's own levels). One HTTP client
per solver instance, so one per dask worker. A transport failure (refused, reset) is retried
``retries`` times ``retry_wait`` seconds apart, then stops the study with the realization
pending (``SolverUnavailable``: ``--resume`` runs it once the server is back); a timeout, an
HTTP error or the model's error object is not retried and fails the realization with its
message.
"""

from __future__ import annotations

import json
import math
import socket
import time
import urllib.error
import urllib.request
from collections.abc import Mapping
from typing import Annotated, Any

import numpy as np
import xarray as xr
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from uqflow.errors import SceneError, SolverError, SolverUnavailable
from uqflow.solver import Solver, register_solver
from uqflow.validation import validation_error

MAX_TIMEOUT = 7 * 24 * 3600.0      # s: a week stands in for any single run


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)


class OutputDeclaration(_Strict):
    name: Annotated[str, Field(min_length=1)]
    #: the output's dims, C order; its size is the product of ``shape``
    dims: list[Annotated[str, Field(min_length=1)]] = Field(default_factory=list)
    shape: list[Annotated[int, Field(ge=1)]] = Field(default_factory=list)
    units: str = ""
    long_name: str = ""


class SceneSpec(_Strict):
    url: Annotated[str, Field(pattern=r"^https?://\S+$")]
    model: Annotated[str, Field(min_length=1)]
    #: the model's input vector: parameter name -> nominal value, in the vector's order
    inputs: dict[str, float] = Field(min_length=1)
    outputs: list[OutputDeclaration] = Field(min_length=1)
    config: dict[str, Any] = Field(default_factory=dict)
    level: Annotated[int, Field(ge=0)] | None = None
    #: s per request
    timeout: Annotated[float, Field(gt=0, le=MAX_TIMEOUT)] = 600.0
    retries: Annotated[int, Field(ge=0, le=100)] = 3
    #: s between retries
    retry_wait: Annotated[float, Field(ge=0, le=3600)] = 2.0


def _validated(scene) -> SceneSpec:
    if not isinstance(scene, Mapping):
        raise SceneError(f"must be a table, got {scene!r}", key="scene")
    data = dict(scene)
    try:
        spec = SceneSpec.model_validate(data)
    except ValidationError as exc:
        found = validation_error(exc, None, prefix="scene", data=data, model=SceneSpec)
        raise SceneError(found.reason, key=found.key) from None
    for k, out in enumerate(spec.outputs):
        if len(out.dims) != len(out.shape):
            raise SceneError(f"dims {out.dims} and shape {out.shape} must have the same length",
                             key=f"scene.outputs[{k}].shape")
    names = [o.name for o in spec.outputs]
    if len(set(names)) != len(names):
        raise SceneError(f"output names must differ, got {names}", key="scene.outputs")
    for name, value in spec.inputs.items():
        if not math.isfinite(value):
            raise SceneError(f"nominal value must be finite, got {value!r}",
                             key=f"scene.inputs.{name}")
    if spec.level is not None and "level" in spec.config:
        raise SceneError("the level is set twice: by 'level' and in 'config'", key="scene.level")
    return spec


class _Client:
    """UM-Bridge requests over HTTP with the scene's timeout and retries."""

    def __init__(self, spec: SceneSpec):
        self.url, self.model = spec.url.rstrip("/"), spec.model
        self.timeout, self.retries, self.retry_wait = spec.timeout, spec.retries, spec.retry_wait

    def post(self, path: str, body: dict) -> dict:
        data = json.dumps({"name": self.model, **body}, allow_nan=False).encode()
        for attempt in range(self.retries + 1):
            request = urllib.request.Request(self.url + path, data=data, method="POST",
                                             headers={"Content-Type": "application/json"})
            try:
                with urllib.request.urlopen(request, timeout=self.timeout) as answer:
                    return self._read(answer.read(), path)
            except urllib.error.HTTPError as error:
                return self._read(error.read(), path, error.code)
            except (TimeoutError, socket.timeout):
                raise self._timed_out(path) from None
            except (urllib.error.URLError, ConnectionError) as error:
                reason = getattr(error, "reason", error)
                if isinstance(reason, (TimeoutError, socket.timeout)):
                    raise self._timed_out(path) from None
                if attempt == self.retries:
                    # not the realization's failure: the study stops, --resume runs it
                    raise SolverUnavailable(f"{self.url}{path}: unreachable after "
                                            f"{self.retries + 1} attempts ({reason})") from None
                time.sleep(self.retry_wait)
        raise AssertionError("unreachable")

    def _timed_out(self, path: str) -> SolverError:
        # a model that hangs at this input fails this realization; not retried
        return SolverError(f"{self.url}{path}: no answer within {self.timeout:g} s "
                           f"(scene.timeout)")

    def _read(self, payload: bytes, path: str, status: int = 200) -> dict:
        try:
            answer = json.loads(payload)
        except (json.JSONDecodeError, UnicodeDecodeError):
            answer = None
        if isinstance(answer, dict) and isinstance(answer.get("error"), dict):
            error = answer["error"]
            raise SolverError(f"model {self.model!r} at {self.url}{path}: "
                              f"{error.get('type', 'error')}: {error.get('message', '')}")
        if status != 200 or not isinstance(answer, dict):
            raise SolverError(f"{self.url}{path}: HTTP {status}, "
                              f"{payload[:200].decode(errors='replace')!r}")
        return answer


@register_solver("umbridge")
class UMBridgeSolver(Solver):
    """A remote model speaking the UM-Bridge protocol, by URL and model name."""

    def __init__(self, spec: SceneSpec):
        self.spec = spec
        self.client = _Client(spec)
        self.config = dict(spec.config, **({} if spec.level is None else {"level": spec.level}))
        self.sizes = [int(np.prod(o.shape, dtype=np.int64)) for o in spec.outputs]
        self._checked = False
        self._template = xr.Dataset({
            o.name: xr.Variable(tuple(o.dims), np.full(tuple(o.shape), np.nan),
                                {"units": o.units, "long_name": o.long_name or o.name})
            for o in spec.outputs})

    @classmethod
    def from_scene(cls, scene: Mapping) -> "UMBridgeSolver":
        return cls(_validated(scene))

    def nominal(self) -> dict[str, float]:
        return dict(self.spec.inputs)

    def outputs(self) -> xr.Dataset:
        return self._template.copy(deep=True)

    def describe(self) -> str:
        """The server, the model and what the model says of itself (its info at the start of
        the study, or why it could not be had): the result's provenance."""
        where = f"UM-Bridge model {self.spec.model!r} at {self.spec.url}"
        try:
            info = self.client.post("/ModelInfo", {"config": self.config})
        except (SolverError, SolverUnavailable) as exc:
            return f"{where} (its info could not be read: {exc})"
        return f"{where}; its info: {json.dumps(info, sort_keys=True)}"

    def _check_sizes(self) -> None:
        """The model's sizes against the scene's declaration, once per client."""
        inputs = self.client.post("/InputSizes", {"config": self.config}).get("inputSizes")
        outputs = self.client.post("/OutputSizes", {"config": self.config}).get("outputSizes")
        if inputs != [len(self.spec.inputs)]:
            raise SolverError(f"model {self.spec.model!r} takes inputs of sizes {inputs}; the "
                              f"scene declares one of {len(self.spec.inputs)} "
                              f"({', '.join(self.spec.inputs)})")
        if outputs != self.sizes:
            raise SolverError(f"model {self.spec.model!r} gives outputs of sizes {outputs}; "
                              f"the scene declares {self.sizes}")
        self._checked = True

    def run(self, params, fields=None) -> xr.Dataset:
        if fields:
            raise SolverError("a remote UM-Bridge model takes no random fields")
        if not self._checked:
            self._check_sizes()
        values = [float(params.get(name, nominal)) for name, nominal in self.spec.inputs.items()]
        answer = self.client.post("/Evaluate", {"input": [values], "config": self.config})
        vectors = answer.get("output")
        if not isinstance(vectors, list) or [len(v) if isinstance(v, list) else None
                                              for v in vectors] != self.sizes:
            raise SolverError(f"model {self.spec.model!r} answered outputs that are not "
                              f"vectors of sizes {self.sizes}")
        ds = self._template.copy(deep=False)
        for out, vector in zip(self.spec.outputs, vectors):
            var = ds.variables[out.name]
            var.values = np.asarray(vector, dtype=float).reshape(var.shape)
        return ds
