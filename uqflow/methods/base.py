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
``status`` ("ok", "failed" or "pending"), ``message``, ``wall_time`` (s) and ``compile_time``
(s, the part of ``wall_time`` numba spent compiling). Outputs a solver marks as diagnostics
(``is_diagnostic``: timings, counters) are stored there too, but are no uncertain quantity:
``output_names`` leaves them out, so no method gives them statistics.

Local sensitivities (an optional solver capability, ``uqflow.solver``): a design's boolean
``with_sensitivities`` (realization) asks the executor to run those realizations with the
solver's local derivatives; the runs then hold ``{out}__gradient`` and ``{out}__hessian`` on
the ``sensitivity_run`` dim (``uqflow.realization.sensitivity_arrays``). A method that needs
the capability says so in ``check_solver``, called when the study is loaded.

Statistics (xr.Dataset): every output with a leading ``statistic`` dimension, the input
summary, and attributes ``method``, ``solver_runs``, ``failed_runs``, ``solver_wall_time``,
``solver_compile_time`` and ``warnings`` (one warning per line). Each output's statistics keep
its dims (after ``statistic`` and the method's own dims); a method that reduces some away (a
time series averaged to one number) gets a warning naming the output and the dims.
"""

from __future__ import annotations

import abc
import types
from typing import Annotated, Any, ClassVar, Literal, Union, get_args, get_origin

import numpy as np
import xarray as xr
from pydantic import BaseModel, ConfigDict, field_validator

from uqflow.errors import StudyError
from uqflow.inputs import InputSpace
from uqflow.registry import method_registry
from uqflow.layout import (COMPILE_TIME, FAILED_RUNS, INPUT_CORRELATION, INPUT_KURTOSIS,
                           INPUT_SUMMARY, INPUTS, METHOD, PARAMETER, PARAMETER_J,
                           PARAMETER_UNITS, REALIZATION, SOLVER_COMPILE_TIME, SOLVER_RUNS,
                           SOLVER_WALL_TIME, STATISTIC, STATUS, STATUS_FAILED, STATUS_PENDING,
                           UNITS, WALL_TIME, WARNINGS, output_names)
# What every method needs beside the contract, importable from ``uqflow.methods`` as the
# README's custom method does; ``uqflow.layout`` is their home.
from uqflow.layout import is_diagnostic, ok_mask, sample_mask  # noqa: F401 (re-exported)


def register_method(name: str):
    """Class decorator: make a PropagationMethod available to study files as ``kind = name``."""
    return method_registry.register(name)


def get_method(name: str) -> type["PropagationMethod"]:
    return method_registry.get(name)


# Upper bounds of the counts a method option can ask for, so that what validates can run
# (docs/study-files.md, "Limits"). A design holds realizations × inputs float64 values and the
# runs one status, message and wall time per realization (~100 bytes with the strings):
# 10^7 realizations are ~1 GiB before any output, and take hours even at 1 ms each.
MAX_REALIZATIONS = 10**7
# A bootstrap draws base samples × resamples int64 indices at once (SALib): 10^8 is 0.8 GiB.
MAX_BOOTSTRAP_DRAWS = 10**8
# An integer option that states no upper bound of its own gets this one (a count beyond it
# is either more realizations than above or a loop no run would finish).
MAX_COUNT = MAX_REALIZATIONS


class MethodOptions(BaseModel):
    """Options of a method, validated from the study file's ``[method]`` table.

    Validation is strict, for every subclass (third-party methods included): an ``int``
    option takes a TOML integer only (not ``1000.0``, ``1e3`` or ``"1000"``), a ``float``
    option an integer or a float, never a boolean or a string, and never NaN or infinity;
    ``Literal`` options of numbers refuse booleans and fractions (``order = true``).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_lookalike_numbers(cls, value, info):
        # Literal[1, 2] compares by equality, so true and 1.0 would pass it as 1; strict mode
        # does not cover Literal.
        annotation = cls.model_fields[info.field_name].annotation
        if isinstance(value, bool) and not _admits(annotation, bool):
            what = "an integer" if _admits(annotation, int) else \
                "a number" if _admits(annotation, float) else "one of the values listed"
            raise ValueError(f"must be {what}, not a boolean, got {str(value).lower()}")
        if isinstance(value, float) and not _admits(annotation, float) and \
                _admits(annotation, int):
            raise ValueError(f"must be an integer: write {value:.0f}, not {value!r}"
                             if value.is_integer() else f"must be an integer, got {value!r}")
        if isinstance(value, int) and not isinstance(value, bool) and value > MAX_COUNT and \
                _admits(annotation, int) and not _has_upper_bound(cls.model_fields[
                    info.field_name]):
            raise ValueError(f"must be <= {MAX_COUNT:,} (the largest count uqflow runs; "
                             f"docs/study-files.md, Limits), got {value:,}")
        return value

    def only_where(self, key: str, applies: bool, where: str) -> "MethodOptions":
        """Refuse ``key`` set in the study file where it has no effect (an option silently
        ignored would mislead): "'key' applies to <where> (drop the key)"."""
        if key in self.model_fields_set and not applies:
            raise ValueError(f"'{key}' applies to {where} (drop the key)")
        return self


def _has_upper_bound(info) -> bool:
    return any(getattr(m, "le", None) is not None or getattr(m, "lt", None) is not None
               for m in info.metadata)


def _admits(annotation, kind: type) -> bool:
    """Whether a field annotated ``annotation`` is meant to take values of type ``kind``."""
    if annotation is kind or annotation is Any:
        return True
    origin = get_origin(annotation)
    if origin is Literal:
        return any(type(v) is kind for v in get_args(annotation))
    if origin is Annotated:
        return _admits(get_args(annotation)[0], kind)
    if origin in (Union, types.UnionType):
        return any(_admits(a, kind) for a in get_args(annotation))
    return False


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

    def check_solver(self, solver, outputs: list[str], parameter_names: list[str]) -> None:
        """Raise ``StudyError`` if this method cannot use ``solver`` for ``outputs`` with the
        uncertain ``parameter_names`` (e.g. a capability it needs); run at load time after
        ``check``. The default accepts every solver."""

    @abc.abstractmethod
    def plan(self, space: InputSpace, fields: list | None,
             seed: np.random.SeedSequence) -> xr.Dataset:
        """The realizations to run (see the module docstring for the layout)."""

    @abc.abstractmethod
    def analyze(self, design: xr.Dataset, runs: xr.Dataset) -> xr.Dataset:
        """Statistics of the outputs in ``runs`` (failed realizations have NaN outputs)."""

    #: whether the method runs the solver at the study's fidelity levels (``[levels]``)
    uses_levels: ClassVar[bool] = False
    #: whether the method adds realizations after seeing runs (``extend``)
    extends: ClassVar[bool] = False

    #: whether the method estimates failure probabilities of the study's [[limit_states]]
    uses_limit_states: ClassVar[bool] = False
    #: the study's ``uqflow.limit_states.LimitStates`` (None without [[limit_states]])
    limit_states = None

    def check_limit_states(self, limit_states) -> None:
        """Take the study's ``uqflow.limit_states.LimitStates``, or None when it declares no
        [[limit_states]]; called at load time after ``check_solver``. The default refuses
        limit states a method does not use (its result would silently ignore them) and
        stores them as ``self.limit_states``; a method that needs them refuses None."""
        if limit_states is not None and not self.uses_limit_states:
            users = [name for name in method_registry.names()
                     if getattr(method_registry.get(name), "uses_limit_states", False)]
            instead = "kind = " + " or ".join(f'"{n}"' for n in users) if users else \
                "a method that does"
            raise StudyError(f"method '{self.name}' estimates no failure probability: drop "
                             f"the [[limit_states]] tables, or use {instead}",
                             key="limit_states")
        self.limit_states = limit_states

    def check_levels(self, levels) -> None:
        """Take the study's ``uqflow.levels.Levels`` (raise ``StudyError`` if unusable);
        called at load time for a method with ``uses_levels``."""

    def extend(self, design: xr.Dataset, runs: xr.Dataset) -> xr.Dataset | None:
        """More realizations to run, as a design of new rows, or None when done.

        Asked by the executor only when every realization so far has finished, with the whole
        design and runs so far, again after the new rows finish, until it answers None. The
        answer must depend on the design and the runs alone (their outputs and statuses, and
        values frozen in them such as a pilot's wall times), never on worker count, batches
        or a resume: a killed study resumed asks the same questions of the same runs.
        The default adds nothing.
        """
        return None

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

    @classmethod
    def report(cls, view):
        """What this method adds to the report of its results: a ``uqflow.report.MethodReport``
        (columns of the summary table, notes, cost details, sensitivities, figures, and whether
        its runs are draws from the inputs' distribution), built from ``view``
        (``uqflow.report.ResultView``: the result's statistics, runs and attributes; the
        method's options are in the statistics' attributes). None (the default): the report
        shows what every result has, and nothing of the method's own.
        """
        return None

    @classmethod
    def compare(cls, trees: list, folder, figures: bool = True) -> tuple[str, list]:
        """What ``uqflow report a.nc b.nc`` adds when results of this method are among
        ``trees``: a text and the figures written into ``folder`` (none unless ``figures``).
        ("", []) by default."""
        return "", []

    def __repr__(self) -> str:
        opts = ", ".join(f"{k}={v!r}" for k, v in self.options.model_dump().items())
        return f"{type(self).__name__}({opts})"


def make_design(space: InputSpace, values: np.ndarray, **variables) -> xr.Dataset:
    """A design dataset from an (n_realizations, n_inputs) array of parameter values."""
    values = np.asarray(values, dtype=float)
    values = values.reshape(values.shape[0] if values.ndim else 1, len(space))
    n = values.shape[0]
    data = {INPUTS: ((REALIZATION, PARAMETER), values)}
    data.update({k: (PARAMETER, v) for k, v in space.summary().items()})
    data[INPUT_KURTOSIS] = (PARAMETER, np.array([i.kurtosis for i in space.inputs]))
    data[INPUT_CORRELATION] = ((PARAMETER, PARAMETER_J), space.correlation)
    data.update(variables)
    units = [inp.units for inp in space.inputs]
    return xr.Dataset(
        data,
        coords={REALIZATION: np.arange(n), PARAMETER: space.names,
                PARAMETER_J: space.names,
                PARAMETER_UNITS: (PARAMETER, units)},
    )


def cost_attrs(runs: xr.Dataset) -> dict:
    status = runs[STATUS].values
    done = status != STATUS_PENDING
    cost = {
        SOLVER_RUNS: int(done.sum()),
        FAILED_RUNS: int((status == STATUS_FAILED).sum()),
        SOLVER_WALL_TIME: float(np.nansum(runs[WALL_TIME].values[done])),
    }
    if COMPILE_TIME in runs:
        cost[SOLVER_COMPILE_TIME] = float(np.nansum(runs[COMPILE_TIME].values[done]))
    return cost


def failure_warning(runs: xr.Dataset) -> list[str]:
    cost = cost_attrs(runs)
    if cost[FAILED_RUNS]:
        return [f"{cost[FAILED_RUNS]} of {cost[SOLVER_RUNS]} realizations failed; the "
                f"statistics use the others, which biases them if failures depend on the inputs"]
    return []


def finish_statistics(stats: xr.Dataset, design: xr.Dataset, runs: xr.Dataset,
                      method: str, warnings: list[str]) -> xr.Dataset:
    """Attach input summary, units, cost and warnings to a statistics dataset."""
    for v in INPUT_SUMMARY:
        if v in design:
            stats[v] = design[v]
    outputs = sorted(output_names(runs), key=len, reverse=True)
    for name in stats.data_vars:
        # y_max is its own output, not y's "_max" extra: the longest matching name owns it.
        owner = next((o for o in outputs if name == o or name.startswith(o + "_")), None)
        if owner is not None:
            stats[name].attrs.setdefault(UNITS, runs[owner].attrs.get(UNITS, ""))
    stats.attrs.update(cost_attrs(runs))
    stats.attrs[METHOD] = method
    stats.attrs[WARNINGS] = "\n".join([*warnings, *reduced_dims_warnings(stats, runs)])
    return stats


def reduced_dims_warnings(stats: xr.Dataset, runs: xr.Dataset) -> list[str]:
    """A warning per output whose statistics lack some of its dims in ``runs``: the method
    reduced them (a time series averaged into one number), and a reader of the result
    should know the numbers are not per point."""
    found = []
    for out in output_names(runs):
        if out not in stats.data_vars or STATISTIC not in stats[out].dims:
            continue
        lost = [d for d in runs[out].dims if d != REALIZATION and d not in stats[out].dims]
        if lost:
            found.append(f"the statistics of '{out}' have no dim {', '.join(map(repr, lost))} "
                         f"of its runs: the method reduced them (its numbers are not per "
                         f"point of {', '.join(lost)})")
    return found
