"""Reductions of MPM results that a user (and the benchmarks) take before computing
statistics: an output at one time, each realization's peak over time, and the plain Monte
Carlo samples inside a control-variate design.

They act on the runs of a result (``uqflow.layout``'s names: dims ``realization``, ``time``,
sensitivity runs on ``sensitivity_run``); nothing in them is particular to the MPM kernels.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from uqflow.layout import (REALIZATION, ROLE, SENSITIVITY_COORD, SENSITIVITY_DIM,
                           WITH_SENSITIVITIES, gradient_variable, hessian_variable)
from uqflow.methods.control_variate import control_count

TIME = "time"
# what a control-variate or Taylor design adds to plain Monte Carlo's rows and attributes
_DESIGN_ONLY_VARIABLES = (ROLE, "offset", "stencil", WITH_SENSITIVITIES)
_DESIGN_ONLY_ATTRS = ("control", "control_runs", "normal_inputs", "control_step")


def at_time(runs: xr.Dataset, time: float) -> xr.Dataset:
    """Every output (and its derivatives) at the output time nearest ``time`` (s)."""
    k = int(np.argmin(np.abs(runs[TIME].values - time)))
    return runs.isel({TIME: k})


def peak_over_time(runs: xr.Dataset, outputs) -> xr.Dataset:
    """Each realization's max |y| over time of each of ``outputs`` (dims realization, time,
    ...), time dropped; the derivatives of a sensitivity run are taken at its own argmax time
    with the sign of y there (d|y|/dθ = sign(y) dy/dθ). A NaN never wins the max."""
    reduced = runs.drop_dims(TIME)
    for out in outputs:
        y = np.asarray(runs[out].transpose(REALIZATION, TIME, ...).values, float)
        k = np.argmax(np.nan_to_num(np.abs(y), nan=-1.0), axis=1)
        at = np.take_along_axis(y, k[:, None, ...], axis=1)[:, 0, ...]
        dims = tuple(d for d in runs[out].transpose(REALIZATION, TIME, ...).dims if d != TIME)
        reduced[out] = (dims, np.abs(at), runs[out].attrs)
        if gradient_variable(out) not in runs:
            continue
        rows = np.asarray(runs[SENSITIVITY_COORD].values, int)
        sign = np.sign(at[rows])                                  # (sensitivity_run, ...)
        for name, extra in ((gradient_variable(out), 1), (hessian_variable(out), 2)):
            d = np.asarray(runs[name].values, float)          # (s, time, ..., param[, param])
            idx = k[rows].reshape(k[rows].shape[0], 1, *k.shape[1:], *([1] * extra))
            picked = np.take_along_axis(d, idx, axis=1)[:, 0]
            picked = picked * sign.reshape(*sign.shape, *([1] * extra))
            dims = tuple(dim for dim in runs[name].dims if dim != TIME)
            reduced[name] = (dims, picked, runs[name].attrs)
    return reduced


def monte_carlo_part(design: xr.Dataset, runs: xr.Dataset, n: int | None = None):
    """(design, runs) of the Monte Carlo samples of a (control-variate) design, without the
    control rows or sensitivity variables, renumbered from 0: the first ``n`` of them (all
    with None) — what plain Monte Carlo on the same points would have planned and run."""
    m = control_count(design)
    stop = None if n is None else m + n
    d = design.isel({REALIZATION: slice(m, stop)})
    r = runs.isel({REALIZATION: slice(m, stop)})
    if SENSITIVITY_DIM in r.dims:
        r = r.drop_dims(SENSITIVITY_DIM)
    d = d.drop_vars([v for v in _DESIGN_ONLY_VARIABLES if v in d.variables])
    r = r.drop_vars([v for v in _DESIGN_ONLY_VARIABLES if v in r.variables])
    index = np.arange(d.sizes[REALIZATION])
    d, r = d.assign_coords({REALIZATION: index}), r.assign_coords({REALIZATION: index})
    d.attrs = {k: v for k, v in design.attrs.items() if k not in _DESIGN_ONLY_ATTRS}
    return d, r
