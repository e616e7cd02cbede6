"""What multilevel and multifidelity Monte Carlo share: options, the sample streams, costs,
the accuracy target and the layout of their designs.

Design variables (dim ``realization``): ``level`` (the fidelity level the row runs at, an index
into the study's ``[levels] values``), ``seed_key`` (rows with one key are one sample at
several levels: same inputs, same realization seed), ``group`` (the estimator term the row
belongs to: the correction level for MLMC, the model for MFMC), ``sample`` (the sample's
index in its stream) and ``round`` (0 for the pilot, then one per re-plan).

Inputs: sample k of stream s is row k of ``SeedSequence(study seed, spawn_key=(s,))``'s
uniform draws mapped through the input space, so a sample's values do not depend on how
many rounds asked for it.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import xarray as xr
from pydantic import Field, field_validator, model_validator

from uqflow.errors import StudyError
from uqflow.layout import COMPILE_TIME, REALIZATION, ROUND, STATUS, STATUS_OK, UNITS, WALL_TIME
from uqflow.levels import LEVEL_VARIABLE, MAX_LEVELS, SEED_KEY_VARIABLE
from uqflow.methods.base import (MAX_REALIZATIONS, MethodOptions, PropagationMethod,
                                 make_design, output_names)
from uqflow.solver import is_diagnostic

#: seed keys of stream s are s * STREAM_STRIDE + k
STREAM_STRIDE = 2**32
#: runs of one sample at one correction level (a pair)
RUNS_PER_SAMPLE = 2
#: largest stated cost of a run: the study's total (every level's runs, up to max_samples
#: samples each) must stay a finite float64
MAX_COST = float(np.finfo(float).max) / (RUNS_PER_SAMPLE * MAX_LEVELS * MAX_REALIZATIONS)


class FidelityOptions(MethodOptions):
    target_rmse: float | None = Field(None, gt=0, description="root-mean-square error wanted, "
                                      "in the outputs' units (one allocating output)")
    target_rel_rmse: float | None = Field(None, gt=0, lt=1, description="root-mean-square "
                                          "error wanted, relative to each allocating output's "
                                          "largest |mean| over its points")
    pilot: int = Field(32, ge=3, le=100_000, description="samples per level (MLMC) or of "
                       "every model (MFMC) before the first allocation")
    costs: Literal["measured"] | list[float] = Field(
        "measured", description="cost of one run per level, coarsest first: 'measured' "
                                "(the pilot's median wall time per level) or numbers")
    allocate_on: list[str] | None = Field(None, description="outputs whose every point must "
                                          "meet the target (default: all)")
    allocate_at: dict[str, list[float | str]] | None = Field(
        None, description="only these points of the allocating outputs must meet it: "
                          "{dim = [coordinate values]}, the nearest for numbers")
    max_samples: int = Field(100_000, ge=1, le=MAX_REALIZATIONS,
                             description="most samples of any level or model")
    max_rounds: int = Field(8, ge=0, le=100, description="allocations after the pilot (0: "
                            "the pilot alone)")
    confidence: float = Field(0.95, gt=0, lt=1, description="level of the mean's interval")

    @field_validator("costs")
    @classmethod
    def _positive_costs(cls, costs):
        if isinstance(costs, list):
            bad = [c for c in costs if not c > 0]
            if bad:
                raise ValueError(f"every cost must be > 0, got {bad[0]!r}")
            huge = [c for c in costs if c > MAX_COST]
            if huge:
                raise ValueError(f"every cost must be <= {MAX_COST:.2g} (the study's total "
                                 f"cost, {RUNS_PER_SAMPLE} runs x {MAX_LEVELS} levels x up "
                                 f"to {MAX_REALIZATIONS:.0e} samples of them, must stay a "
                                 f"finite number; costs are relative, any unit), "
                                 f"got {huge[0]!r}")
        return costs

    @model_validator(mode="after")
    def _one_target(self):
        if (self.target_rmse is None) == (self.target_rel_rmse is None):
            raise ValueError("give exactly one of target_rmse and target_rel_rmse")
        return self


class FidelitySampling(PropagationMethod):
    """Base of the methods that sample the study's fidelity levels in rounds."""

    Options = FidelityOptions
    uses_levels = True
    extends = True

    def check_levels(self, levels) -> None:
        self.n_levels = len(levels)
        self.level_values = list(levels.values)
        costs = self.options.costs
        if isinstance(costs, list) and len(costs) != self.n_levels:
            raise StudyError(f"costs has {len(costs)} values for {self.n_levels} levels",
                             key="method.costs")

    def check_solver(self, solver, outputs, parameter_names):
        template = solver.outputs()
        for name in self.options.allocate_on or []:
            if name not in outputs:
                raise StudyError(f"'{name}' is not among the study's outputs "
                                 f"({', '.join(outputs)})", key="method.allocate_on")
            if is_diagnostic(template[name]):
                raise StudyError(f"'{name}' is a diagnostic of the run (a timing or a "
                                 f"counter), not an uncertain quantity to allocate on",
                                 key="method.allocate_on")
        chosen = self.options.allocate_on or \
            [n for n in outputs if not is_diagnostic(template[n])]
        if not chosen:
            raise StudyError(f"every output of the study ({', '.join(outputs)}) is a "
                             f"diagnostic of the run: list an uncertain quantity in outputs",
                             key="outputs")
        for dim, wanted in (self.options.allocate_at or {}).items():
            _check_allocate_at(template, chosen, dim, wanted)
        if self.options.target_rmse is not None and len(chosen) != 1:
            raise StudyError(f"target_rmse is in the units of one output, and {len(chosen)} "
                             f"allocate ({', '.join(chosen)}): name one with allocate_on = "
                             f"[\"...\"], or use target_rel_rmse", key="method.target_rmse")

    # --- designs ----------------------------------------------------------------------------

    def plan(self, space, fields, seed):
        self.check(space, fields)
        if not hasattr(self, "n_levels"):
            raise StudyError(f"method '{self.name}' needs the study's [levels]", key="levels")
        self._space, self._seed = space, seed
        return self.pilot_design()

    def draw(self, stream: int, start: int, stop: int) -> np.ndarray:
        """Parameter values of samples ``start..stop-1`` of ``stream``."""
        ss = np.random.SeedSequence(self._seed.entropy,
                                    spawn_key=(*self._seed.spawn_key, int(stream)))
        u = np.random.default_rng(ss).random((stop, len(self._space)))[start:]
        return self._space.from_unit_hypercube(u)

    def rows(self, blocks: list[tuple[int, int, int, int, int]], round_: int) -> xr.Dataset:
        """A design of ``blocks`` (level, group, stream, start, stop): samples start..stop-1
        of ``stream``, run at ``level``, belonging to estimator term ``group``."""
        values, level, group, sample, keys = [], [], [], [], []
        for lv, g, stream, start, stop in blocks:
            if stop <= start:
                continue
            values.append(self.draw(stream, start, stop))
            k = np.arange(start, stop)
            level.append(np.full(k.size, lv))
            group.append(np.full(k.size, g))
            sample.append(k)
            keys.append(stream * STREAM_STRIDE + k)
        cat = (lambda parts: np.concatenate(parts).astype(np.int64))
        return make_design(self._space, np.vstack(values), **{
            LEVEL_VARIABLE: (REALIZATION, cat(level)),
            "group": (REALIZATION, cat(group)),
            "sample": (REALIZATION, cat(sample)),
            SEED_KEY_VARIABLE: (REALIZATION, cat(keys)),
            ROUND: (REALIZATION, np.full(sum(p.size for p in level), round_,
                                             dtype=np.int64))})

    # --- costs and targets ------------------------------------------------------------------

    def run_costs(self, runs: xr.Dataset) -> np.ndarray:
        """Cost of one run per level: stated, or the median wall time of the pilot's
        successful runs (frozen at the pilot, so re-plans and resumes agree), less the time
        numba spent compiling in it: compiling is paid once per process, not per run."""
        if isinstance(self.options.costs, list):
            return np.asarray(self.options.costs, dtype=float)
        level = runs[LEVEL_VARIABLE].values
        pilot = (runs[ROUND].values == 0) & (runs[STATUS].values == STATUS_OK)
        seconds = np.asarray(runs[WALL_TIME].values, dtype=float)
        if COMPILE_TIME in runs:
            # NaN: a run that did not measure it (an older result); nothing to take off
            seconds = seconds - np.nan_to_num(np.asarray(runs[COMPILE_TIME].values,
                                                         dtype=float), nan=0.0)
        costs = np.array([np.median(seconds[pilot & (level == lv)])
                          if np.any(pilot & (level == lv)) else np.nan
                          for lv in range(self.n_levels)])
        if np.isnan(costs).any():
            # a level whose whole pilot failed: price it like the dearest level measured
            costs = np.where(np.isnan(costs), np.nanmax(costs) if np.isfinite(costs).any()
                             else 1.0, costs)
        return np.maximum(costs, 1e-9)

    def allocating(self, runs: xr.Dataset) -> list[str]:
        """The outputs whose chosen points must meet the target: ``allocate_on``, or every
        uncertain output (never a diagnostic such as a timing)."""
        return list(self.options.allocate_on or output_names(runs))

    def variance_targets(self, means: dict[str, np.ndarray],
                         runs: xr.Dataset) -> dict[str, np.ndarray]:
        """eps^2 per point of each allocating output, from the current mean estimates; NaN
        at the points ``allocate_at`` leaves out (they then drive nothing)."""
        out = {}
        for name, mean in means.items():
            chosen = self.allocated_points(runs, name)
            if self.options.target_rmse is not None:
                eps = self.options.target_rmse
            else:
                picked = np.abs(mean)[chosen]
                scale = np.nanmax(picked) if np.isfinite(picked).any() else np.nan
                eps = self.options.target_rel_rmse * scale
            # numpy's square: a target whose square overflows is inf (met by any stderr),
            # not Python's OverflowError
            with np.errstate(over="ignore"):
                out[name] = np.where(chosen, np.square(np.float64(eps)), np.nan)
        return out

    def target_not_met(self, runs: xr.Dataset, name: str, stderr: np.ndarray,
                       allowed2: np.ndarray, drawn: np.ndarray) -> str | None:
        """A warning when a point of output ``name`` chosen to meet the target does not:
        its ``stderr`` (flat, per point) above the allowed variance ``allowed2``, or either
        unknown (a level without successful runs, a target relative to an unknown mean) —
        never silence where the target cannot be shown met. ``drawn``: samples drawn per
        level or model, to say why the study stopped."""
        chosen = self.allocated_points(runs, name)
        if not chosen.any():
            return f"{name}: no point is chosen to meet the target (allocate_at), so it is " \
                   f"not met"
        with np.errstate(invalid="ignore"):
            # a target met exactly may differ from it by the roundings of the sums: 1e-9 ≫ eps
            met = stderr**2 <= allowed2 * (1 + 1e-9)
            ratio = np.where(np.isfinite(stderr**2 / allowed2), stderr**2 / allowed2, np.inf)
        short = np.flatnonzero(chosen & ~met)
        if not short.size:
            return None
        k = int(short[np.argmax(ratio[short])])
        got = f"stderr {stderr[k]:.3g}" if np.isfinite(stderr[k]) else "stderr unknown"
        wanted = f"{np.sqrt(allowed2[k]):.3g}" if np.isfinite(allowed2[k]) else "unknown"
        return (f"{point_label(runs, name, k)}: target not met: {got}, wanted at most "
                f"{wanted}; {self.stop_reason(runs, drawn)}")

    def stop_reason(self, runs: xr.Dataset, drawn: np.ndarray) -> str:
        """Why the rounds stopped short of the target."""
        if int(runs[ROUND].values.max()) >= self.options.max_rounds:
            return f"max_rounds = {self.options.max_rounds} reached"
        if np.any(np.asarray(drawn) >= self.options.max_samples):
            return f"max_samples = {self.options.max_samples} reached"
        return ("no more samples could be allocated, as a level's variance or the target is "
                "unknown (runs failed, or target_rel_rmse of a mean of 0)")

    def allocated_points(self, runs: xr.Dataset, name: str) -> np.ndarray:
        """Which flattened points of output ``name`` must meet the target."""
        dims, shape = output_shape(runs, name)
        keep = [np.ones(n, dtype=bool) for n in shape]
        for dim, wanted in (self.options.allocate_at or {}).items():
            if dim not in dims:
                continue
            axis = dims.index(dim)
            coord = runs[dim].values if dim in runs.coords else np.arange(shape[axis])
            mask = np.zeros(shape[axis], dtype=bool)
            for value in wanted:
                if isinstance(value, str):
                    mask |= coord.astype(str) == value
                else:
                    mask[int(np.argmin(np.abs(coord.astype(float) - value)))] = True
            keep[axis] = mask
        full = np.ones(shape, dtype=bool)
        for axis, mask in enumerate(keep):
            full &= mask.reshape([-1 if a == axis else 1 for a in range(len(shape))])
        return full.reshape(-1)


def _check_allocate_at(template: xr.Dataset, chosen: list[str], dim: str, wanted: list) -> None:
    """Refuse at load what ``allocate_at``'s ``dim`` cannot pick: no value, a dim no allocating
    output has, a value of the wrong type for the coordinate (a number for named probes, a
    name for times) or a name that is not a coordinate."""
    key = f"method.allocate_at.{dim}"
    if not wanted:
        raise StudyError(f"give at least one '{dim}' value (an empty list would leave no "
                         f"point to meet the target); drop '{dim}' to allocate on every one",
                         key=key)
    holders = [n for n in chosen if dim in template[n].dims]
    if not holders:
        raise StudyError(f"no allocating output has a dimension '{dim}' "
                         f"({', '.join(f'{n}: {template[n].dims}' for n in chosen)})", key=key)
    if dim not in template.coords:
        names = [v for v in wanted if isinstance(v, str)]
        if names:
            raise StudyError(f"'{dim}' has no coordinate values, so '{names[0]}' names no "
                             f"point: give positions 0 .. {template.sizes[dim] - 1}", key=key)
        return
    known = np.asarray(template[dim].values)
    if known.dtype.kind in "iuf":
        names = [v for v in wanted if isinstance(v, str)]
        if names:
            raise StudyError(f"'{dim}' coordinates are numbers ({_span(template[dim])}), got the "
                             f"string '{names[0]}': give a number (the nearest point is taken)",
                             key=key)
        return
    labels = [str(v) for v in known]
    for value in wanted:
        if not isinstance(value, str):
            raise StudyError(f"'{dim}' coordinates are names ({', '.join(labels)}), got the "
                             f"number {value!r}: give one of the names as a string", key=key)
        if value not in labels:
            raise StudyError(f"'{value}' is not a '{dim}' coordinate ({', '.join(labels)})",
                             key=key)


def _span(coord: xr.DataArray) -> str:
    values = np.asarray(coord.values)
    units = f" {coord.attrs['units']}" if coord.attrs.get(UNITS) else ""
    return (f"{values.size} values from {values.min():g} to {values.max():g}{units}"
            if values.size > 1 else f"{values[0]:g}{units}")


def point_label(runs: xr.Dataset, name: str, flat_index: int) -> str:
    """Output ``name`` at the point ``flat_index`` of its flattened values, by coordinates:
    "S11 at t = 9e-06 s, probe = H" (a position where a dim has no coordinate)."""
    dims, shape = output_shape(runs, name)
    if not dims:
        return name
    parts = []
    for dim, i in zip(dims, np.unravel_index(int(flat_index), shape)):
        if dim in runs.coords:
            value = runs[dim].values[i]
            units = str(runs[dim].attrs.get(UNITS, ""))
            shown = f"{value:g}" if isinstance(value, (int, float, np.number)) else str(value)
            parts.append(f"{dim} = {shown}" + (f" {units}" if units else ""))
        else:
            parts.append(f"{dim} = #{int(i)}")
    return f"{name} at {', '.join(parts)}"


def flat(runs: xr.Dataset, name: str, rows: np.ndarray) -> np.ndarray:
    """Output ``name`` of realizations ``rows`` as (rows, points)."""
    values = np.asarray(runs[name].values, dtype=float)[rows]
    # the point count from the shape, not -1: no rows (a level whose runs all failed) has 0
    return values.reshape(values.shape[0], int(np.prod(values.shape[1:])))


def output_shape(runs: xr.Dataset, name: str) -> tuple[tuple, tuple]:
    """(dims, shape) of one realization of output ``name``."""
    var = runs[name]
    dims = tuple(d for d in var.dims if d != REALIZATION)
    return dims, tuple(var.sizes[d] for d in dims)
