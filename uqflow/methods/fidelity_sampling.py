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
from pydantic import Field, model_validator

from uqflow.errors import StudyError
from uqflow.levels import LEVEL_VARIABLE, SEED_KEY_VARIABLE
from uqflow.methods.base import (MAX_REALIZATIONS, MethodOptions, PropagationMethod,
                                 make_design, output_names)

#: seed keys of stream s are s * STREAM_STRIDE + k
STREAM_STRIDE = 2**32


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

    @model_validator(mode="after")
    def _one_target(self):
        if (self.target_rmse is None) == (self.target_rel_rmse is None):
            raise ValueError("give exactly one of target_rmse and target_rel_rmse")
        if isinstance(self.costs, list) and any(not c > 0 for c in self.costs):
            raise ValueError("every cost must be > 0")
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
        chosen = self.options.allocate_on or outputs
        for name in chosen:
            if name not in outputs:
                raise StudyError(f"'{name}' is not among the study's outputs "
                                 f"({', '.join(outputs)})", key="method.allocate_on")
        at = self.options.allocate_at or {}
        template = solver.outputs()
        for dim, wanted in at.items():
            holders = [n for n in chosen if dim in template[n].dims]
            if not holders:
                raise StudyError(f"no allocating output has a dimension '{dim}' "
                                 f"({', '.join(f'{n}: {template[n].dims}' for n in chosen)})",
                                 key=f"method.allocate_at.{dim}")
            known = template[holders[0]][dim].values if dim in template.coords else None
            for value in wanted:
                if isinstance(value, str) and (known is None or value not in known.astype(str)):
                    raise StudyError(f"'{value}' is not a '{dim}' coordinate"
                                     + (f" ({', '.join(map(str, known))})" if known is not None
                                        else ""), key=f"method.allocate_at.{dim}")
        if self.options.target_rmse is not None and len(chosen) != 1:
            raise StudyError("target_rmse is in the units of one output: name it with "
                             "allocate_on = [\"...\"], or use target_rel_rmse",
                             key="method.target_rmse")

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
            LEVEL_VARIABLE: ("realization", cat(level)),
            "group": ("realization", cat(group)),
            "sample": ("realization", cat(sample)),
            SEED_KEY_VARIABLE: ("realization", cat(keys)),
            "round": ("realization", np.full(sum(p.size for p in level), round_,
                                             dtype=np.int64))})

    # --- costs and targets ------------------------------------------------------------------

    def run_costs(self, runs: xr.Dataset) -> np.ndarray:
        """Cost of one run per level: stated, or the median wall time of the pilot's
        successful runs (frozen at the pilot, so re-plans and resumes agree)."""
        if isinstance(self.options.costs, list):
            return np.asarray(self.options.costs, dtype=float)
        level = runs[LEVEL_VARIABLE].values
        pilot = (runs["round"].values == 0) & (runs["status"].values == "ok")
        costs = np.array([np.median(runs["wall_time"].values[pilot & (level == lv)])
                          if np.any(pilot & (level == lv)) else np.nan
                          for lv in range(self.n_levels)])
        if np.isnan(costs).any():
            # a level whose whole pilot failed: price it like the dearest level measured
            costs = np.where(np.isnan(costs), np.nanmax(costs) if np.isfinite(costs).any()
                             else 1.0, costs)
        return np.maximum(costs, 1e-9)

    def allocating(self, runs: xr.Dataset) -> list[str]:
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
            out[name] = np.where(chosen, float(eps) ** 2, np.nan)
        return out

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


def flat(runs: xr.Dataset, name: str, rows: np.ndarray) -> np.ndarray:
    """Output ``name`` of realizations ``rows`` as (rows, points)."""
    values = np.asarray(runs[name].values, dtype=float)[rows]
    return values.reshape(values.shape[0], -1)


def output_shape(runs: xr.Dataset, name: str) -> tuple[tuple, tuple]:
    """(dims, shape) of one realization of output ``name``."""
    var = runs[name]
    dims = tuple(d for d in var.dims if d != "realization")
    return dims, tuple(var.sizes[d] for d in dims)
