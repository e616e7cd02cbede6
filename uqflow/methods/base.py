"""The PropagationMethod contract and the helpers every method shares.

A method turns the input space into a *design* (``plan``: which parameter values each
realization gets) and the finished *runs* into *statistics* (``analyze``). It never sees dask
or the solver: the executor runs the design, the store keeps it.

Design (xr.Dataset): dims ``realization`` and ``parameter``; variable ``inputs``
(realization, parameter) holds the parameter values; ``input_mean``/``input_std``/
``input_cv``/``input_skewness``/``input_kurtosis`` (parameter) and ``input_correlation``
(parameter, parameter_j; Gaussian-copula correlation) describe the inputs; methods add their own
variables and attributes.

Runs (xr.Dataset): the design's ``inputs`` plus every output (realization, *output dims),
``status`` ("ok", "failed" or "pending"), ``message`` and ``wall_time`` (s).

Statistics (xr.Dataset): every output with a leading ``statistic`` dimension, the input
summary, and attributes ``method``, ``solver_runs``, ``failed_runs``, ``solver_wall_time``
and ``warnings`` (one warning per line).
"""

from __future__ import annotations

import abc
from typing import ClassVar

import numpy as np
import xarray as xr
from pydantic import BaseModel, ConfigDict

from uqflow.errors import StudyError
from uqflow.inputs import InputSpace
from uqflow.registry import Registry

method_registry = Registry("uqflow.methods", "method")


def register_method(name: str):
    """Class decorator: make a PropagationMethod available to study files as ``kind = name``."""
    return method_registry.register(name)


def get_method(name: str) -> type["PropagationMethod"]:
    return method_registry.get(name)


class MethodOptions(BaseModel):
    """Options of a method, validated from the study file's ``[method]`` table."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class PropagationMethod(abc.ABC):
    """Base class of propagation methods; subclasses define ``Options``, ``plan`` and ``analyze``."""

    name: ClassVar[str] = ""
    Options: ClassVar[type[MethodOptions]] = MethodOptions

    def __init__(self, **options):
        self.options = self.Options(**options)

    #: whether ``plan`` draws random-field germs (``[[fields]]`` in a study)
    accepts_fields: ClassVar[bool] = False
    #: whether a study must declare at least one random input or field
    needs_inputs: ClassVar[bool] = True

    def check(self, space: InputSpace, fields: list | None) -> None:
        """Raise ``StudyError`` if this method cannot treat ``space``; cheap, run at load time
        (so ``uqflow validate`` catches it) and again by ``plan``."""
        if fields and not self.accepts_fields:
            raise StudyError(f"method '{self.name}' takes no random fields; use kl-weibull, or "
                             f"drop the [[fields]] tables", key="fields")

    @abc.abstractmethod
    def plan(self, space: InputSpace, fields: list | None,
             seed: np.random.SeedSequence) -> xr.Dataset:
        """The realizations to run (see the module docstring for the layout)."""

    @abc.abstractmethod
    def analyze(self, design: xr.Dataset, runs: xr.Dataset) -> xr.Dataset:
        """Statistics of the outputs in ``runs`` (failed realizations have NaN outputs)."""

    def stop_points(self, n_planned: int) -> np.ndarray:
        """Realization counts (increasing, each <= ``n_planned``) at which ``enough`` is asked.

        They depend on the design alone, never on batches, workers, completion order or a
        resume: the executor asks ``enough`` on the prefix ``[0, n)`` of the design for each
        ``n`` in turn, once every realization of that prefix has finished, and stops at the
        first ``n`` that answers True. The default (no points) runs the whole design.
        """
        return np.zeros(0, dtype=np.int64)

    def enough(self, design: xr.Dataset, runs: xr.Dataset) -> bool:
        """True when the first ``runs.sizes["realization"]`` realizations answer the question.

        Asked only at ``stop_points``; realizations past the stopping count are dropped.
        The default runs the whole design.
        """
        return False

    def __repr__(self) -> str:
        opts = ", ".join(f"{k}={v!r}" for k, v in self.options.model_dump().items())
        return f"{type(self).__name__}({opts})"


def make_design(space: InputSpace, values: np.ndarray, **variables) -> xr.Dataset:
    """A design dataset from an (n_realizations, n_inputs) array of parameter values."""
    values = np.asarray(values, dtype=float)
    values = values.reshape(values.shape[0] if values.ndim else 1, len(space))
    n = values.shape[0]
    data = {"inputs": (("realization", "parameter"), values)}
    data.update({k: ("parameter", v) for k, v in space.summary().items()})
    data["input_kurtosis"] = ("parameter", np.array([i.kurtosis for i in space.inputs]))
    data["input_correlation"] = (("parameter", "parameter_j"), space.correlation)
    data.update(variables)
    units = [inp.units for inp in space.inputs]
    return xr.Dataset(
        data,
        coords={"realization": np.arange(n), "parameter": space.names,
                "parameter_j": space.names,
                "parameter_units": ("parameter", units)},
    )


def output_names(runs: xr.Dataset) -> list[str]:
    """The solver outputs stored in ``runs`` (everything with a ``realization`` dim but ours)."""
    skip = {"inputs", "status", "message", "wall_time", "realization_seed", "clipped_points"}
    return [v for v in runs.data_vars if v not in skip and "realization" in runs[v].dims
            and not v.startswith(("germ_", "field_"))]


def ok_mask(runs: xr.Dataset) -> np.ndarray:
    return np.asarray(runs["status"].values == "ok")


def cost_attrs(runs: xr.Dataset) -> dict:
    status = runs["status"].values
    done = status != "pending"
    return {
        "solver_runs": int(done.sum()),
        "failed_runs": int((status == "failed").sum()),
        "solver_wall_time": float(np.nansum(runs["wall_time"].values[done])),
    }


def failure_warning(runs: xr.Dataset) -> list[str]:
    cost = cost_attrs(runs)
    if cost["failed_runs"]:
        return [f"{cost['failed_runs']} of {cost['solver_runs']} realizations failed; the "
                f"statistics use the others, which biases them if failures depend on the inputs"]
    return []


def finish_statistics(stats: xr.Dataset, design: xr.Dataset, runs: xr.Dataset,
                      method: str, warnings: list[str]) -> xr.Dataset:
    """Attach input summary, units, cost and warnings to a statistics dataset."""
    for v in ("input_mean", "input_std", "input_cv", "input_skewness", "input_kurtosis",
              "input_correlation"):
        if v in design:
            stats[v] = design[v]
    outputs = sorted(output_names(runs), key=len, reverse=True)
    for name in stats.data_vars:
        # y_max is its own output, not y's "_max" extra: the longest matching name owns it.
        owner = next((o for o in outputs if name == o or name.startswith(o + "_")), None)
        if owner is not None:
            stats[name].attrs.setdefault("units", runs[owner].attrs.get("units", ""))
    stats.attrs.update(cost_attrs(runs))
    stats.attrs["method"] = method
    stats.attrs["warnings"] = "\n".join(warnings)
    return stats
