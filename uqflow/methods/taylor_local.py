"""Local Taylor method (``taylor-local``): the moments of the outputs from ONE solver run.

Seed 000, sections 4-5: the solver runs once at the input means and returns, besides the
outputs, their analytic derivatives with respect to the inputs at the state it computed (the
optional Solver capability ``run_with_sensitivities``). The mean is the second-order
expansion (eq. 22), the variance the first-order one (eq. 24), both with the inputs'
correlations; the moment formulas are those of ``taylor``, which gets the same derivatives by
differentiating the whole solver (2n + 1 runs). A local derivative holds the solver's state
fixed (a "frozen state"), so it leaves out the feedback of a parameter on the history that
led to that state. See docs/taylor_local.md.
"""

from __future__ import annotations

import warnings as pywarnings
from typing import Literal

import numpy as np
import xarray as xr
from pydantic import Field

from uqflow.errors import AccuracyWarning, StudyError
from uqflow.methods.base import (MethodOptions, PropagationMethod, finish_statistics,
                                 is_diagnostic, make_design, output_names, register_method)
from uqflow.layout import (INPUT_CORRELATION, INPUT_CV, INPUT_KURTOSIS, INPUT_SKEWNESS, INPUT_STD,
                           MESSAGE, PARAMETER, PARAMETER_J, REALIZATION, SOLVER_RUNS, STATISTIC,
                           STATUS, STATUS_OK, STATUS_PENDING, UNITS)
from uqflow.methods.taylor import (LABELS, _label, _per_param, _second_order_variance,
                                   contributions, cv_warnings)
from uqflow.report import MethodReport
from uqflow.realization import SENSITIVITY_FLAG, sensitivity_arrays

#: the realization of the design (its only one)
CENTRE = 0
# Warn where |mean_2 - f(mu)| > this x std_1. For one normal input and a quadratic f the
# first-order variance is then short of the exact one, g^2 s^2 + H^2 s^4 / 2, by more than
# 2 q^2 = 20 % (q the ratio): the accuracy the seed's tables are read to (issue 9).
CURVATURE_RATIO_WARNING = 0.1**0.5
FROZEN_STATE = ("frozen state: the derivatives are the solver's local ones, at the state its "
                "one run computed, so where an output depends on a history (the MPM's "
                "deformation) the feedback of a parameter on that history (a stronger material "
                "deforms less) is left out; kind = \"taylor\" keeps it. For closed-form "
                "models the local derivatives are the exact ones")
ALTERNATIVE = "use kind = \"taylor\" (whole-solver finite differences, 2n+1 runs)"


class TaylorLocalOptions(MethodOptions):
    order: Literal[1, 2] = Field(2, description="1: mean = f(mu); 2: mean with curvature "
                                                "(seed 000 eq. 22)")
    variance: Literal["first-order", "second-order"] = Field(
        "first-order", description="first-order: seed 000 eq. 24; second-order: the full "
                                   "variance of the quadratic expansion (normal inputs, or "
                                   "independent ones)")
    cv_warning: float = Field(0.15, ge=0, description="warn about inputs with a larger C.V. "
                                                      "(seed 000 sec. 4.1)")


def _correlated(rho: np.ndarray, active: np.ndarray) -> bool:
    return any(rho[k, j] != 0 for k in active for j in active if k < j)


@register_method("taylor-local")
class TaylorLocal(PropagationMethod):
    """One run at the input means with the solver's local gradient and Hessian."""

    Options = TaylorLocalOptions

    # ------------------------------------------------------------------ plan
    def check(self, space, fields):
        super().check(space, fields)
        active = np.flatnonzero(space.stds > 0)
        normal = all(space.inputs[k].kind == "normal" for k in active)
        if self.options.variance == "second-order" and not normal and \
                _correlated(space.correlation, active):
            raise StudyError("the second-order variance needs the joint third and fourth "
                             "moments of the inputs: closed-form for normal inputs (any "
                             "correlation) or independent ones, not for correlated non-normal "
                             "inputs; use variance = \"first-order\" or monte-carlo",
                             key="method.variance")

    def check_solver(self, solver, outputs, parameter_names):
        # a diagnostic (a timing, a counter) is no uncertain quantity: it needs no derivative
        # (a stand-in without the Solver base class may have no template to say so)
        template = solver.outputs() if hasattr(solver, "outputs") else {}
        outputs = [o for o in outputs if o not in template or not is_diagnostic(template[o])]
        available = solver.local_sensitivities()
        label = _solver_label(solver)
        if not available:
            raise StudyError(f"solver '{label}' has no local sensitivities (it cannot return "
                             f"derivatives of its outputs from one run); {ALTERNATIVE}",
                             key="method.kind")
        for out in outputs:
            if out not in available:
                having = ", ".join(available)
                raise StudyError(f"output '{out}' has no local derivative in solver "
                                 f"'{label}' (those with one: {having}); {ALTERNATIVE}",
                                 key="outputs")
            missing = [p for p in parameter_names if p not in available[out]]
            if missing:
                raise StudyError(f"output '{out}' has no local derivative with respect to "
                                 f"input '{missing[0]}' in solver '{label}'; {ALTERNATIVE}",
                                 key="outputs")

    def plan(self, space, fields, seed):
        self.check(space, fields)
        active = np.flatnonzero(space.stds > 0)
        design = make_design(space, space.means[None, :],
                             **{SENSITIVITY_FLAG: (REALIZATION, np.array([True]))})
        design.attrs["normal_inputs"] = int(all(space.inputs[k].kind == "normal"
                                                for k in active))
        return design

    # --------------------------------------------------------------- analyze
    def analyze(self, design, runs):
        opts = self.options
        names = [str(p) for p in design[PARAMETER].values]
        s = design[INPUT_STD].values
        rho = design[INPUT_CORRELATION].values
        active = np.flatnonzero(s > 0)
        normal = bool(design.attrs.get("normal_inputs", 0))
        if opts.variance == "second-order" and not normal and _correlated(rho, active):
            raise StudyError("the second-order variance of correlated non-normal inputs has "
                             "no closed form; use variance = \"first-order\"",
                             key="method.variance")
        covariance = np.outer(s, s) * rho
        mu3 = np.where(s > 0, design[INPUT_SKEWNESS].values * s**3, 0.0)
        mu4 = np.where(s > 0, np.nan_to_num(design[INPUT_KURTOSIS].values) * s**4, 0.0)

        status = runs[STATUS].values[CENTRE]
        warnings = []
        if status != STATUS_OK:
            why = "did not run" if status == STATUS_PENDING else \
                (str(runs[MESSAGE].values[CENTRE]) or "no message")
            warnings.append(f"the one realization (at the input means) failed: {why}; every "
                            f"estimate is NaN")
        data = {}
        for out in output_names(runs):
            dims = runs[out].dims[1:]
            f0 = np.asarray(runs[out].values[CENTRE], dtype=float)
            index, gradients, hessians = sensitivity_arrays(runs, out)
            run = int(np.flatnonzero(index == CENTRE)[0])
            # the derivatives' parameter axes first, as taylor stores them
            g = np.moveaxis(gradients[run], -1, 0)
            hess = np.moveaxis(hessians[run], (-2, -1), (0, 1))
            if status != STATUS_OK:
                f0, g, hess = (np.full_like(a, np.nan) for a in (f0, g, hess))
            curvature = 0.5 * np.einsum("kj...,kj->...", hess, covariance)
            first_order = np.einsum("k...,kj,j...->...", g, covariance, g)
            mean = f0 + curvature if opts.order == 2 else f0.copy()
            if opts.variance == "first-order":
                var = first_order
            elif normal:
                # Gaussian d: g.d and d'Hd/2 are uncorrelated (odd moments vanish) and
                # Var(d'Hd/2) = tr((H C)^2)/2 by Isserlis' theorem, for any correlation C.
                hc = np.einsum("ki...,ij->kj...", hess, covariance)
                var = first_order + 0.5 * np.einsum("kj...,jk...->...", hc, hc)
            else:
                computed = np.ones((len(names), len(names)), dtype=bool)
                var = _second_order_variance(g, hess, computed, s, mu3, mu4, dims)
            std = np.sqrt(np.maximum(var, 0.0))
            std_first = np.sqrt(np.maximum(first_order, 0.0))
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = np.where(curvature == 0, 0.0, np.abs(curvature) / std_first)
            units = runs[out].attrs.get(UNITS, "")
            data[out] = ((STATISTIC, *dims), np.stack([mean, var, std, f0]))
            data[f"{out}_gradient"] = ((PARAMETER, *dims), g, {
                "long_name": f"local d{out}/dx_k at the input means (frozen state)",
                UNITS: _per_param(units)})
            data[f"{out}_hessian"] = ((PARAMETER, PARAMETER_J, *dims), hess, {
                "long_name": f"local d2{out}/dx_k dx_j at the input means (frozen state)",
                UNITS: _per_param(units, 2)})
            data[f"{out}_curvature_ratio"] = (dims, ratio, {
                "long_name": "|1/2 sum_kj H_kj C_kj| / first-order std: the curvature term "
                             "of the mean against the spread", UNITS: "1"})
            warnings += _curvature_warnings(out, runs, dims, ratio)
        stats = xr.Dataset(data, coords={STATISTIC: LABELS})
        stats = stats.assign_coords({d: runs[d] for d in runs.coords
                                     if d != REALIZATION and d in stats.dims})
        warnings += cv_warnings(design[INPUT_CV].values, active, names, opts.cv_warning)
        for msg in warnings:
            pywarnings.warn(msg, AccuracyWarning, stacklevel=2)
        stats = finish_statistics(stats, design, runs, self.name, warnings)
        stats.attrs.update(order=opts.order, variance=opts.variance, assumption=FROZEN_STATE)
        return stats

    @classmethod
    def report(cls, view):
        """Each input's contribution g_k² s_k² to an output's variance, from the local
        derivatives; the one run is at the input means, not a draw."""
        attrs = view.stats.attrs
        runs = int(attrs.get(SOLVER_RUNS, 0))
        variance = attrs.get("variance", "")
        return MethodReport(
            description=f"Taylor expansion from the solver's local derivatives, order "
                        f"{attrs.get('order', '?')}, {runs} run{'' if runs == 1 else 's'}"
                        + (", second-order variance" if variance == "second-order" else ""),
            sensitivities=lambda out: contributions(view, out))


def _solver_label(solver) -> str:
    """The solver's name, with its variant where its description starts with one
    ("analytic/sobol_g", "gamut_bar/M1"; "mpm" from "mpm: 120x70 cells ...")."""
    words = solver.describe().split()
    first = words[0].rstrip(":,;") if words else ""
    return first if solver.name and first.startswith(solver.name) else solver.name


def _curvature_warnings(out, runs, dims, ratio) -> list[str]:
    bad = ratio > CURVATURE_RATIO_WARNING
    if not np.any(bad):
        return []
    at = np.unravel_index(np.argmax(np.where(bad, ratio, -np.inf)), np.shape(ratio))
    where = ""
    if dims:
        where = " (largest at " + ", ".join(
            f"{d} = {_label(runs[d].values[i])}" if d in runs.coords else f"{d}[{i}]"
            for d, i in zip(dims, at)) + ")"
    return [f"'{out}': the curvature term of the mean is {ratio[at]:.3g} x the first-order "
            f"std{where}, above {CURVATURE_RATIO_WARNING:.3g} at {int(np.sum(bad))} of "
            f"{np.size(ratio)} points: the expansion is not trustworthy at these C.V.s "
            f"(the first-order variance misses the quadratic term: try variance = "
            f"\"second-order\" and check against monte-carlo)"]
